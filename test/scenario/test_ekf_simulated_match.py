"""Issue 5 targets on the full offline pipeline (beams_sim.simulated_match: trajectory, edge-level
sensor, decoder with the exact variance, drifting odometry): RMS position <= 1 cm, heading <= 0.3 deg,
NEES in its 95% band >= 90% of the time, far better than odometry alone."""

import math

import numpy as np
import pytest

from beams_common.geometry.pose2d import compose
from beams_ekf.bearing_ekf import BearingEkf
from beams_ekf.localiser import Localiser
from beams_sim.simulated_match import SimulatedMatch, simulate_match
from beams_thesis.match_replay import bearing_events
from beams_thesis.replay import Accuracy, ReplayResult, accuracy, replay


@pytest.fixture(scope="module")
def match() -> SimulatedMatch:
    return simulate_match(30.0, seed=7, turret_offset_m=(0.02, -0.01))


@pytest.fixture(scope="module")
def result(match) -> ReplayResult:
    beacons = dict(zip(match.beacon_map.ids, map(tuple, match.beacon_map.xy), strict=True))
    o = match.odometry
    x, y, theta = match.initial_pose
    # start one ToTal-sized error away from the truth
    return replay(
        Localiser(BearingEkf(beacons, match.turret_offset_m)),
        o.stamp_s,
        np.column_stack([o.x_m, o.y_m, o.theta_rad]),
        bearing_events(match.revolutions),
        match.truth_at,
        (x + 0.01, y - 0.01, theta + math.radians(1.0)),
        np.diag([1e-4, 1e-4, math.radians(1.0) ** 2]),
    )


@pytest.fixture(scope="module")
def figures(result) -> Accuracy:
    return accuracy(result)


def test_accuracy_targets(figures):
    assert figures.rms_position_m <= 0.01
    assert math.degrees(figures.rms_heading_rad) <= 0.3
    assert figures.max_position_m < 0.03


def test_consistency_target(figures):
    assert figures.nees_in_band >= 0.9


def test_nearly_every_bearing_is_used(match, result):
    published = sum(len(r.bearings) for r in match.revolutions)
    assert result.counts["bearings_accepted"] >= 0.97 * published


def test_filter_beats_odometry_alone(match, figures):
    o = match.odometry
    placed = [compose(match.initial_pose, pose) for pose in zip(o.x_m, o.y_m, o.theta_rad, strict=True)]
    errors = [
        math.hypot(p[0] - match.truth_at(t)[0], p[1] - match.truth_at(t)[1])
        for p, t in zip(placed, o.stamp_s, strict=True)
    ]
    assert math.sqrt(np.mean(np.square(errors))) > 5 * figures.rms_position_m
