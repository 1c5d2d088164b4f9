"""The localiser against implausible inputs (issue 18): an odometry jump is never followed, and no
operator pose that passes the covariance bound can wedge the filter."""

from itertools import groupby
from math import hypot

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.bearing import Bearing
from beams_common.intake.plausibility import MAX_POSE_SIGMA_M, MAX_POSE_SIGMA_RAD
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake, pose_covariance_problem
from beams_common.intake.validation import planar_estimate_problem
from beams_ekf.localiser import Localiser, build_localiser, revolution_of
from beams_ekf.outcomes import OdometryOutcome
from beams_ekf.settings import FilterSettings
from beams_thesis.synthetic import SyntheticMatch, synthetic_match

JUMP_AT_S = 3.0


@pytest.fixture(scope="module")
def match() -> SyntheticMatch:
    return synthetic_match(6.0, seed=5)


def _localiser() -> Localiser:
    return build_localiser(EUROBOT_BEACON_MAP.as_dict(), (0.0, 0.0), FilterSettings())


def _run(localiser: Localiser, match: SyntheticMatch, odometry_of, *, initial_covariance=None):
    """Feed the match (odometry through odometry_of(t, pose)); the estimates' position errors and the
    odometry outcomes."""
    start = float(match.times_s[0])
    localiser.on_odometry(start, tuple(match.odometry[0]))
    if initial_covariance is not None:
        localiser.on_pose(
            planar_pose_intake(PoseSource.OPERATOR, start, match.truth_at(start), initial_covariance)
        )
    errors, outcomes, invalid = [], [], 0
    k = 1
    for arrival_s, group in groupby(match.bearings, key=lambda b: b.arrival_s):
        while k < len(match.times_s) and match.times_s[k] <= arrival_s:
            t = float(match.times_s[k])
            outcomes.append(localiser.on_odometry(t, tuple(odometry_of(t, np.array(match.odometry[k])))))
            k += 1
        revolution = [Bearing(b.stamp_s, b.beacon_id, b.bearing_rad, b.variance_rad2) for b in group]
        localiser.on_bearings(revolution_of(localiser, revolution))
        estimate = localiser.estimate()
        if estimate is None:
            continue
        invalid += bool(planar_estimate_problem(estimate.pose, estimate.covariance))
        truth = match.truth_at(estimate.stamp_s)
        errors.append(hypot(estimate.pose[0] - truth[0], estimate.pose[1] - truth[1]))
    return np.array(errors), outcomes, invalid


def _shifted(t: float, pose: np.ndarray) -> np.ndarray:
    return pose + np.array([100.0, 0.0, 0.0]) if t > JUMP_AT_S else pose


def _spike(t: float, pose: np.ndarray) -> np.ndarray:
    return pose + np.array([0.0, -100.0, 2.0]) if JUMP_AT_S < t <= JUMP_AT_S + 0.02 else pose


@pytest.mark.parametrize("odometry_of", [_shifted, _spike], ids=["+100 m for good", "one sample off"])
def test_an_odometry_jump_is_refused_counted_and_never_followed(match, odometry_of):
    localiser = _localiser()
    errors, outcomes, invalid = _run(localiser, match, odometry_of, initial_covariance=np.diag([1e-4] * 3))
    jumps = outcomes.count(OdometryOutcome.JUMPED)
    assert jumps == (1 if odometry_of is _shifted else 2)  # a spike jumps there and back
    assert localiser.stats.counts["odometry_jumps"] == jumps
    assert "a jump, not motion" in localiser.last_odometry_jump
    # the issue's EKF was 35 m, then 77 m off; here the error stays at its usual millimetres
    assert errors.max() < 0.02, errors.max()
    assert invalid == 0


def test_a_total_fix_across_a_jump_is_not_carried_by_it(match):
    # before the filter is initialised the odometry history carries a fix to "now": a history across a
    # jump would move the fix by 100 m
    localiser = _localiser()
    for t, pose in zip(match.times_s[:200], match.odometry[:200], strict=True):
        localiser.on_odometry(float(t), tuple(_shifted(float(t), np.array(pose))))
    fix_s = float(match.times_s[148])  # 0.04 s before the jump
    localiser.on_pose(planar_pose_intake(PoseSource.TOTAL, fix_s, match.truth_at(fix_s), np.diag([1e-4] * 3)))
    estimate = localiser.estimate()
    assert (
        estimate is None or hypot(*np.subtract(estimate.pose[:2], match.truth_at(estimate.stamp_s)[:2])) < 0.1
    )


@settings(max_examples=15, deadline=None)
@given(
    st.floats(1e-8, MAX_POSE_SIGMA_M**2),
    st.floats(1e-8, MAX_POSE_SIGMA_RAD**2),
    st.floats(-0.99, 0.99),
)
def test_no_operator_covariance_within_the_bound_wedges_the_filter(match, position_var, heading_var, rho):
    covariance = np.diag([position_var, position_var, heading_var])
    covariance[0, 1] = covariance[1, 0] = rho * position_var
    assert pose_covariance_problem(covariance) == ""
    _, _, invalid = _run(_localiser(), match, lambda t, pose: pose, initial_covariance=covariance)
    assert invalid == 0


def test_the_issue_s_wedging_covariances_are_refused():
    for variance in (1e12, 1e300):
        assert "no information" in pose_covariance_problem(np.diag([variance, variance, 0.01]))
