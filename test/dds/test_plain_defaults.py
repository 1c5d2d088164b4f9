"""Issue 19 over DDS: the nodes with no parameter at all (`ros2 run` of each, as a new user starts them)
are honest. A moving robot (sim_world_node, driver_node, triangulation_node, ekf_node, every one with its
defaults) and, in namespace `still`, a robot standing still (sim_world_node told only `trajectory: static`,
driver_node with its defaults) run at once, each node its own process:

- the driver says it is uncalibrated: WARN "uncalibrated" on /diagnostics and `calibrated: false` on every
  beams/bearings message;
- the still robot's bearings spread as the driver's published variances say, within 0.7-1.43 per beacon;
- the EKF's mean NEES over 30 s of the match, 30-60 s after its first estimate, is within the band a
  consistent filter's falls in 99 % of the time (3 for a consistent filter; the power bias treated as
  white noise before issue 19 gave 37-42 over 30 s). One run's 30 s mean averages correlated samples:
  the self-calibrating filter's NEES has an integrated autocorrelation time of 3.2 s (pooled over 10
  matches, bench_self_calibration.py), 10.6 independent samples per 30 s, so the band is
  chi2(3 x 10.6) / 10.6's 1.41-5.29 (beams_thesis.nees_band; issue 19's 2.0-4.5 holds 91.5 % of a
  consistent filter's windows, too tight for one window tested in every `make test`). Runs on the
  loaded machine gave 2.10, 2.48, 2.58, 1.91 (a CPU-heavy replay beside it), 3.33, 4.25, 1.94.
  The first 30 s (for 10 s the power bias is not modelled yet: those bearings update the pose alone)
  vary more from run to run over DDS, 1.60, 2.03, 1.80, 14.64 (the same loaded run), 3.55, 5.27: held
  to 1.0-10 only (docs/self_calibration.md).
"""

import math

import numpy as np
import pytest

pytestmark = pytest.mark.dds

ROBOT_NODES = (
    ("beams_sim", "sim_world_node"),
    ("beams_driver", "driver_node"),
    ("beams_triangulation", "triangulation_node"),
    ("beams_ekf", "ekf_node"),
)

SPREAD_BAND = (0.7, 1.43)
NEES_WINDOW_S = 30.0
# independent samples in a 30 s mean of the self-calibrating filter's NEES (tau 3.18 s, BENCHMARKS.md's
# bench_self_calibration rows) and the probability its band holds for a consistent filter
SELF_CALIBRATING_SAMPLES_PER_WINDOW = 10.6
NEES_BAND_PROBABILITY = 0.99
WARM_UP_NEES_BAND = (1.0, 10.0)
# the EKF's first estimates need the nodes up and ToTal's first fix: bounded waits
START_TIMEOUT_S = 60.0
STILL_REVOLUTIONS = 200


def _row(msg) -> tuple[float, float, float, float, float]:
    from beams_common.ros.messages import pose2d_of, stamp_to_seconds

    x, y, theta = pose2d_of(msg.pose.pose)
    return (0.0, stamp_to_seconds(msg.header.stamp), x, y, theta)


