"""Plausibility of a calibration's values (thesis ch. 7) before any node applies it, and its effect on recent
fixes. Section 7.4 expects beacons a few millimetres from the manual measurements, a power bias of a few
degrees and a rotation bias of a few tenths at most (the turret offset found: (-0.98, -0.11) mm, section
7.3.5); the limits leave a margin of about three (a rotation bias of 3 rad put the EKF 1.6-2.5 m off while
it reported 2 mm). `calibration_value_problem` runs on every load; `calibration_nominal_problem`
holds it to the nominal geometry; `bearing_residual_rms` compares a new calibration with the one in use.
"""

import math
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from beams_common.calibration.bearing_correction import THESIS_CALIBRATION_WINDOW_RANGE_RAD, BearingCorrection
from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import BeaconMap

# "power bias corrections of a few degrees maximum" (section 7.4); the thesis's global fit (fig. 7.11)
# reaches 3.7 deg over its windows.
MAX_POWER_BIAS_RAD = math.radians(10.0)
# "the rotation bias a few tenths of degree maximum" (section 7.4); the thesis's fit (fig. 7.12): 0.21 deg.
MAX_ROTATION_BIAS_RAD = math.radians(1.0)
# The turret sits on the robot: a Eurobot robot's footprint (perimeter <= 1.2 m) has a radius ~0.2 m.
MAX_TURRET_OFFSET_M = 0.2
# A calibration corrects the nominal turret position by millimetres (thesis: 1 mm); 2 cm is a mounting
# mistake, not a calibration.
MAX_TURRET_CORRECTION_M = 0.02
# Beacons corrected up to 4 mm in the thesis (table 7.4); a Eurobot beacon support puts a beacon within
# 1-2 cm of its nominal place: 5 cm is another place.
MAX_BEACON_CORRECTION_M = 0.05
# Grid of the maxima (windows, turret angles): the biases are cubics and second-order Fourier series,
# smooth enough for 256 points to find their extremes within a fraction of a percent.
_GRID_POINTS = 256
# A calibration is flagged when it raises the residual RMS of recent bearings by this factor and by more
# than the floor (rad): below the floor the difference is the bearings' noise (0.27 deg, section 7.5).
WORSE_RMS_FACTOR = 1.5
WORSE_RMS_FLOOR_RAD = math.radians(0.3)


def _max_abs(values: np.ndarray) -> float:
    """max |values|, inf when any is not finite (a coefficient of 1e300 overflows)."""
    return float(np.max(np.abs(values))) if np.all(np.isfinite(values)) else math.inf


def power_bias_extent_rad(correction: BearingCorrection) -> float:
    """The largest |f_corr1(w)| (eq. 7.19) over the windows the correction applies to: its own
    window_range_rad, else the thesis's calibration windows."""
    low, high = correction.window_range_rad or THESIS_CALIBRATION_WINDOW_RANGE_RAD
    with np.errstate(all="ignore"):
        return _max_abs(np.asarray(correction.power_bias(np.linspace(low, high, _GRID_POINTS))))


def rotation_bias_extent_rad(correction: BearingCorrection) -> float:
    """The largest |f_corr2(phi)| (eq. 7.25) over a turn of the turret."""
    angles = np.linspace(-math.pi, math.pi, _GRID_POINTS, endpoint=False)
    with np.errstate(all="ignore"):
        return _max_abs(np.asarray(correction.rotation_bias(angles)))


def calibration_value_problem(correction: BearingCorrection, turret_offset_m: Sequence[float]) -> str:
    """Why a calibration's bearing correction or turret offset is not one a BeAMS calibration finds, or
    '' (the limits and their source are in the module docstring)."""
    power = power_bias_extent_rad(correction)
    if not power <= MAX_POWER_BIAS_RAD:
        return (
            f"power_bias reaches {math.degrees(power):.3g} deg over its windows, beyond the "
            f"{math.degrees(MAX_POWER_BIAS_RAD):g} deg a calibration finds (thesis 7.4: a few degrees)"
        )
    rotation = rotation_bias_extent_rad(correction)
    if not rotation <= MAX_ROTATION_BIAS_RAD:
        return (
            f"rotation_bias reaches {math.degrees(rotation):.3g} deg over a turn, beyond the "
            f"{math.degrees(MAX_ROTATION_BIAS_RAD):g} deg a calibration finds (thesis 7.4: a few tenths)"
        )
    offset = math.hypot(float(turret_offset_m[0]), float(turret_offset_m[1]))
    if not offset <= MAX_TURRET_OFFSET_M:
        return (
            f"turret_offset_m is {offset:.3g} m from base_link, off a Eurobot robot "
            f"(at most {MAX_TURRET_OFFSET_M:g} m)"
        )
    return ""


