"""The localiser fed as ekf_node is live: messages in arrival order with the delays of the running system
(odometry at 50 Hz, a revolution's bearings published when it ends, up to 0.1 s after their stamps,
ToTal's fix stamped at the revolution's middle and arriving ~0.1 s later), the node starting while the
robot moves. Issue 5: live, the filter initialised from a fix older than its odometry history as if it
were current, sat 0.22 m and 7 deg off with ToTal's 1 mm covariance, gated two bearings in three, and
the kidnap recovery never fired."""

from dataclasses import dataclass
from math import hypot

import numpy as np
import pytest

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.bearing import Bearing
from beams_common.geometry.pose2d import Pose2D
from beams_common.intake.pose_intake import PoseIntake, PoseSource, planar_pose_intake
from beams_ekf.bearing_ekf import BearingEkf
from beams_ekf.localiser import Localiser, LocaliserConfig, revolution_of
from beams_thesis.synthetic import SyntheticMatch, synthetic_match

EUROBOT_BEACONS = EUROBOT_BEACON_MAP.as_dict()

OFFSET = (0.03, -0.01)
DRIVER_DELAY_S = 0.005  # a revolution is published this long after it ends
TOTAL_DELAY_S = 0.05  # ToTal's fix arrives this long after the revolution (stamped at its middle)
ODOMETRY_DELAY_S = 0.001
TOTAL_SIGMA = (0.002, 0.002, 0.0007)  # ToTal's error (m, m, rad) as measured live (3 mm RMS)
# ToTal's published covariance: smaller than its real error, as live (the filter must cope with it)
TOTAL_COVARIANCE = np.diag([1e-6, 1e-6, 2e-7])
SETTLE_S = 0.5


@dataclass(frozen=True)
class Arrival:
    """One message as the node receives it."""

    arrival_s: float
    kind: str  # "odometry", "bearings" or "pose"
    payload: object


@pytest.fixture(scope="module")
def match() -> SyntheticMatch:
    return synthetic_match(10.0, seed=7, sensor_offset_m=OFFSET)


def live_stream(match: SyntheticMatch, seed: int = 3) -> list[Arrival]:
    """Every message of the match in arrival order (ties: odometry, then bearings, then poses)."""
    rng = np.random.default_rng(seed)
    arrivals = [
        Arrival(float(t) + ODOMETRY_DELAY_S, "odometry", (float(t), tuple(pose)))
        for t, pose in zip(match.times_s, match.odometry, strict=True)
    ]
    revolutions: dict[float, list[Bearing]] = {}
    for b in match.bearings:
        revolutions.setdefault(b.arrival_s, []).append(
            Bearing(b.stamp_s, b.beacon_id, b.bearing_rad, b.variance_rad2)
        )
    for end_s, bearings in revolutions.items():
        arrivals.append(Arrival(end_s + DRIVER_DELAY_S, "bearings", bearings))
        stamp_s = end_s - 0.05  # the revolution's middle
        fix = np.add(match.truth_at(stamp_s), rng.normal(0.0, TOTAL_SIGMA))
        arrivals.append(Arrival(end_s + DRIVER_DELAY_S + TOTAL_DELAY_S, "pose", (stamp_s, tuple(fix))))
    order = {"odometry": 0, "bearings": 1, "pose": 2}
    return sorted(arrivals, key=lambda a: (a.arrival_s, order[a.kind]))


def feed(
    localiser: Localiser, stream: list[Arrival], start_s: float, stop_s: float = float("inf"), truth_at=None
) -> list[tuple[float, float, float]]:
    """Deliver the messages arriving in [start_s, stop_s); (time, position error, heading error) after
    each odometry once initialised, when `truth_at` is given."""
    errors = []
    for arrival in stream:
        if not start_s <= arrival.arrival_s < stop_s:
            continue
        if arrival.kind == "odometry":
            localiser.on_odometry(*arrival.payload)
        elif arrival.kind == "bearings":
            localiser.on_bearings(revolution_of(localiser, arrival.payload))
        else:
            localiser.on_pose(_fix(*arrival.payload))
        estimate = localiser.estimate()
        if truth_at is not None and arrival.kind == "odometry" and estimate is not None:
            error = _error(estimate.pose, truth_at(estimate.stamp_s))
            errors.append((estimate.stamp_s, *error))
    return errors


def _fix(stamp_s: float, pose: Pose2D, source: PoseSource = PoseSource.TOTAL) -> PoseIntake:
    """A pose with ToTal's covariance through the pose intake (an operator's with `source`)."""
    return planar_pose_intake(source, stamp_s, pose, TOTAL_COVARIANCE)


def _error(pose: Pose2D, truth: Pose2D) -> tuple[float, float]:
    return hypot(pose[0] - truth[0], pose[1] - truth[1]), abs(wrap_to_pi(pose[2] - truth[2]))


def _localiser() -> Localiser:
    return Localiser(BearingEkf(EUROBOT_BEACONS, OFFSET), LocaliserConfig())


def _rms_after_settling(errors: list[tuple[float, float, float]]) -> tuple[float, float]:
    rows = np.array(errors)
    rows = rows[rows[:, 0] >= rows[0, 0] + SETTLE_S]
    return float(np.sqrt(np.mean(rows[:, 1] ** 2))), float(np.sqrt(np.mean(rows[:, 2] ** 2)))


