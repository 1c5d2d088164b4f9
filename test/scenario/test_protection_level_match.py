"""The protection levels on a nominal simulated match (docs/protection_level.md's figures): the
thesis-hardware sensor after its calibration, default parameters. The EKF's level stays far within the
default 5 cm / 3 deg alert limits (the demo stays tracking) and its error never exceeds it; ToTal's
fault-free bound is within them on nearly every accepted pose; hiding a beacon raises the EKF's level."""

import math
from dataclasses import replace

import numpy as np
import pytest

from beams_common.status.protection_level import Integrity
from beams_ekf.localiser import FilterSettings, build_localiser
from beams_sim.simulated_match import SimulatedMatch, calibrated_match
from beams_thesis.match_replay import match_fixes, replay_match

SEEDS, DURATION_S, SETTLE_S = (0, 1), 30.0, 1.0
START_SIGMA = (0.01, 0.01, math.radians(1.0))
INTEGRITY = Integrity.default()


@pytest.fixture(scope="module")
def matches() -> list[SimulatedMatch]:
    return [calibrated_match("thesis_hardware", DURATION_S, seed) for seed in SEEDS]


def _replay(match: SimulatedMatch) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(times, position errors, protection levels (k, 2), ekf_node's status is tracking) after SETTLE_S."""
    beacons = dict(zip(match.beacon_map.ids, map(tuple, match.beacon_map.xy), strict=True))
    result = replay_match(
        build_localiser(beacons, match.turret_offset_m, FilterSettings()),
        match,
        match.initial_pose,
        np.diag(np.square(START_SIGMA)),
        match_fixes(match),
    )
    keep = result.times_s >= result.times_s[0] + SETTLE_S
    errors = result.errors()[keep]
    position = np.hypot(errors[:, 0], errors[:, 1])
    return result.times_s[keep], position, result.protection_levels[keep], result.tracking[keep]


def test_the_ekf_level_is_about_a_centimetre_and_bounds_the_error(matches):
    for match in matches:
        _, errors, levels, tracking = _replay(match)
        assert tracking.mean() > 0.99  # the levels far within the alert limits: the status stays tracking
        horizontal, heading = levels[:, 0], levels[:, 1]
        p50, p99 = 1e3 * np.percentile(horizontal, [50, 99])
        print(
            f"EKF HPL median {p50:.1f} mm, p99 {p99:.1f} mm; heading {np.degrees(np.median(heading)):.2f} deg"
        )
        assert np.median(horizontal) < 0.02 and np.percentile(horizontal, 99) < 0.03
        assert np.percentile(heading, 99) < math.radians(0.7)
        assert np.all(errors <= horizontal)


def test_total_fault_free_level_is_within_the_limit_on_nearly_every_pose(matches):
    for match in matches:
        levels = [INTEGRITY.level(fix.covariance) for fix in match_fixes(match)]
        horizontal = np.array([level.horizontal_m for level in levels])
        assert not any(level.faults_covered for level in levels)  # three bearings: no redundancy
        assert 0.01 < np.median(horizontal) < 0.025
        assert np.mean([INTEGRITY.within(level) for level in levels]) >= 0.95


def test_hiding_two_beacons_raises_the_ekf_level(matches):
    match = matches[0]
    hidden = [
        replace(r, bearings=[b for b in r.bearings if b.beacon_id == 3 or not 10.0 < b.stamp_s < 20.0])
        for r in match.revolutions
    ]
    times, errors, levels, _ = _replay(replace(match, revolutions=hidden))
    window = (times > 11.0) & (times < 20.0)
    nominal = _replay(match)[2]
    assert np.median(levels[window, 0]) > 2.0 * np.median(nominal[:, 0])
    assert np.all(errors <= levels[:, 0])