def test_plain_defaults_are_honest(start_node, rclpy_node):
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry

    from beams_bringup.demo import nees_against_truth
    from beams_common.ros.messages import planar_covariance
    from beams_common.ros.node_support import BEARINGS_QOS
    from beams_msgs.msg import BeaconBearingArray
    from beams_thesis.nees_band import chi_square_mean_band

    graph = rclpy_node
    truth, ekf, covariances = [], [], []
    bearings, still_bearings, driver_statuses = [], [], []
    node = graph.node
    node.create_subscription(Odometry, "beams/sim/ground_truth", lambda m: truth.append(_row(m)), 100)

    def on_ekf(msg) -> None:
        ekf.append(_row(msg))
        covariances.append(planar_covariance(msg.pose.covariance))

    node.create_subscription(Odometry, "beams/ekf/odometry", on_ekf, 100)
    node.create_subscription(BeaconBearingArray, "beams/bearings", bearings.append, BEARINGS_QOS)
    node.create_subscription(BeaconBearingArray, "/still/beams/bearings", still_bearings.append, BEARINGS_QOS)

    def on_diagnostics(msg) -> None:
        driver_statuses.extend(s for s in msg.status if s.name == "/driver_node: driver")

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
    for package, executable in ROBOT_NODES:
        start_node(package, executable)  # no parameter at all
    start_node("beams_sim", "sim_world_node", {"trajectory": "static"}, "still")
    start_node("beams_driver", "driver_node", None, "still")

    assert graph.spin_until(lambda: len(ekf) > 0, START_TIMEOUT_S), "no EKF estimate"
    first_s = ekf[0][1]
    assert graph.spin_until(
        lambda: ekf[-1][1] >= first_s + 2.0 * NEES_WINDOW_S and len(still_bearings) >= STILL_REVOLUTIONS,
        2.0 * NEES_WINDOW_S + 30.0,
    ), f"EKF {ekf[-1][1] - first_s:.1f} s, still robot {len(still_bearings)} revolutions"

    # the driver says it is uncalibrated, on the topic and on /diagnostics
    assert bearings and not any(msg.calibrated for msg in bearings + still_bearings)
    warned = [s for s in driver_statuses if s.level == b"\x01" and "uncalibrated" in s.message]
    assert warned, [(s.level, s.message) for s in driver_statuses[-3:]]
    assert {kv.key: kv.value for kv in warned[-1].values}["calibrated"] == "False"

    # the still robot: spread / published variance per beacon
    by_beacon: dict[int, tuple[list[float], list[float]]] = {}
    for msg in still_bearings[10:]:  # the sim's first revolutions may precede its first pose
        for b in msg.bearings:
            by_beacon.setdefault(b.beacon_id, ([], []))
            by_beacon[b.beacon_id][0].append(b.bearing)
            by_beacon[b.beacon_id][1].append(b.variance)
    assert sorted(by_beacon) == [1, 2, 3]
    ratios = {k: float(np.var(v[0]) / np.mean(v[1])) for k, v in by_beacon.items()}
    print(f"still robot spread / published variance: {ratios}")
    assert all(SPREAD_BAND[0] <= r <= SPREAD_BAND[1] for r in ratios.values()), ratios

    # the moving robot: the EKF's mean NEES over 0-30 s and 30-60 s from its first estimate
    rows = np.array(ekf)
    means = []
    for start_s in (0.0, NEES_WINDOW_S):
        keep = (rows[:, 1] >= first_s + start_s) & (rows[:, 1] < first_s + start_s + NEES_WINDOW_S)
        chosen = [c for c, k in zip(covariances, keep, strict=True) if k]
        nees = nees_against_truth(rows[keep], chosen, np.array(truth))
        assert len(nees) > 100 and math.isfinite(nees.max())
        means.append(float(nees.mean()))
    print(f"EKF mean NEES over 0-30 s: {means[0]:.2f}, over 30-60 s: {means[1]:.2f}")
    assert WARM_UP_NEES_BAND[0] <= means[0] <= WARM_UP_NEES_BAND[1], means
    low, high = chi_square_mean_band(SELF_CALIBRATING_SAMPLES_PER_WINDOW, NEES_BAND_PROBABILITY)
    assert low <= means[1] <= high, (means, (low, high))


def test_save_calibration_writes_a_file_the_driver_reads(start_node, rclpy_node, tmp_path):
    """ekf_node's ~/save_calibration writes the learnt power bias as a chapter-7 calibration file (here
    nothing learnt yet: the prior, a zero curve); a path it cannot write (under a file) is refused with
    the reason."""
    from std_srvs.srv import Trigger

    from beams_common.calibration.calibration_file import load_calibration

    path = tmp_path / "learnt.yaml"
    start_node("beams_ekf", "ekf_node", {"self_calibration_file": str(path)})
    reply = rclpy_node.call(Trigger, "/ekf_node/save_calibration", Trigger.Request(), 20.0)
    assert reply.success, reply.message
    assert str(path) in reply.message
    calibration = load_calibration(path)
    assert calibration.bearing_correction.window_range_rad is not None
    assert calibration.bearing_correction.is_identity  # nothing learnt: no bearing came
    start_node("beams_ekf", "ekf_node", {"self_calibration_file": str(path / "x.yaml")}, "bad")
    reply = rclpy_node.call(Trigger, "/bad/ekf_node/save_calibration", Trigger.Request(), 20.0)
    assert not reply.success and "not saved" in reply.message
