"""The localiser on synthetic matches: accuracy and consistency against ground truth, late and out-of-order
bearings, initialisation, kidnapping, time jumps and odometry gaps."""

from itertools import groupby
from math import hypot

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.bearing import Bearing
from beams_common.geometry.pose2d import compose
from beams_common.intake.bearing_intake import BearingRefusal
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake
from beams_ekf.bearing_ekf import BearingEkf
from beams_ekf.localiser import Localiser, LocaliserConfig, revolution_of
from beams_thesis.replay import accuracy, replay
from beams_thesis.synthetic import SyntheticMatch, synthetic_match

EUROBOT_BEACONS = EUROBOT_BEACON_MAP.as_dict()

OFFSET = (0.03, -0.01)
START_COVARIANCE = np.diag([1e-6, 1e-6, 1e-6])


@pytest.fixture(scope="module")
def match() -> SyntheticMatch:
    return synthetic_match(20.0, seed=5, sensor_offset_m=OFFSET)


def _localiser(config: LocaliserConfig | None = None) -> Localiser:
    return Localiser(BearingEkf(EUROBOT_BEACONS, OFFSET), config)


def _bearings(localiser: Localiser, bearings: list[Bearing]):
    """Bearings through the localiser's bearing door (the intake's rules, as ekf_node's)."""
    return localiser.on_bearings(revolution_of(localiser, bearings))


def _pose(localiser: Localiser, stamp_s: float, pose, covariance, *, operator: bool):
    """A pose through the localiser's pose door (the pose intake, as ekf_node's)."""
    source = PoseSource.OPERATOR if operator else PoseSource.TOTAL
    return localiser.on_pose(planar_pose_intake(source, stamp_s, pose, covariance))


def _revolutions(match: SyntheticMatch):
    """(arrival_s, [Bearing]) per revolution."""
    for arrival_s, group in groupby(match.bearings, key=lambda b: b.arrival_s):
        yield arrival_s, [Bearing(b.stamp_s, b.beacon_id, b.bearing_rad, b.variance_rad2) for b in group]


def _drive(
    localiser: Localiser,
    match: SyntheticMatch,
    start_s: float,
    stop_s: float,
    *,
    bearings=None,
    pose_source=None,
    skip_odometry=lambda t: False,
) -> None:
    """Feed odometry and revolutions arriving in [start_s, stop_s); optionally offer a pose per revolution."""
    times = match.times_s
    k = int(np.searchsorted(times, start_s))
    for arrival_s, revolution in bearings if bearings is not None else _revolutions(match):
        if not start_s <= arrival_s < stop_s:
            continue
        while k < len(times) and times[k] <= arrival_s:
            if not skip_odometry(times[k]):
                localiser.on_odometry(float(times[k]), tuple(match.odometry[k]))
            k += 1
        _bearings(localiser, revolution)
        if pose_source is not None:
            stamp_s = revolution[-1].stamp_s
            _pose(localiser, stamp_s, pose_source(stamp_s), np.diag([1e-4, 1e-4, 1e-3]), operator=False)


def _position_error(localiser: Localiser, truth) -> float:
    estimate = localiser.estimate()
    true_pose = truth(estimate.stamp_s)
    return hypot(estimate.pose[0] - true_pose[0], estimate.pose[1] - true_pose[1])


def test_accuracy_and_consistency_on_a_synthetic_match(match):
    result = replay(
        _localiser(),
        match.times_s,
        match.odometry,
        match.bearings,
        match.truth_at,
        tuple(match.truth[0]),
        START_COVARIANCE,
    )
    figures = accuracy(result)
    assert figures.rms_position_m < 0.004
    assert np.degrees(figures.rms_heading_rad) < 0.1
    assert figures.nees_in_band >= 0.9
    assert result.counts["bearings_accepted"] >= 0.98 * len(match.bearings)


def test_odometry_alone_drifts_far_more_than_the_filter(match):
    # odometry composed on the true start pose: its error grows with the drift (2% scale, 1% rotation)
    odometry_in_map = [compose(tuple(match.truth[0]), tuple(p)) for p in match.odometry]
    final = odometry_in_map[-1]
    final_error = hypot(final[0] - match.truth[-1][0], final[1] - match.truth[-1][1])
    assert final_error > 0.03


