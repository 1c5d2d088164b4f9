"""What the EKF learnt of the sensor while driving, as a chapter-7 calibration file.

The power-bias states (`power_bias_states`) hold the curve f(w) of eq. 7.19 on a Chebyshev basis; the
file holds it as eq. 7.19's (a, b, c, d) with the window range (beams_common.calibration.calibration_file), so
driver_node corrects the bearings with it and the chapter-7 tools (`calibrate`, the plots) read it. With
turret offset states (`turret_offset_states`) the file's turret offset is the configured one corrected,
with beacon states (`beacon_states`) its beacon map holds the learnt coordinates of those beacons.
"""

import os

from beams_common.calibration.calibration_file import SensorCalibration, save_calibration
from beams_common.geometry.beacon_map import BeaconMap
from beams_ekf.beacon_states import BeaconStates
from beams_ekf.bearing_ekf import BearingEkf
from beams_ekf.power_bias_states import PowerBiasStates
from beams_ekf.turret_offset_states import TurretOffsetStates


def self_calibration(
    ekf: BearingEkf, beacon_map: BeaconMap, turret_offset_m: tuple[float, float]
) -> SensorCalibration:
    """The calibration of the filter's power-bias estimate, with the geometry it runs with (turret_offset_m
    the configured offset, corrected by the filter's estimate when it has turret offset states; the
    beacons it estimates at their learnt coordinates);
    ValueError when the filter has no power-bias states."""
    states, estimate = ekf.block(PowerBiasStates), ekf.estimate(PowerBiasStates)
    if states is None or estimate is None:
        raise ValueError("the filter has no power-bias states (power_bias_states is 'off')")
    correction = states.correction(estimate[0])
    offset = ekf.estimate(TurretOffsetStates)
    if offset is not None:
        turret_offset_m = (turret_offset_m[0] + float(offset[0][0]), turret_offset_m[1] + float(offset[0][1]))
    beacons = ekf.block(BeaconStates)
    if beacons is not None:
        learnt = beacons.learnt(*ekf.estimate(BeaconStates), ekf.beacons_xy)
        xy = [learnt[i][0] if i in learnt else tuple(beacon_map.xy[n]) for n, i in enumerate(beacon_map.ids)]
        beacon_map = BeaconMap.from_lists(beacon_map.ids, [p[0] for p in xy], [p[1] for p in xy])
    warnings = () if states.estimate else ("power_bias_states 'consider': the prior, nothing learnt",)
    return SensorCalibration(
        beacon_map,
        correction,
        turret_offset_m,
        warnings=warnings,
        created_utc=SensorCalibration.now_utc(),
    )


def save_self_calibration(
    ekf: BearingEkf, beacon_map: BeaconMap, turret_offset_m: tuple[float, float], path: str | os.PathLike
) -> SensorCalibration:
    """Write `self_calibration` to path (atomically, the previous file kept as .bak); returns it."""
    calibration = self_calibration(ekf, beacon_map, turret_offset_m)
    save_calibration(calibration, path)
    return calibration
