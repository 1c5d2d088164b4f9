"""The calibration dataset of thesis section 7.3.1: reference configurations (eq. 7.5), each a true pose
with every beacon's mean bearing and window (eq. 7.16). The YAML format: docs/calibration.md."""

import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from beams_calibration.parameters import CALIBRATION_PARAMETERS
from beams_common.calibration import file_schema
from beams_common.calibration.calibration_file import atomic_write_text
from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import BeaconMap
from beams_common.intake.plausibility import TABLE_MARGIN_M, off_table_problem
from beams_triangulation.total import triangulate

DATASET_FORMAT = "beams-calibration-dataset"
DATASET_VERSION = 1


class DatasetError(ValueError):
    """A dataset file that cannot be read, or a capture that cannot be recorded; says why."""


@dataclass(frozen=True)
class BeaconObservation:
    """One beacon in one configuration: mean bearing and window (rad), spread (rad), revolutions seen."""

    beacon_id: int
    bearing_rad: float
    window_rad: float
    spread_rad: float
    revolutions: int


@dataclass(frozen=True)
class Configuration:
    """A reference configuration C_k (eq. 7.5) and its averaged measurements (eq. 7.7, 7.16)."""

    x_m: float
    y_m: float
    theta_rad: float
    observations: tuple[BeaconObservation, ...]
    revolutions: int
    recorded_utc: str = ""
    label: str = ""

    def observation(self, beacon_id: int) -> BeaconObservation | None:
        """The observation of one beacon, or None when it was not recorded."""
        return next((o for o in self.observations if o.beacon_id == beacon_id), None)

    def summary(self) -> str:
        """One line: pose and beacons seen (for ListConfigurations)."""
        seen = ", ".join(
            f"B{o.beacon_id} {math.degrees(o.bearing_rad):.2f} deg (w {math.degrees(o.window_rad):.2f} deg)"
            for o in self.observations
        )
        label = f" [{self.label}]" if self.label else ""
        return (
            f"x={self.x_m:.4f} m y={self.y_m:.4f} m theta={math.degrees(self.theta_rad):.1f} deg"
            f"{label}, {self.revolutions} revolutions: {seen}"
        )


# The pose at the start of a summary line (ListConfigurations: "3: x=0.1200 m y=0.8400 m theta=90.0 deg ...").
_SUMMARY_POSE = re.compile(r"x=(-?[0-9.]+) m y=(-?[0-9.]+) m theta=(-?[0-9.]+) deg")


def pose_of_summary(line: str) -> tuple[float, float, float] | None:
    """The pose (m, m, rad) a `Configuration.summary` line states (to 0.1 mm and 0.1 deg), or None."""
    match = _SUMMARY_POSE.search(line)
    if match is None:
        return None
    x_m, y_m, theta_deg = map(float, match.groups())
    return x_m, y_m, math.radians(theta_deg)


@dataclass(frozen=True)
class Dataset:
    """The a-priori beacon map (section 7.3.4's starting point) and the recorded configurations."""

    beacon_map: BeaconMap
    configurations: tuple[Configuration, ...] = field(default=())

    def with_configuration(self, configuration: Configuration) -> "Dataset":
        return replace(self, configurations=(*self.configurations, configuration))

    def cleared(self) -> "Dataset":
        return replace(self, configurations=())


@dataclass(frozen=True)
class CalibrationArrays:
    """A dataset as arrays for Algorithm 7.1: n configurations by the map's three beacons."""

    poses: np.ndarray  # (n, 3) true x (m), y (m), theta (rad)
    bearings_rad: np.ndarray  # (n, 3) mean bearings, sensor frame
    windows_rad: np.ndarray  # (n, 3) mean angular windows
    beacon_ids: tuple[int, ...]  # the beacons, in the columns' order
    beacons_xy: np.ndarray  # (3, 2) a-priori coordinates
    names: tuple[str, ...] = ()  # each row's configuration, as a warning names it

    @property
    def count(self) -> int:
        return int(self.poses.shape[0])

    def subset(self, rows: np.ndarray) -> "CalibrationArrays":
        """The configurations of `rows` only."""
        names = tuple(self.names[k] for k in rows) if self.names else ()
        return replace(
            self,
            poses=self.poses[rows],
            bearings_rad=self.bearings_rad[rows],
            windows_rad=self.windows_rad[rows],
            names=names,
        )


