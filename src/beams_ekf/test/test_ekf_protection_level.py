"""The EKF's fault hypotheses for its protection level (beams_ekf.separations, docs/protection_level.md): one
per beacon, its first bearing's exactly the filter without that bearing, a biased beacon's the filter run
without its bearings (to first order), none before a bearing or after a re-initialisation, and the level
falls as beacons are added."""

import math
from dataclasses import replace

import numpy as np
import pytest

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.bearing import Bearing
from beams_common.geometry.pose2d import Pose2D
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake
from beams_common.status.protection_level import Integrity
from beams_ekf.bearing_ekf import bearing_measurement
from beams_ekf.localiser import FilterSettings, Localiser, build_localiser, revolution_of
from beams_ekf.separations import BeaconSeparations
from beams_ekf.settings import LocaliserConfig
from beams_sim.simulated_match import SimulatedMatch, calibrated_match
from beams_thesis.match_replay import match_fixes, replay_match

POSE = (1.2, 0.8, 0.3)
START_MATCH = np.diag(np.square((0.01, 0.01, math.radians(1.0))))
START = np.diag([0.02**2, 0.02**2, math.radians(1.0) ** 2])
VARIANCE_RAD2 = math.radians(0.1) ** 2
INTEGRITY = Integrity.default()


def _biased(match: SimulatedMatch, beacon_id: int, bias_rad: float) -> SimulatedMatch:
    revolutions = [
        replace(
            r,
            bearings=[
                replace(b, bearing=b.bearing + bias_rad) if b.beacon_id == beacon_id else b
                for b in r.bearings
            ],
        )
        for r in match.revolutions
    ]
    return replace(match, revolutions=revolutions)


def _localiser() -> Localiser:
    """Initialised by ToTal; the odometry says the robot stands still."""
    localiser = build_localiser(EUROBOT_BEACON_MAP.as_dict(), (0.0, 0.0), FilterSettings())
    localiser.on_odometry(0.0, (0.0, 0.0, 0.0))
    localiser.on_pose(planar_pose_intake(PoseSource.TOTAL, 0.0, POSE, START))
    return localiser


def _bearing(beacon_id: int, stamp_s: float, pose: Pose2D = POSE, error_rad: float = 0.0) -> Bearing:
    bearing, _ = bearing_measurement(pose, EUROBOT_BEACON_MAP.as_dict()[beacon_id], (0.0, 0.0, 0.0))
    return Bearing(stamp_s, beacon_id, bearing + error_rad, VARIANCE_RAD2)


def _revolution(localiser: Localiser, ids, stamp_s: float, errors=None) -> None:
    errors = errors or {}
    localiser.on_odometry(stamp_s + 0.1, (0.0, 0.0, 0.0))
    bearings = [_bearing(b, stamp_s + 0.03 * k, error_rad=errors.get(b, 0.0)) for k, b in enumerate(ids)]
    localiser.on_bearings(revolution_of(localiser, bearings))


def test_a_beacons_first_hypothesis_is_the_filter_without_its_bearing():
    localiser = _localiser()
    localiser.separations = BeaconSeparations(0)  # from the initialisation on
    _revolution(localiser, (1, 2), 0.0)
    localiser.on_odometry(0.1 + 0.1, (0.0, 0.0, 0.0))  # the odometry that covers the next revolution
    before = localiser.estimate()
    _revolution(localiser, (3,), 0.1, {3: math.radians(0.2)})
    after = localiser.estimate()
    assert after.fault_shifts.shape == (3, 3) and after.fault_covariances.shape == (3, 3, 3)
    assert after.fault_shifts[2] == pytest.approx(np.subtract(after.pose, before.pose), abs=1e-12)
    assert after.fault_covariances[2] == pytest.approx(before.covariance, rel=1e-9, abs=1e-15)
    level = INTEGRITY.level(after.covariance, after.fault_shifts, after.fault_covariances)
    fault_free = INTEGRITY.level(after.covariance)
    assert level.faults_covered and not fault_free.faults_covered
    assert level.horizontal_m > fault_free.horizontal_m and level.heading_rad > fault_free.heading_rad


@pytest.mark.parametrize("bias_deg", [0.0, 0.3])
def test_a_beacons_separation_follows_the_filter_run_without_it(bias_deg):
    """A moving robot, beacon 2's bearings biased from the start (inside the gate): its hypothesis's shift
    and covariance are those of a filter that never had its bearings, to first order (the beacon exclusion
    off: it would undo the pull in one of them)."""
    settings = FilterSettings(localiser=LocaliserConfig(exclusion_gated_bearings=0))
    match = calibrated_match("thesis_hardware", 12.0, 3)
    faulty = _biased(match, 2, math.radians(bias_deg))
    without = replace(
        faulty,
        revolutions=[
            replace(r, bearings=[b for b in r.bearings if b.beacon_id != 2]) for r in faulty.revolutions
        ],
    )
    runs = []
    for m in (faulty, without):
        localiser = build_localiser(EUROBOT_BEACON_MAP.as_dict(), m.turret_offset_m, settings)
        localiser.separations = BeaconSeparations(0)
        replay_match(localiser, m, m.initial_pose, START_MATCH, match_fixes(m)[:1])
        runs.append((localiser.estimate(), localiser.separations.beacons))
    (full, beacons), (alone, _) = runs
    row = beacons.index(2)
    separation = np.subtract(full.pose, alone.pose)
    lacking = full.fault_covariances[row][:2, :2]
    assert np.trace(lacking) == pytest.approx(np.trace(alone.covariance[:2, :2]), rel=0.3)
    # within a quarter of the separation, or of its spread when there is no fault (half a millimetre)
    off = np.hypot(*(full.fault_shifts[row] - separation)[:2])
    assert off < 0.25 * np.hypot(*separation[:2]) + 0.5 * np.sqrt(np.trace(lacking))
    assert abs(full.fault_shifts[row][2] - separation[2]) < 0.25 * abs(separation[2]) + 0.5 * np.sqrt(
        full.fault_covariances[row][2, 2]
    )


def _level_after(ids, revolutions: int = 10):
    localiser = _localiser()
    for k in range(revolutions):
        _revolution(localiser, ids, 0.1 * k)
    estimate = localiser.estimate()
    return INTEGRITY.level(estimate.covariance, estimate.fault_shifts, estimate.fault_covariances)


def test_the_level_falls_as_beacons_are_added():
    """A still robot: two beacons leave the position along one direction unobserved (the
    start's 2 cm: above the 5 cm alert limit), three to about a centimetre (each solution without one of
    them keeps the first revolution's uncertainty along one direction)."""
    one, two, three = _level_after((1,)), _level_after((1, 2)), _level_after((1, 2, 3))
    assert one.horizontal_m >= two.horizontal_m > three.horizontal_m
    assert one.heading_rad >= two.heading_rad > three.heading_rad
    assert INTEGRITY.problem(two) and not INTEGRITY.problem(three)
    assert three.horizontal_m < 0.02
