"""The calibration file: what the chapter-7 calibration found, read by the driver, ToTal and the EKF (YAML,
written atomically; its format: docs/calibration.md). A file without window_range_rad holds its power bias
outside the thesis's 5-13 deg windows (`THESIS_CALIBRATION_WINDOW_RANGE_RAD`)."""

import contextlib
import datetime
import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from beams_common.calibration import file_schema
from beams_common.calibration.bearing_correction import THESIS_CALIBRATION_WINDOW_RANGE_RAD, BearingCorrection
from beams_common.calibration.calibration_checks import calibration_nominal_problem, calibration_value_problem
from beams_common.geometry.beacon_map import BeaconMap

FILE_FORMAT = "beams-calibration"
FILE_VERSION = 1
_POWER_KEYS = ("a", "b", "c", "d")
_ROTATION_KEYS = ("A", "B", "C", "D")


class CalibrationFileError(ValueError):
    """A calibration file that exists but cannot be used; the message names the file and the problem."""


@dataclass(frozen=True)
class RmsFigures:
    """Position RMS (m, eq. 7.10) and orientation RMS (rad, eq. 7.11) after one calibration stage."""

    stage: str
    position_rms_m: float
    orientation_rms_rad: float


@dataclass(frozen=True)
class SensorCalibration:
    """Everything chapter 7 calibrates, plus how well it did and when it was made."""

    beacon_map: BeaconMap
    bearing_correction: BearingCorrection = field(default_factory=BearingCorrection)
    turret_offset_m: tuple[float, float] = (0.0, 0.0)
    rms: tuple[RmsFigures, ...] = ()
    leave_one_out: RmsFigures | None = None
    warnings: tuple[str, ...] = ()
    created_utc: str = ""

    @staticmethod
    def now_utc() -> str:
        """The creation-time format of the file (ISO 8601, UTC, seconds)."""
        return datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


class StagedFile:
    """A file written in full beside its target, not yet in place: `commit` swaps it in (os.replace, atomic
    on POSIX), `discard` removes it. Several staged files let a writer produce every output before it
    replaces any: a failure meanwhile leaves all the targets as they were."""

    def __init__(self, target: str | os.PathLike, fill: Callable[[Any], object]) -> None:
        self.target = Path(target)
        descriptor, temporary = tempfile.mkstemp(
            dir=self.target.parent, prefix=f".{self.target.name}.", suffix=".tmp"
        )
        self._temporary: Path | None = Path(temporary)
        try:
            # mkstemp creates the file 0600; give it the usual umask-derived mode of a new file.
            os.fchmod(descriptor, 0o666 & ~_current_umask())
            with os.fdopen(descriptor, "wb") as handle:
                fill(handle)
                handle.flush()
                os.fsync(handle.fileno())
        except BaseException:
            self.discard()
            raise

    def commit(self, *, keep_backup: bool = False) -> None:
        """Put the file in place; with keep_backup, the previous target is first copied to `<target>.bak`."""
        if self._temporary is None:
            raise RuntimeError(f"{self.target}: staged file already committed or discarded")
        if keep_backup and self.target.exists():
            backup = self.target.with_name(self.target.name + ".bak")
            StagedFile(backup, lambda handle: _copy_into(self.target, handle)).commit()
        try:
            os.replace(self._temporary, self.target)
        except BaseException:
            self.discard()
            raise
        self._temporary = None
        _fsync_directory(self.target.parent)

    def discard(self) -> None:
        if self._temporary is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self._temporary)
            self._temporary = None