def to_arrays(dataset: Dataset, beacon_ids: Sequence[int] | None = None) -> CalibrationArrays:
    """Arrays of the configurations that saw the three chosen beacons (default: the map's first three)."""
    ids = tuple(beacon_ids) if beacon_ids is not None else dataset.beacon_map.ids[:3]
    if len(ids) != 3:
        raise DatasetError(f"calibration uses exactly three beacons (thesis ch. 7), got {list(ids)}")
    numbered = [
        (k, c)
        for k, c in enumerate(dataset.configurations, 1)
        if all(c.observation(i) is not None for i in ids)
    ]
    rows = [c for _, c in numbered]
    poses = np.array([(c.x_m, c.y_m, c.theta_rad) for c in rows], dtype=float).reshape(-1, 3)
    bearings = np.array([[c.observation(i).bearing_rad for i in ids] for c in rows], dtype=float)
    windows = np.array([[c.observation(i).window_rad for i in ids] for c in rows], dtype=float)
    return CalibrationArrays(
        poses=poses,
        bearings_rad=bearings.reshape(-1, 3),
        windows_rad=windows.reshape(-1, 3),
        beacon_ids=ids,
        beacons_xy=dataset.beacon_map.subset(ids),
        names=tuple(
            f"configuration {k}{f' [{c.label}]' if c.label else ''} {_pose_text(c.x_m, c.y_m, c.theta_rad)}"
            for k, c in numbered
        ),
    )


# --- capture: plausibility of the operator's pose ----------------------------------------------

# Headings are given in (-pi, pi] or [0, 2 pi); beyond one turn either way the operator mistyped.
MAX_CAPTURE_HEADING_RAD = 2.0 * math.pi


def capture_pose_problem(
    x_m: float, y_m: float, theta_rad: float, beacon_map: BeaconMap, margin_m: float = TABLE_MARGIN_M
) -> str:
    """Why a reference pose is implausible (not finite, off the beacons' table, heading beyond one turn),
    or ''."""
    if not all(math.isfinite(v) for v in (x_m, y_m, theta_rad)):
        return f"the pose ({x_m}, {y_m}, {theta_rad}) is not finite"
    off_table = off_table_problem(x_m, y_m, beacon_map.xy, margin_m)
    if off_table:
        return off_table
    if abs(theta_rad) > MAX_CAPTURE_HEADING_RAD:
        return f"the heading {theta_rad:.4g} rad is beyond one turn: give it in (-pi, pi] or [0, 2 pi)"
    return ""


# A reference pose farther than this from its uncalibrated ToTal pose is mistyped: the simulated thesis
# hardware's worst of section 7.3.1's 48 is 34 mm and 1.9 deg (the power bias turns it, fig. 7.11).
CAPTURE_POSITION_TOLERANCE_M = 0.1
CAPTURE_HEADING_TOLERANCE_RAD = math.radians(5.0)


def _pose_text(x_m: float, y_m: float, theta_rad: float) -> str:
    return f"({x_m:.3f} m, {y_m:.3f} m, {math.degrees(theta_rad):.1f} deg)"


def capture_bearing_problem(
    pose: tuple[float, float, float], observations: Sequence[BeaconObservation], beacon_map: BeaconMap
) -> str:
    """Why a reference pose is not the one its mean bearings give, or '': ToTal (Algorithm 6.1) on the
    map's first three beacons (those Algorithm 7.1 uses), within CAPTURE_POSITION_TOLERANCE_M and
    CAPTURE_HEADING_TOLERANCE_RAD; the reason states both poses."""
    ids = beacon_map.ids[:3]
    bearings = {o.beacon_id: o.bearing_rad for o in observations}
    fix = triangulate(beacon_map.subset(ids), [bearings.get(i, math.nan) for i in ids])
    if not fix.ok:
        return f"the bearings give no pose for reference pose {_pose_text(*pose)}: {fix.reason}"
    distance = math.hypot(fix.x - pose[0], fix.y - pose[1])
    turn = abs(float(wrap_to_pi(fix.heading - pose[2])))
    if distance <= CAPTURE_POSITION_TOLERANCE_M and turn <= CAPTURE_HEADING_TOLERANCE_RAD:
        return ""
    return (
        f"reference pose {_pose_text(*pose)} is {distance:.3f} m and {math.degrees(turn):.1f} deg from "
        f"the pose its bearings give {_pose_text(fix.x, fix.y, fix.heading)} (uncalibrated: within "
        f"{CAPTURE_POSITION_TOLERANCE_M} m, {math.degrees(CAPTURE_HEADING_TOLERANCE_RAD):.0f} deg): "
        "theta off by pi? mirrored? mistyped?"
    )