def test_arrival_order_of_bearings_does_not_change_the_estimate(match):
    batched, one_by_one = _localiser(), _localiser()
    for localiser in (batched, one_by_one):
        _pose(localiser, 0.0, tuple(match.truth[0]), START_COVARIANCE, operator=True)
    k = 0
    for arrival_s, revolution in _revolutions(match):
        if arrival_s > 3.0:
            break
        while match.times_s[k] <= arrival_s:
            for localiser in (batched, one_by_one):
                localiser.on_odometry(float(match.times_s[k]), tuple(match.odometry[k]))
            k += 1
        _bearings(batched, revolution)
        for bearing in reversed(revolution):
            _bearings(one_by_one, [bearing])
    np.testing.assert_allclose(batched.estimate().pose, one_by_one.estimate().pose, atol=1e-12)
    np.testing.assert_allclose(batched.estimate().covariance, one_by_one.estimate().covariance, atol=1e-15)


def test_bearings_before_initialisation_are_counted_and_toal_initialises(match):
    localiser = _localiser()
    _drive(localiser, match, 0.0, 1.0)
    assert localiser.estimate() is None
    assert localiser.stats.counts["bearings_uninitialised"] == 27
    _drive(localiser, match, 1.0, 6.0, pose_source=match.truth_at)
    assert localiser.stats.counts["initialisations"] == 1
    assert _position_error(localiser, match.truth_at) < 0.005


def test_kidnapped_robot_is_reinitialised_from_a_confident_far_fix(match):
    shift = np.array([0.5, -0.3])
    # moving every beacon by -shift is what the turret sees when the robot is carried by +shift
    moved = {i: (x - shift[0], y - shift[1]) for i, (x, y) in EUROBOT_BEACONS.items()}
    kidnapped = synthetic_match(20.0, seed=5, sensor_offset_m=OFFSET, beacons_xy=moved)
    carried = lambda t: tuple(np.add(match.truth_at(t), (*shift, 0.0)))  # noqa: E731

    localiser = _localiser()
    _pose(localiser, 0.0, tuple(match.truth[0]), START_COVARIANCE, operator=True)
    _drive(localiser, match, 0.0, 8.0, pose_source=match.truth_at)
    assert localiser.stats.counts["kidnap_reinitialisations"] == 0
    assert _position_error(localiser, match.truth_at) < 0.005

    _drive(localiser, match, 8.0, 14.0, bearings=list(_revolutions(kidnapped)), pose_source=carried)
    assert localiser.stats.counts["bearings_gated"] >= LocaliserConfig().kidnap_gated_bearings
    assert localiser.stats.counts["kidnap_reinitialisations"] == 1
    assert _position_error(localiser, carried) < 0.005


def test_near_fix_does_not_reinitialise(match):
    localiser = _localiser()
    _pose(localiser, 0.0, tuple(match.truth[0]), START_COVARIANCE, operator=True)
    _drive(localiser, match, 0.0, 3.0, pose_source=lambda t: tuple(np.add(match.truth_at(t), (0.02, 0, 0))))
    assert localiser.stats.counts["initialisations"] == 1
    assert localiser.stats.counts["kidnap_reinitialisations"] == 0


def test_operator_pose_always_reinitialises(match):
    localiser = _localiser()
    _pose(localiser, 0.0, tuple(match.truth[0]), START_COVARIANCE, operator=True)
    _drive(localiser, match, 0.0, 2.0)
    assert _pose(localiser, 2.0, (0.5, 0.5, 1.0), np.eye(3) * 1e-4, operator=True) == "initialisations"
    assert localiser.estimate().pose[:2] != pytest.approx(match.truth_at(2.0)[:2], abs=0.1)


def test_time_going_backwards_resets_cleanly(match):
    localiser = _localiser()
    _pose(localiser, 0.0, tuple(match.truth[0]), START_COVARIANCE, operator=True)
    _drive(localiser, match, 0.0, 5.0)
    # the bag loops: odometry starts again at t = 0 (the first message back is held: it may be a stray)
    assert localiser.on_odometry(0.0, tuple(match.odometry[0])) == "held"
    assert localiser.estimate() is not None
    assert localiser.on_odometry(float(match.times_s[1]), tuple(match.odometry[1])) == "reference"
    assert localiser.stats.counts["time_jump_resets"] == 1
    assert localiser.estimate() is None
    assert len(localiser.history) == 1
    _drive(localiser, match, 0.0, 5.0, pose_source=match.truth_at)
    assert localiser.stats.counts["initialisations"] == 2
    assert _position_error(localiser, match.truth_at) < 0.005