def stage_text(path: str | os.PathLike, text: str) -> StagedFile:
    """`text` staged for `path` (UTF-8), its directory created if needed."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return StagedFile(path, lambda handle: handle.write(text.encode("utf-8")))


def atomic_write_text(path: str | os.PathLike, text: str, *, keep_backup: bool = True) -> None:
    """Replace `path` by `text` (a fsynced temporary file renamed over it; with keep_backup the previous file
    first copied to `<path>.bak` likewise), so that a crash leaves either the old or the new file."""
    stage_text(path, text).commit(keep_backup=keep_backup)


def _copy_into(source: Path, handle: Any) -> None:
    with source.open("rb") as original:
        shutil.copyfileobj(original, handle)


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_directory(directory: Path) -> None:
    # The rename itself is only durable once the directory entry is on disk.
    with contextlib.suppress(OSError):
        descriptor = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)


def calibration_to_dict(calibration: SensorCalibration) -> dict[str, Any]:
    """The YAML document of a calibration (plain types only)."""
    correction = calibration.bearing_correction
    document: dict[str, Any] = {
        "format": FILE_FORMAT,
        "version": FILE_VERSION,
        "created_utc": calibration.created_utc or SensorCalibration.now_utc(),
        "beacons": [
            {"id": int(beacon_id), "x_m": float(xy[0]), "y_m": float(xy[1])}
            for beacon_id, xy in zip(calibration.beacon_map.ids, calibration.beacon_map.xy, strict=True)
        ],
        "power_bias": _power_bias_to_dict(correction),
        "rotation_bias": dict(zip(_ROTATION_KEYS, correction.rotation_bias_coefficients, strict=True)),
        "turret_offset_m": {
            "x": float(calibration.turret_offset_m[0]),
            "y": float(calibration.turret_offset_m[1]),
        },
        "rms": [_rms_to_dict(figures) for figures in calibration.rms],
        "warnings": list(calibration.warnings),
    }
    if calibration.leave_one_out is not None:
        document["leave_one_out"] = _rms_to_dict(calibration.leave_one_out)
    return document


def _power_bias_to_dict(correction: BearingCorrection) -> dict[str, Any]:
    entry: dict[str, Any] = dict(zip(_POWER_KEYS, correction.power_bias_coefficients, strict=True))
    if correction.window_range_rad is not None:
        entry["window_range_rad"] = list(correction.window_range_rad)
    return entry


def _rms_to_dict(figures: RmsFigures) -> dict[str, Any]:
    return {
        "stage": figures.stage,
        "position_rms_m": float(figures.position_rms_m),
        "orientation_rms_rad": float(figures.orientation_rms_rad),
    }


_HEADER = """\
# BeAMS sensor calibration (thesis chapter 7), written by beams_calibration.
# beacons: true beacon coordinates in the map frame (m).
# power_bias: f(w) = a w^3 + b w^2 + c w + d (eq. 7.19), window w and f in rad;
#   held at its edge value outside window_range_rad (the windows the calibration saw).
# rotation_bias: f(phi) = A cos(phi) + B sin(phi) + C cos(2 phi) + D sin(2 phi) (eq. 7.25), rad.
# The driver publishes phi - f_power(w) - f_rotation(phi) (eq. 7.18, 7.24).
# turret_offset_m: turret rotation centre in base_link (m), eq. 7.26.
# rms: position (m, eq. 7.10) and orientation (rad, eq. 7.11) RMS errors after each stage.
"""


def calibration_text(calibration: SensorCalibration) -> str:
    """The calibration file's text (YAML with its explanatory header)."""
    document = calibration_to_dict(calibration)
    return _HEADER + yaml.safe_dump(document, sort_keys=False, default_flow_style=None)


def save_calibration(calibration: SensorCalibration, path: str | os.PathLike) -> None:
    """Write the calibration as YAML, atomically, keeping the previous file as `<path>.bak`."""
    atomic_write_text(path, calibration_text(calibration), keep_backup=True)


def load_calibration(path: str | os.PathLike) -> SensorCalibration:
    """Read a calibration file: FileNotFoundError, or CalibrationFileError naming the file and the faulty
    entry or implausible value (`calibration_checks.calibration_value_problem`)."""
    source = Path(path)
    if not source.is_file():
        raise FileNotFoundError(f"calibration file {source} does not exist")
    try:
        calibration = calibration_from_dict(file_schema.read_yaml(source))
    except ValueError as error:  # SchemaError, or BeaconMap's and BearingCorrection's own checks
        raise CalibrationFileError(f"calibration file {source}: {error}") from None
    problem = calibration_value_problem(calibration.bearing_correction, calibration.turret_offset_m)
    if problem:
        raise CalibrationFileError(f"calibration file {source}: implausible, {problem}")
    return calibration