# --- capture: averaging revolutions into one configuration ------------------------------------


def average_capture(
    revolutions: Sequence[Mapping[int, tuple[float, float]]],
    required_ids: Iterable[int],
    *,
    min_seen_fraction: float = CALIBRATION_PARAMETERS.default("min_seen_fraction"),
    max_spread_rad: float = math.radians(CALIBRATION_PARAMETERS.default("max_spread_deg")),
) -> tuple[BeaconObservation, ...]:
    """Average single revolutions {beacon_id: (bearing_rad, window_rad)} into observations.

    Refuses (DatasetError with the reason) when a required beacon was seen in fewer than
    min_seen_fraction of the revolutions, or when a beacon's bearings spread more than
    max_spread_rad (the robot moved, or the bearing is unstable).
    """
    if not revolutions:
        raise DatasetError("no revolution received: is the driver publishing beams/bearings?")
    observations = []
    for beacon_id in sorted(set(required_ids)):
        samples = [rev[beacon_id] for rev in revolutions if beacon_id in rev]
        if len(samples) < min_seen_fraction * len(revolutions):
            raise DatasetError(
                f"beacon {beacon_id} seen in {len(samples)} of {len(revolutions)} revolutions "
                f"(at least {min_seen_fraction:.0%} needed): is it occluded or switched off?"
            )
        observation = _average_beacon(beacon_id, np.array(samples, dtype=float))
        if observation.spread_rad > max_spread_rad:
            raise DatasetError(
                f"beacon {beacon_id}: bearing spread {math.degrees(observation.spread_rad):.3f} deg exceeds "
                f"{math.degrees(max_spread_rad):.3f} deg: did the robot move during the capture?"
            )
        observations.append(observation)
    return tuple(observations)


def _average_beacon(beacon_id: int, samples: np.ndarray) -> BeaconObservation:
    """Circular mean of the bearings (they may straddle +-pi), arithmetic mean of the windows."""
    bearings, windows = samples[:, 0], samples[:, 1]
    mean_bearing = math.atan2(float(np.mean(np.sin(bearings))), float(np.mean(np.cos(bearings))))
    deviations = np.asarray(wrap_to_pi(bearings - mean_bearing))
    return BeaconObservation(
        beacon_id=int(beacon_id),
        bearing_rad=float(wrap_to_pi(mean_bearing)),
        window_rad=float(np.mean(windows)),
        spread_rad=float(np.sqrt(np.mean(deviations**2))),
        revolutions=len(samples),
    )


# --- the file ----------------------------------------------------------------------------------


def dataset_to_dict(dataset: Dataset) -> dict[str, Any]:
    """The YAML document of a dataset (plain types only)."""
    return {
        "format": DATASET_FORMAT,
        "version": DATASET_VERSION,
        "beacons": [
            {"id": int(i), "x_m": float(xy[0]), "y_m": float(xy[1])}
            for i, xy in zip(dataset.beacon_map.ids, dataset.beacon_map.xy, strict=True)
        ],
        "configurations": [_configuration_to_dict(c) for c in dataset.configurations],
    }


def _configuration_to_dict(configuration: Configuration) -> dict[str, Any]:
    return {
        "pose": {"x_m": configuration.x_m, "y_m": configuration.y_m, "theta_rad": configuration.theta_rad},
        "revolutions": configuration.revolutions,
        "recorded_utc": configuration.recorded_utc,
        "label": configuration.label,
        "beacons": [
            {"id" if key == "beacon_id" else key: value for key, value in asdict(o).items()}
            for o in configuration.observations
        ],
    }