def test_live_stream_delays_are_those_of_the_running_system(match):
    """The stream itself: bearings up to 0.1 s late, fixes ~0.1 s after their stamps, 50 Hz odometry."""
    stream = live_stream(match)
    bearing_delays = [a.arrival_s - b.stamp_s for a in stream if a.kind == "bearings" for b in a.payload]
    pose_delays = [a.arrival_s - a.payload[0] for a in stream if a.kind == "pose"]
    assert 0.09 < max(bearing_delays) <= 0.1 + DRIVER_DELAY_S and min(bearing_delays) > 0.0
    assert pose_delays == pytest.approx([0.05 + DRIVER_DELAY_S + TOTAL_DELAY_S] * len(pose_delays))
    odometry_times = [a.payload[0] for a in stream if a.kind == "odometry"]
    assert np.diff(odometry_times) == pytest.approx(0.02)


# node starts: with the match (its first fix covered by odometry); 1 ms before the odometry sample that
# precedes a fix stamped 0.1 s earlier (the live failure: the fix predates the whole history); between
# that odometry and the fix; and just before a fix, with no odometry at all yet
@pytest.mark.parametrize("start_s", [0.0, 2.0395, 2.0445, 2.0545])
def test_node_started_mid_match_initialises_at_the_right_place(match, start_s):
    localiser = _localiser()
    errors = feed(localiser, live_stream(match), start_s, truth_at=match.truth_at)
    counts = localiser.stats.counts
    assert counts["initialisations"] == 1 and counts["kidnap_reinitialisations"] == 0
    # the first estimate is already right (ToTal's error, a few mm), not 0.1 s of motion away
    assert errors[0][1] < 0.01 and errors[0][2] < np.radians(0.3)
    rms_position_m, rms_heading_rad = _rms_after_settling(errors)
    assert rms_position_m < 0.005 and np.degrees(rms_heading_rad) < 0.15
    assert counts["bearings_gated"] <= 0.01 * counts["bearings_accepted"]


def test_fix_older_than_the_odometry_history_does_not_initialise(match):
    localiser = _localiser()
    assert localiser.on_pose(_fix(1.0, match.truth_at(1.0))) == "outside_history"
    localiser.on_odometry(1.1, (0.0, 0.0, 0.0))
    assert localiser.on_pose(_fix(1.0, match.truth_at(1.0))) == "outside_history"
    assert localiser.stats.counts["poses_outside_history"] == 2 and localiser.estimate() is None
    # an operator's pose has no meaningful stamp: it is taken as current
    assert localiser.on_pose(_fix(1.0, (1.0, 1.0, 0.0), PoseSource.OPERATOR)) == "initialisations"
    assert localiser.estimate().pose == (1.0, 1.0, 0.0)


@pytest.mark.parametrize("wrong", [(-0.22, 0.02, 0.115), (0.05, -0.03, -0.02), (0.6, 0.4, 0.0)])
def test_lost_filter_is_reinitialised_by_a_confident_fix(match, wrong):
    """Started confidently wrong (the live failure: 0.22 m and 6.6 deg, closer than any absolute
    threshold, with bearings still accepted now and then), the filter gates most bearings, and the
    first consistent ToTal fix re-initialises it."""
    stream = live_stream(match)
    localiser = _localiser()
    feed(localiser, [a for a in stream if a.kind == "odometry"], 0.0, 1.0)
    stamp_s = localiser.history.latest[0]
    localiser.on_pose(_fix(stamp_s, tuple(np.add(match.truth_at(stamp_s), wrong)), PoseSource.OPERATOR))
    errors = feed(localiser, stream, 1.0, 4.0, truth_at=match.truth_at)
    counts = localiser.stats.counts
    # one restart, by whichever test fires first: the kidnap test or the lost (NIS) test
    assert counts["kidnap_reinitialisations"] + counts["lost_reinitialisations"] == 1
    # the lost test needs at least three bearings at the gate (3 x 10.8 > 30.7, chi-square 3 dof at 1 - 1e-6)
    assert counts["bearings_gated"] >= min(3, LocaliserConfig().kidnap_gated_bearings)
    # recovered within half a second of ToTal's fixes, then tracking
    assert max(e[1] for e in errors if e[0] > 1.6) < 0.01
    assert _rms_after_settling([e for e in errors if e[0] > 1.6])[0] < 0.005


def test_wrong_fixes_do_not_pull_a_filter_whose_bearings_agree(match):
    """ToTal confidently 0.5 m off (a wrong fix) while the bearings keep being accepted: no re-init."""
    stream = live_stream(match)
    localiser = _localiser()
    feed(localiser, stream, 0.0, 3.0)
    assert localiser.stats.counts["initialisations"] == 1
    for arrival in stream:
        if 3.0 <= arrival.arrival_s < 6.0:
            if arrival.kind == "pose":
                stamp_s, fix = arrival.payload
                localiser.on_pose(_fix(stamp_s, (fix[0] + 0.5, fix[1], fix[2])))
            else:
                feed(localiser, [arrival], 3.0)
    assert localiser.stats.counts["kidnap_reinitialisations"] == 0
    assert not localiser.kidnap.suspected
    estimate = localiser.estimate()
    assert _error(estimate.pose, match.truth_at(estimate.stamp_s))[0] < 0.005