def test_map_to_odom_puts_the_odometry_pose_on_the_estimate(match):
    """REP-105's map -> odom: composed with the odometry pose at the estimate's instant, the estimate;
    after a drifting drive it is no longer the identity (it corrects the drift)."""
    from beams_common.geometry.pose2d import compose

    localiser = _localiser()
    _pose(localiser, 0.0, tuple(match.truth[0]), START_COVARIANCE, operator=True)
    assert localiser.estimate().map_to_odom is None  # no odometry yet
    _drive(localiser, match, 0.0, 4.0)
    estimate = localiser.estimate()
    k = int(np.searchsorted(match.times_s, estimate.stamp_s))
    assert estimate.odom_pose == tuple(match.odometry[k])
    assert compose(estimate.map_to_odom, estimate.odom_pose) == pytest.approx(estimate.pose, abs=1e-12)
    assert hypot(*estimate.map_to_odom[:2]) > 0.3  # the match starts away from the map's origin


def test_one_stray_odometry_message_from_the_past_changes_nothing(match):
    """A message stamped 3 s in the past between good ones (a second publisher, a late retransmission)
    is dropped and counted; the estimate goes on as if it had never come."""
    localiser, undisturbed = _localiser(), _localiser()
    for each in (localiser, undisturbed):
        _pose(each, 0.0, tuple(match.truth[0]), START_COVARIANCE, operator=True)
        _drive(each, match, 0.0, 5.0)
    assert localiser.on_odometry(2.0, (9.0, 9.0, 3.0)) == "held"
    for each in (localiser, undisturbed):
        _drive(each, match, 5.0, 8.0)
    assert localiser.stats.counts["odometry_back_in_time"] == 1
    assert localiser.stats.counts["time_jump_resets"] == 0
    assert localiser.estimate().pose == undisturbed.estimate().pose
    assert _position_error(localiser, match.truth_at) < 0.005


def test_odometry_gap_inflates_the_covariance_and_the_filter_recovers(match):
    localiser = _localiser()
    _pose(localiser, 0.0, tuple(match.truth[0]), START_COVARIANCE, operator=True)
    _drive(localiser, match, 0.0, 5.0)
    before = np.trace(localiser.estimate().covariance[:2, :2])
    in_gap = lambda t: 5.0 <= t < 7.0  # noqa: E731
    _drive(localiser, match, 5.0, 7.05, skip_odometry=in_gap)
    estimate = localiser.estimate()
    assert np.all(np.isfinite(estimate.covariance)) and all(np.isfinite(estimate.pose))
    assert localiser.stats.counts["odometry_gaps"] == 1
    assert localiser.stats.counts["bearings_outside_history"] > 0
    assert np.trace(estimate.covariance[:2, :2]) > before
    _drive(localiser, match, 7.05, 10.0)
    assert _position_error(localiser, match.truth_at) < 0.005


@pytest.mark.parametrize("bad", [(float("nan"), 0.0, 0.0), (0.0, float("inf"), 0.0)])
def test_non_finite_inputs_never_reach_the_state(match, bad):
    localiser = _localiser()
    _pose(localiser, 0.0, tuple(match.truth[0]), START_COVARIANCE, operator=True)
    _drive(localiser, match, 0.0, 1.0)
    before = localiser.estimate().pose
    assert localiser.on_odometry(1.5, bad) == "invalid"
    assert _pose(localiser, 1.5, bad, np.eye(3), operator=True) == "invalid"
    intake = revolution_of(localiser, [Bearing(0.95, 1, float("nan"), 1e-6)])
    assert [r.refusal for r in intake.refused] == [BearingRefusal.INVALID_MEASUREMENT]
    assert localiser.on_bearings(intake) == []
    assert localiser.stats.counts["bearings_invalid_measurement"] == 1
    assert localiser.estimate().pose == before


def test_heading_error_stays_small_through_a_wrap_of_pi(match):
    # the synthetic trajectory crosses heading +-pi several times in 20 s
    headings = match.truth[:, 2]
    assert np.any(np.abs(np.diff(headings)) > np.pi)
    result = replay(
        _localiser(),
        match.times_s,
        match.odometry,
        match.bearings,
        match.truth_at,
        tuple(match.truth[0]),
        START_COVARIANCE,
    )
    assert max(abs(wrap_to_pi(float(e))) for e in result.errors()[:, 2]) < np.radians(0.5)


_events = st.lists(
    st.one_of(
        st.tuples(st.just("odometry"), st.floats(-0.5, 3.0), st.floats(-0.05, 0.05), st.floats(-0.3, 0.3)),
        st.tuples(st.just("bearing"), st.floats(-0.5, 3.0), st.integers(0, 4), st.floats(-4.0, 4.0)),
        st.tuples(st.just("pose"), st.floats(-0.5, 3.0), st.floats(-1.0, 4.0), st.floats(-4.0, 4.0)),
        st.tuples(st.just("gap"), st.floats(0.0, 30.0), st.just(0.0), st.just(0.0)),
    ),
    max_size=60,
)