def node_refusal(
    calibration: SensorCalibration, nominal_map: BeaconMap, nominal_turret_offset_m: tuple[float, float]
) -> str:
    """Why a node would refuse this calibration at start-up, or '': its file text read back against the
    schema and `calibration_value_problem` (`load_calibration`), then `calibration_nominal_problem`
    against the nominal geometry (`geometry_parameters.geometry_of_calibration`)."""
    try:
        loaded = calibration_from_dict(yaml.safe_load(calibration_text(calibration)))
    except ValueError as error:
        return str(error)
    offset = loaded.turret_offset_m
    return calibration_value_problem(loaded.bearing_correction, offset) or calibration_nominal_problem(
        loaded.beacon_map, offset, nominal_map, nominal_turret_offset_m
    )


def calibration_from_dict(document: Any) -> SensorCalibration:
    """Parse the YAML document of a calibration against its schema (see the module docstring): every
    entry is checked for type, shape and finiteness; SchemaError (a ValueError) names the faulty one."""
    top = file_schema.header(document, FILE_FORMAT, FILE_VERSION)
    beacon_map = BeaconMap.from_lists(*file_schema.beacon_lists(top))
    power, rotation, offset = (
        file_schema.mapping(file_schema.required(top, key), key, keys)
        for key, keys in (
            ("power_bias", _POWER_KEYS),
            ("rotation_bias", _ROTATION_KEYS),
            ("turret_offset_m", ("x", "y")),
        )
    )
    window_range = file_schema.optional(
        power, "window_range_rad", _window_range, "power_bias", THESIS_CALIBRATION_WINDOW_RANGE_RAD
    )
    correction = BearingCorrection(
        tuple(file_schema.number(power[key], f"power_bias.{key}") for key in _POWER_KEYS),
        tuple(file_schema.number(rotation[key], f"rotation_bias.{key}") for key in _ROTATION_KEYS),
        window_range,
    )
    turret_offset_m = (
        file_schema.number(offset["x"], "turret_offset_m.x"),
        file_schema.number(offset["y"], "turret_offset_m.y"),
    )
    rms = file_schema.optional(top, "rms", lambda v, p: file_schema.items(v, p), "", [])
    warnings = file_schema.optional(top, "warnings", lambda v, p: file_schema.items(v, p), "", [])
    return SensorCalibration(
        beacon_map=beacon_map,
        bearing_correction=correction,
        turret_offset_m=turret_offset_m,
        rms=tuple(_rms_from_dict(item, f"rms[{index}]") for index, item in enumerate(rms)),
        leave_one_out=file_schema.optional(top, "leave_one_out", _rms_from_dict, "", None),
        warnings=tuple(file_schema.text(item, f"warnings[{index}]") for index, item in enumerate(warnings)),
        created_utc=file_schema.optional(top, "created_utc", file_schema.text, "", ""),
    )


def _window_range(value: Any, path: str) -> tuple[float, float]:
    low, high = (
        file_schema.number(v, f"{path}[{k}]", minimum=0.0)
        for k, v in enumerate(file_schema.items(value, path, 2))
    )
    if not low <= high:
        raise file_schema.SchemaError(f"{path}: expected [low, high] with low <= high, got [{low}, {high}]")
    return (low, high)


def _rms_from_dict(item: Any, path: str) -> RmsFigures:
    entry = file_schema.mapping(item, path, ("stage", "position_rms_m", "orientation_rms_rad"))
    return RmsFigures(
        file_schema.text(entry["stage"], f"{path}.stage"),
        file_schema.number(entry["position_rms_m"], f"{path}.position_rms_m", minimum=0.0),
        file_schema.number(entry["orientation_rms_rad"], f"{path}.orientation_rms_rad", minimum=0.0),
    )