_HEADER = """\
# BeAMS calibration dataset (thesis section 7.3.1), written by beams_calibration; editable.
# beacons: a-priori beacon coordinates in the map frame (m), the calibration's starting point.
# configurations: true robot pose (m, rad, map frame) and, per beacon, the circular mean of the
#   bearings (rad, sensor frame), mean angular window (rad), bearing spread (rad, one revolution)
#   and the number of revolutions in which the beacon was decoded.
"""


def save_dataset(dataset: Dataset, path: str | os.PathLike) -> None:
    """Write the whole dataset atomically (temporary file, fsync, rename), keeping `<path>.bak`."""
    text = _HEADER + yaml.safe_dump(dataset_to_dict(dataset), sort_keys=False, default_flow_style=None)
    atomic_write_text(path, text, keep_backup=True)


def load_dataset(path: str | os.PathLike) -> Dataset:
    """Read a dataset file; FileNotFoundError when missing, DatasetError naming the problem otherwise."""
    source = Path(path)
    if not source.is_file():
        raise FileNotFoundError(f"dataset file {source} does not exist")
    try:
        return dataset_from_dict(file_schema.read_yaml(source))
    except ValueError as error:  # SchemaError, or BeaconMap's own checks
        raise DatasetError(f"dataset file {source}: {error}") from None


def append_configuration(
    path: str | os.PathLike, beacon_map: BeaconMap, configuration: Configuration
) -> Dataset:
    """Append one configuration to the dataset file (created on `beacon_map` if absent); atomic."""
    dataset = load_dataset(path) if Path(path).is_file() else Dataset(beacon_map)
    dataset = dataset.with_configuration(configuration)
    save_dataset(dataset, path)
    return dataset


def dataset_from_dict(document: Any) -> Dataset:
    """Parse the YAML document of a dataset against its schema (see the module docstring): every entry
    is checked for type, shape and finiteness; SchemaError (a ValueError) names the faulty one."""
    top = file_schema.header(document, DATASET_FORMAT, DATASET_VERSION)
    beacon_map = BeaconMap.from_lists(*file_schema.beacon_lists(top))
    configurations = file_schema.optional(top, "configurations", file_schema.items, "", [])
    return Dataset(
        beacon_map,
        tuple(
            _configuration_from_dict(item, f"configurations[{k}]") for k, item in enumerate(configurations)
        ),
    )


def _configuration_from_dict(item: Any, path: str) -> Configuration:
    entry = file_schema.mapping(item, path, ("pose", "beacons"))
    pose = file_schema.mapping(entry["pose"], f"{path}.pose", ("x_m", "y_m", "theta_rad"))
    values = tuple(file_schema.number(pose[key], f"{path}.pose.{key}") for key in ("x_m", "y_m", "theta_rad"))
    revolutions = file_schema.optional(entry, "revolutions", _count, path, 1)
    observations = tuple(
        _observation_from_dict(b, f"{path}.beacons[{k}]", revolutions)
        for k, b in enumerate(file_schema.items(entry["beacons"], f"{path}.beacons"))
    )
    ids = [o.beacon_id for o in observations]
    if len(set(ids)) != len(ids):
        raise file_schema.SchemaError(f"{path}.beacons: beacon id repeated in {ids}")
    return Configuration(
        *values,
        observations=observations,
        revolutions=revolutions,
        recorded_utc=file_schema.optional(entry, "recorded_utc", file_schema.text, path, ""),
        label=file_schema.optional(entry, "label", file_schema.text, path, ""),
    )


def _count(value: Any, path: str) -> int:
    return file_schema.integer(value, path, minimum=1)


def _observation_from_dict(item: Any, path: str, revolutions: int) -> BeaconObservation:
    beacon = file_schema.mapping(item, path, ("id", "bearing_rad", "window_rad"))
    return BeaconObservation(
        beacon_id=file_schema.integer(beacon["id"], f"{path}.id", minimum=0, maximum=65535),
        bearing_rad=file_schema.number(beacon["bearing_rad"], f"{path}.bearing_rad"),
        window_rad=file_schema.number(beacon["window_rad"], f"{path}.window_rad", minimum=0.0),
        spread_rad=file_schema.optional(beacon, "spread_rad", _non_negative, path, 0.0),
        revolutions=file_schema.optional(beacon, "revolutions", _count, path, revolutions),
    )


def _non_negative(value: Any, path: str) -> float:
    return file_schema.number(value, path, minimum=0.0)