@settings(max_examples=60, deadline=None)
@given(_events)
def test_any_sequence_of_inputs_keeps_the_estimate_finite(events):
    """Time jumps both ways, gaps, unknown beacons, wild poses: never an exception, never a NaN."""
    localiser = _localiser()
    clock_s, odometry = 0.0, (0.0, 0.0, 0.0)
    for kind, a, b, c in events:
        if kind == "odometry":
            # mostly forward in steps of 20 ms, sometimes back (a bag loop)
            clock_s = clock_s + 0.02 if a > 0.0 else a
            odometry = compose(odometry, (b, 0.0, c))
            localiser.on_odometry(clock_s, odometry)
        elif kind == "bearing":
            _bearings(localiser, [Bearing(clock_s - 0.05 * a, b, c, 1e-6)])
        elif kind == "pose":
            _pose(localiser, clock_s - 0.1 * a, (b, 1.0, c), np.diag([1e-4, 1e-4, 1e-3]), operator=a > 2.5)
        else:
            clock_s += a
        estimate = localiser.estimate()
        if estimate is not None:
            assert all(np.isfinite(estimate.pose)) and np.all(np.isfinite(estimate.covariance))
            assert np.all(np.linalg.eigvalsh(estimate.covariance) > 0.0)


def test_bearings_ahead_of_odometry_wait_for_it(match):
    """Bearings published before the odometry of their instant arrived give the same estimate."""
    # no extrapolation: every bearing ahead of the odometry has to wait
    in_order, early = (_localiser(LocaliserConfig(max_odometry_extrapolation_s=0.0)) for _ in range(2))
    for localiser in (in_order, early):
        _pose(localiser, 0.0, tuple(match.truth[0]), START_COVARIANCE, operator=True)
    revolutions = [r for a, r in _revolutions(match) if a < 2.0]
    k = r = 0
    outcomes = []
    for t, pose in zip(match.times_s, match.odometry, strict=True):
        if t > 2.0:
            break
        # `early` gets each revolution as soon as its first bearing's instant is reached
        while r < len(revolutions) and min(b.stamp_s for b in revolutions[r]) <= t:
            outcomes += _bearings(early, revolutions[r])
            r += 1
        in_order.on_odometry(float(t), tuple(pose))
        early.on_odometry(float(t), tuple(pose))
        while k < len(revolutions) and max(b.stamp_s for b in revolutions[k]) <= t:
            _bearings(in_order, revolutions[k])
            k += 1
    deferred = sum(o.reason == "deferred" for o in outcomes)
    assert deferred > 20 and early.stats.counts["bearings_deferred"] == deferred
    np.testing.assert_allclose(early.estimate().pose, in_order.estimate().pose, atol=1e-12)


def test_a_bearing_kept_from_before_the_first_state_leaves_once_the_history_no_longer_covers_it() -> None:
    """Found by the fault campaign (ekf_node died with a TypeError): a bearing stamped before the filter's
    first state is applied at that state and kept there for re-filtering; once the odometry history is
    trimmed past its stamp, a later bearing in the same interval re-filters the slot. The old bearing must
    leave the slot (it can no longer be placed), the new one must still be applied, nothing raises."""
    pose = (1.0, 1.0, 0.3)
    sensor = compose(pose, (*OFFSET, 0.0))

    def bearing(stamp_s: float, beacon_id: int) -> Bearing:
        bx, by = EUROBOT_BEACONS[beacon_id]
        direction = np.arctan2(by - sensor[1], bx - sensor[0]) - pose[2]
        return Bearing(stamp_s, beacon_id, float(wrap_to_pi(direction)), 1e-6)

    localiser = _localiser(LocaliserConfig(odometry_history_s=0.5))
    stamps = np.round(np.arange(0.0, 0.52, 0.02), 6)
    for stamp_s in stamps:
        localiser.on_odometry(float(stamp_s), pose)
    _pose(localiser, 0.5, pose, START_COVARIANCE, operator=True)
    first = _bearings(localiser, [bearing(0.1, 1)])  # before the first state: applied there
    assert first[0].accepted
    for stamp_s in np.round(np.arange(0.52, 0.9, 0.02), 6):  # the history now starts after 0.1 s
        localiser.on_odometry(float(stamp_s), pose)
    assert localiser.pose_at(0.1) is None
    late = _bearings(localiser, [bearing(0.51, 2)])  # the slot of 0.5 s is filtered again
    assert late[0].accepted, late[0].reason
    estimate = localiser.estimate()
    assert estimate is not None and hypot(estimate.pose[0] - pose[0], estimate.pose[1] - pose[1]) < 1e-3