def calibration_nominal_problem(
    beacon_map: BeaconMap,
    turret_offset_m: Sequence[float],
    nominal_map: BeaconMap,
    nominal_turret_offset_m: Sequence[float],
) -> str:
    """Why a calibrated beacon map and turret offset are not corrections of the nominal ones (the node's
    parameters), or '': every calibrated beacon on the nominal map within MAX_BEACON_CORRECTION_M, the
    turret within MAX_TURRET_CORRECTION_M of its nominal position."""
    for beacon_id, xy in zip(beacon_map.ids, beacon_map.xy, strict=True):
        if beacon_id not in nominal_map:
            return (
                f"calibrated beacon {beacon_id} is not on the nominal map {list(nominal_map.ids)} "
                "(beacon_ids): set the nominal map to the table's layout"
            )
        moved = float(np.hypot(*(xy - nominal_map.position(beacon_id))))
        if moved > MAX_BEACON_CORRECTION_M:
            return (
                f"calibrated beacon {beacon_id} is {moved:.3f} m from its nominal position "
                f"(beacon_x/y), beyond the {MAX_BEACON_CORRECTION_M:g} m a calibration corrects"
            )
    dx = float(turret_offset_m[0]) - float(nominal_turret_offset_m[0])
    dy = float(turret_offset_m[1]) - float(nominal_turret_offset_m[1])
    if math.hypot(dx, dy) > MAX_TURRET_CORRECTION_M:
        return (
            f"calibrated turret offset {tuple(round(float(v), 4) for v in turret_offset_m)} m is "
            f"{math.hypot(dx, dy):.3f} m from the nominal turret_offset_m "
            f"{tuple(float(v) for v in nominal_turret_offset_m)}, beyond the {MAX_TURRET_CORRECTION_M:g} m "
            "a calibration corrects"
        )
    return ""


@dataclass(frozen=True)
class BearingSample:
    """A bearing (sensor frame, rad) of a beacon, with the robot's estimated pose (map) at its instant."""

    robot_pose: tuple[float, float, float]
    beacon_id: int
    bearing_rad: float


def bearing_residual_rms(
    samples: Iterable[BearingSample],
    beacons_xy: Mapping[int, Sequence[float]],
    turret_offset_m: Sequence[float],
) -> float:
    """RMS (rad) of the bearings' residuals: measured minus predicted from the robot pose, the turret at
    its offset (eq. 7.26) and the beacon's position (the bearing model of thesis eq. 7.8); nan without a
    sample of a known beacon."""
    residuals = []
    for sample in samples:
        beacon = beacons_xy.get(sample.beacon_id)
        if beacon is None:
            continue
        x, y, theta = sample.robot_pose
        c, s = math.cos(theta), math.sin(theta)
        turret_x = x + c * turret_offset_m[0] - s * turret_offset_m[1]
        turret_y = y + s * turret_offset_m[0] + c * turret_offset_m[1]
        predicted = math.atan2(beacon[1] - turret_y, beacon[0] - turret_x) - theta
        residuals.append(float(wrap_to_pi(sample.bearing_rad - predicted)))
    return math.sqrt(float(np.mean(np.square(residuals)))) if residuals else math.nan


def calibration_worse_problem(rms_before_rad: float, rms_after_rad: float) -> str:
    """Why a new calibration makes the recent bearings worse (their residual RMS up by WORSE_RMS_FACTOR
    and WORSE_RMS_FLOOR_RAD), or '' (also when either RMS is unknown)."""
    if not (math.isfinite(rms_before_rad) and math.isfinite(rms_after_rad)):
        return ""
    if (
        rms_after_rad > WORSE_RMS_FACTOR * rms_before_rad
        and rms_after_rad - rms_before_rad > WORSE_RMS_FLOOR_RAD
    ):
        return (
            f"the new calibration makes the recent bearings worse: residual RMS "
            f"{math.degrees(rms_before_rad):.3f} -> {math.degrees(rms_after_rad):.3f} deg"
        )
    return ""


class RecentBearings:
    """The last `size` accepted bearings with the robot's estimated pose at their instants: what a new
    calibration is compared on (`worse_problem`)."""

    def __init__(self, size: int = 60) -> None:
        self._samples: deque[BearingSample] = deque(maxlen=size)

    def add(self, sample: BearingSample) -> None:
        self._samples.append(sample)

    def clear(self) -> None:
        self._samples.clear()

    def __len__(self) -> int:
        return len(self._samples)

    def worse_problem(
        self,
        before: tuple[Mapping[int, Sequence[float]], Sequence[float]],
        after: tuple[Mapping[int, Sequence[float]], Sequence[float]],
    ) -> str:
        """`calibration_worse_problem` of the recent bearings' residual RMS under the geometry in use
        (`before`: beacons {id: (x, y)}, turret offset) and the new one (`after`), or ''."""
        return calibration_worse_problem(
            bearing_residual_rms(self._samples, *before), bearing_residual_rms(self._samples, *after)
        )
