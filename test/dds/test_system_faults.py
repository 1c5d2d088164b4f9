"""The whole suite under faults, over DDS, every node its own process (issue 7, "Faults").

One simulated robot (sim_world_node, driver_node, triangulation_node, ekf_node) runs a match while the test
kills (SIGKILL) and restarts the triangulation and then the EKF, the driver hides a beacon for a while
(`sim_occlusion_windows`), the simulated wheel odometry goes silent for 2 s (`odometry_dropout_s`) and the
test publishes a burst of malformed messages on every input. One running system serves all these checks,
one after the other (the test budget of a 2-core machine); each fault's interval is read from the data
(bearings without the hidden beacon, the gap in `odom`), never assumed, and after each one the EKF's pose
error against the simulator's truth must come back within its bound.

A second system drives a robot where two beacons are almost aligned (compound windows, thesis 2.4.5),
and the fault parameters added for these tests are checked to refuse bad values.

The helpers at the top (`robot_parameters`, `start_robot`, `RobotProbe`, `errors_against_truth`) also
serve test_system_multi_robot.py.
"""

import math
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

# The EKF's accuracy on the match (issue 5): RMS position (m) and heading (rad); after a fault too.
EKF_RMS_BOUND_M = 0.01
EKF_HEADING_RMS_BOUND_RAD = math.radians(0.3)
# ToTal's accepted poses: RMS position (m) and heading (rad) bounds of issue 4.
TOTAL_RMS_BOUND_M = 0.02
TOTAL_HEADING_RMS_BOUND_RAD = math.radians(0.5)
# Recovery: from a restarted node's "ready" log line to its first output over DDS, issue 7's 2 s, after a
# clean stop (SIGTERM) and after kill -9 alike. The bench measured at most 0.7 s (SIGTERM) and 0.4 s
# (kill -9, user data on UDP as the discovery profile sets it; 2.4 s over shared memory): BENCHMARKS.md.
RECOVERY_BOUND_S = 2.0
START_TIMEOUT_S = 40.0
# Let the filter settle this long after a fault ends before its error counts again.
SETTLE_S = 2.0
# While a beacon is hidden the EKF (two beacons and odometry) must not drift beyond the position std that
# the triangulation's gate accepts (max_position_std_m, 5 cm): measured 2.3 to 2.8 cm at most here.
HIDDEN_MAX_ERROR_M = 0.05
# Fault schedule, after the restarts (about 15 to 25 s from the start here). Beacon 3 is hidden for 10 s
# of the driver's time (the figure; the robot keeps moving, so the EKF runs on two beacons and
# odometry); the odometry is silent for 2 s of match time.
OCCLUDED_BEACON = 3
OCCLUSION_S = (32.0, 42.0)
ODOMETRY_DROPOUT_S = (50.0, 52.0)
MATCH_S = 120.0


def robot_parameters(seed: int, **overrides: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Parameters of the four nodes of one simulated robot: its trajectory and noise from `seed`.

    `overrides` maps a node ("sim_world", "driver", "triangulation", "ekf") to parameters to add.
    """
    parameters = {
        "sim_world": {
            "trajectory": "random",
            "trajectory_seed": seed,
            "odometry_seed": seed + 1,
            "duration_s": MATCH_S,
        },
        "driver": {"sim_sensor_seed": seed + 2},
        "triangulation": {"publish_markers": False},
        "ekf": {},
    }
    for node, values in overrides.items():
        parameters[node].update(values)
    return parameters


NODE_EXECUTABLES = {
    "sim_world": ("beams_sim", "sim_world_node"),
    "driver": ("beams_driver", "driver_node"),
    "triangulation": ("beams_triangulation", "triangulation_node"),
    "ekf": ("beams_ekf", "ekf_node"),
}


def start_robot(
    start_node: Callable[..., Any], parameters: dict[str, dict[str, Any]], namespace: str = ""
) -> dict[str, Any]:
    """Start the four nodes of one robot (separate processes) in a namespace; {node: NodeProcess}."""
    return {
        name: start_node(*NODE_EXECUTABLES[name], parameters[name], namespace) for name in NODE_EXECUTABLES
    }


def stamp_s(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


def heading_of(orientation) -> float:
    return math.atan2(2.0 * orientation.w * orientation.z, 1.0 - 2.0 * orientation.z**2)


def pose_row(stamp, pose) -> tuple[float, float, float, float]:
    """(t, x, y, theta) of a stamped geometry_msgs/Pose."""
    return (stamp_s(stamp), pose.position.x, pose.position.y, heading_of(pose.orientation))


def errors_against_truth(track: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and heading (rad) errors of rows (t, x, y, theta) against the truth interpolated
    at their stamps; rows outside the truth's time span are left out."""
    track = track.reshape(-1, 4)
    if len(truth) < 2 or len(track) == 0:
        return np.empty(0), np.empty(0)
    track = track[(track[:, 0] >= truth[0, 0]) & (track[:, 0] <= truth[-1, 0])]
    x, y = (np.interp(track[:, 0], truth[:, 0], truth[:, k]) for k in (1, 2))
    heading = np.interp(track[:, 0], truth[:, 0], np.unwrap(truth[:, 3]))
    heading_error = np.angle(np.exp(1j * (track[:, 3] - heading)))
    return np.hypot(track[:, 1] - x, track[:, 2] - y), np.abs(heading_error)


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else math.nan


@dataclass
class RobotProbe:
    """What one robot's nodes publish, recorded with arrival times (monotonic s) for recovery timing."""

    namespace: str
    truth: list[tuple[float, float, float, float]] = field(default_factory=list)
    ekf: list[tuple[float, float, float, float]] = field(default_factory=list)
    ekf_arrivals: list[float] = field(default_factory=list)
    total: list[tuple[float, float, float, float]] = field(default_factory=list)
    total_arrivals: list[float] = field(default_factory=list)
    # ToTal poses (accepted or not) with a non-finite coordinate
    total_non_finite: int = 0
    odometry_stamps: list[float] = field(default_factory=list)
    # (revolution stamp, beacon ids seen)
    revolutions: list[tuple[float, tuple[int, ...]]] = field(default_factory=list)
    # diagnostics of this robot's nodes: node tag ("driver", "ekf", ...) -> [(arrival, level, values)]
    diagnostics: dict[str, list[tuple[float, int, dict[str, str]]]] = field(default_factory=dict)

    def attach(self, graph) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from beams_msgs.msg import BeaconBearingArray, TriangulatedPose

        prefix = f"/{self.namespace}/" if self.namespace else ""
        node = graph.node
        node.create_subscription(Odometry, prefix + "beams/sim/ground_truth", self._on_truth, 50)
        node.create_subscription(Odometry, prefix + "beams/ekf/odometry", self._on_ekf, 50)
        node.create_subscription(TriangulatedPose, prefix + "beams/pose", self._on_total, 50)
        # every odometry sample and revolution, also those published while the test waits for a node to
        # stop without spinning (a best-effort depth of 5 drops them: a silence the dropout check took for
        # the odometry's, 1.14 s against 2 s, and the occlusion check for beacon 3 hidden)
        odometry_qos = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(Odometry, prefix + "odom", self._on_odometry, odometry_qos)
        bearings_qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(
            BeaconBearingArray, prefix + "beams/bearings", self._on_bearings, bearings_qos
        )
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)

    def _on_truth(self, msg) -> None:
        row = pose_row(msg.header.stamp, msg.pose.pose)
        if all(math.isfinite(v) for v in row):  # the malformed burst's ground truth is not the truth
            self.truth.append(row)

    def _on_ekf(self, msg) -> None:
        self.ekf.append(pose_row(msg.header.stamp, msg.pose.pose))
        self.ekf_arrivals.append(time.monotonic())

    def _on_total(self, msg) -> None:
        if not all(math.isfinite(v) for v in pose_row(msg.header.stamp, msg.pose.pose)):
            self.total_non_finite += 1
        if msg.accepted:
            self.total.append(pose_row(msg.header.stamp, msg.pose.pose))
            self.total_arrivals.append(time.monotonic())

    def _on_odometry(self, msg) -> None:
        self.odometry_stamps.append(stamp_s(msg.header.stamp))

    def _on_bearings(self, msg) -> None:
        self.revolutions.append((stamp_s(msg.header.stamp), tuple(b.beacon_id for b in msg.bearings)))

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            # names are "<fully qualified node name>: <tag>"
            node_name, _, tag = status.name.partition(": ")
            if node_name.rsplit("/", 1)[0] != (f"/{self.namespace}" if self.namespace else ""):
                continue
            values = {kv.key: kv.value for kv in status.values}
            self.diagnostics.setdefault(tag, []).append((time.monotonic(), ord(status.level), values))

    def counter(self, tag: str, key: str, since: float = -math.inf) -> float:
        """The newest value of a node's diagnostic counter among the reports that arrived after `since`
        (monotonic s); 0 before it reports one."""
        for arrival, _, values in reversed(self.diagnostics.get(tag, [])):
            if arrival > since and key in values:
                return float(values[key])
        return 0.0

    def ekf_errors(self, since_stamp_s: float = -math.inf, until_stamp_s: float = math.inf):
        """EKF position and heading errors for the outputs stamped in [since, until)."""
        track = np.array(self.ekf, dtype=float).reshape(-1, 4)
        track = track[(track[:, 0] >= since_stamp_s) & (track[:, 0] < until_stamp_s)]
        return errors_against_truth(track, np.array(self.truth, dtype=float).reshape(-1, 4))

    def total_errors(self):
        return errors_against_truth(np.array(self.total, dtype=float), np.array(self.truth, dtype=float))

    def latest_truth_stamp(self) -> float:
        return self.truth[-1][0] if self.truth else -math.inf


def wait_for_log(graph, node, text: str, timeout_s: float) -> float:
    """Spin until a node's log shows `text`; the monotonic time it was seen (fails the test on time-out)."""
    assert graph.spin_until(lambda: text in node.log(), timeout_s), (
        f"{node.name} did not log {text!r} within {timeout_s} s:\n{node.log()}"
    )
    return time.monotonic()


def restart_after_kill(
    graph,
    start_node,
    nodes: dict[str, Any],
    name: str,
    parameters: dict[str, dict[str, Any]],
    ready_text: str,
    stop_signal: int = signal.SIGKILL,
) -> float:
    """Kill a node (SIGKILL) or stop it cleanly (SIGTERM: exit 0), start it again; the monotonic time the
    new process logged `ready_text`."""
    status = nodes[name].stop(stop_signal)
    expected = -signal.SIGKILL if stop_signal == signal.SIGKILL else 0
    assert status == expected, f"{name} stopped by signal {stop_signal} with exit status {status}"
    nodes[name] = start_node(*NODE_EXECUTABLES[name], parameters[name])
    return wait_for_log(graph, nodes[name], ready_text, START_TIMEOUT_S)


def first_after(arrivals: list[float], instant: float) -> float:
    return next((t for t in arrivals if t > instant), math.inf)


def interval_without(stamps: list[float], min_gap_s: float) -> tuple[float, float] | None:
    """The first silence longer than min_gap_s between consecutive stamps, as (last before, first after)."""
    gaps = np.diff(stamps)
    index = np.flatnonzero(gaps > min_gap_s)
    return (stamps[index[0]], stamps[index[0] + 1]) if len(index) else None


def malformed_inputs(now_s: float) -> list[tuple[str, Any]]:
    """(topic, message) pairs of one malformed burst: NaN bearings, an unknown beacon id, an empty
    revolution, NaN odometry and NaN ground truth, stamped now (so they reach every node's logic)."""
    from builtin_interfaces.msg import Time
    from nav_msgs.msg import Odometry

    from beams_common.interfaces.bearing_messages import NS_PER_S, BearingFields
    from beams_common.ros.messages import bearing_array
    from beams_msgs.msg import BeaconBearingArray

    stamp = Time(sec=int(now_s), nanosec=int((now_s % 1.0) * 1e9))
    stamp_ns = stamp.sec * NS_PER_S + stamp.nanosec

    def revolution(bearings: list[tuple[int, float, float]]) -> BeaconBearingArray:
        fields = [
            BearingFields(stamp_ns, beacon_id, bearing, variance) for beacon_id, bearing, variance in bearings
        ]
        return bearing_array(stamp_ns, fields, period_s=0.1)

    def nan_odometry(frame: str) -> Odometry:
        msg = Odometry()
        msg.header.stamp, msg.header.frame_id, msg.child_frame_id = stamp, frame, "base_link"
        msg.pose.pose.position.x = msg.pose.pose.orientation.w = math.nan
        msg.twist.twist.linear.x = math.nan
        return msg

    return [
        ("beams/bearings", revolution([(1, math.nan, 1e-6), (2, 0.5, math.nan), (3, 1.0, 1e-6)])),
        ("beams/bearings", revolution([(1, 0.1, 1e-6), (2, 1.5, 1e-6), (9, 2.0, 1e-6)])),
        ("beams/bearings", revolution([])),
        ("odom", nan_odometry("odom")),
        ("beams/sim/ground_truth", nan_odometry("map")),
    ]


def publish_burst(graph, count: int, spacing_s: float) -> None:
    """Publish `count` malformed bursts, `spacing_s` apart, once every input has a subscriber."""
    from nav_msgs.msg import Odometry

    from beams_msgs.msg import BeaconBearingArray

    types = {"beams/bearings": BeaconBearingArray, "odom": Odometry, "beams/sim/ground_truth": Odometry}
    publishers = {topic: graph.node.create_publisher(kind, topic, 50) for topic, kind in types.items()}
    assert graph.spin_until(lambda: all(p.get_subscription_count() >= 2 for p in publishers.values()), 10.0)
    for _ in range(count):
        now_s = graph.node.get_clock().now().nanoseconds * 1e-9
        for topic, msg in malformed_inputs(now_s):
            publishers[topic].publish(msg)
        graph.spin_for(spacing_s)


def assert_ekf_back(probe: RobotProbe, since_s: float, until_s: float, what: str) -> float:
    """The EKF's errors over outputs stamped in [since, until) are within issue 5's bounds; the RMS (m)."""
    position, heading = probe.ekf_errors(since_s, until_s)
    assert len(position) > 20, f"only {len(position)} EKF outputs to judge the recovery after {what}"
    assert rms(position) < EKF_RMS_BOUND_M, f"EKF RMS {rms(position):.4f} m after {what}"
    assert rms(heading) < EKF_HEADING_RMS_BOUND_RAD, f"EKF heading RMS {rms(heading):.5f} rad after {what}"
    return rms(position)


def check_restarts(graph, start_node, nodes, parameters, probe: RobotProbe) -> dict[str, float]:
    """Restart the triangulation after a clean stop, then kill -9 and restart the triangulation, then the
    EKF: each output is back within issue 7's 2 s of its start-up, the new EKF
    reports its initialisation and is accurate again once settled."""
    ready = restart_after_kill(
        graph, start_node, nodes, "triangulation", parameters, "triangulation_node ready", signal.SIGTERM
    )
    graph.spin_until(lambda: first_after(probe.total_arrivals, ready) < math.inf, 10.0)
    clean_back_s = first_after(probe.total_arrivals, ready) - ready
    assert clean_back_s <= RECOVERY_BOUND_S, f"ToTal back {clean_back_s:.2f} s after a clean restart"

    ready = restart_after_kill(
        graph, start_node, nodes, "triangulation", parameters, "triangulation_node ready"
    )
    graph.spin_until(lambda: first_after(probe.total_arrivals, ready) < math.inf, 10.0)
    total_back_s = first_after(probe.total_arrivals, ready) - ready
    assert total_back_s <= RECOVERY_BOUND_S, f"ToTal back {total_back_s:.2f} s after a kill -9"

    ready = restart_after_kill(graph, start_node, nodes, "ekf", parameters, "ekf_node ready")
    graph.spin_until(lambda: first_after(probe.ekf_arrivals, ready) < math.inf, 10.0)
    ekf_back_s = first_after(probe.ekf_arrivals, ready) - ready
    assert ekf_back_s <= RECOVERY_BOUND_S, f"EKF back {ekf_back_s:.2f} s after a kill -9"
    # the killed process cannot report any more: what arrives after `ready` is the new one's
    assert graph.spin_until(lambda: probe.counter("ekf", "initialisations", since=ready) == 1, 5.0), (
        "the restarted EKF did not report its initialisation in /diagnostics"
    )
    restarted_s = probe.ekf[-1][0]
    graph.spin_until(lambda: probe.latest_truth_stamp() > restarted_s + 2 * SETTLE_S, 15.0)
    rms_m = assert_ekf_back(probe, restarted_s + SETTLE_S, restarted_s + 2 * SETTLE_S, "its restart")
    return {
        "ToTal back after a clean restart (s)": clean_back_s,
        "ToTal back after restart (s)": total_back_s,
        "EKF back after restart (s)": ekf_back_s,
        "EKF RMS after restart (m)": rms_m,
        "restarts over at (stamp s)": restarted_s + 2 * SETTLE_S,
    }


def check_occlusion(graph, probe: RobotProbe) -> tuple[float, dict[str, float]]:
    """Beacon 3 hidden for 10 s: ToTal has two beacons and says so, the EKF goes on. The hidden span
    comes from the bearings (revolutions without beacon 3); returns its end and the figures."""

    def hidden() -> tuple[float, float] | None:
        return interval_without([t for t, ids in probe.revolutions if OCCLUDED_BEACON in ids], 1.0)

    assert graph.spin_until(lambda: hidden() is not None, START_TIMEOUT_S + OCCLUSION_S[1]), (
        "beacon 3 never disappeared"
    )
    hidden_from, hidden_to = hidden()
    assert hidden_to - hidden_from == pytest.approx(OCCLUSION_S[1] - OCCLUSION_S[0], abs=0.3)
    no_pose = probe.counter("triangulation", "no_pose")
    assert no_pose >= 50, f"the triangulation reported only {no_pose} revolutions without a pose"
    during, _ = probe.ekf_errors(hidden_from, hidden_to)
    assert len(during) > 100, "the EKF stopped publishing while a beacon was hidden"
    assert max(during) < HIDDEN_MAX_ERROR_M, f"the EKF drifted {max(during):.3f} m while a beacon was hidden"
    return hidden_to, {"EKF RMS while hidden (m)": rms(during), "EKF max while hidden (m)": max(during)}


def check_odometry_dropout(graph, probe: RobotProbe) -> tuple[float, float]:
    """Odometry silent for 2 s: sim_world counts the dropped samples, the EKF a gap. Returns the silence."""
    assert graph.spin_until(lambda: interval_without(probe.odometry_stamps, 1.0) is not None, 30.0), (
        "the odometry never stopped"
    )
    silent_from, silent_to = interval_without(probe.odometry_stamps, 1.0)
    assert silent_to - silent_from == pytest.approx(ODOMETRY_DROPOUT_S[1] - ODOMETRY_DROPOUT_S[0], abs=0.1)
    assert graph.spin_until(lambda: probe.counter("sim_world", "odometry_dropped") >= 90, 3.0)
    assert graph.spin_until(lambda: probe.counter("ekf", "odometry_gaps") >= 1, 5.0)
    return silent_from, silent_to


def check_malformed_burst(graph, probe: RobotProbe) -> float:
    """A burst of malformed messages on every input: each node that reads them counts them in
    /diagnostics. Returns the stamp the burst started at."""
    keys = (
        ("triangulation", "bad_input"),
        ("ekf", "bearings_invalid_measurement"),
        ("ekf", "bearings_unknown_beacon"),
        ("ekf", "odometry_invalid"),
        ("driver", "ground_truth_rejected_non_finite"),
    )
    before = {key: probe.counter(*key) for key in keys}
    burst_from = probe.latest_truth_stamp()
    publish_burst(graph, count=20, spacing_s=0.05)
    for tag, key in keys:  # diagnostics come once a second
        assert graph.spin_until(lambda tag=tag, key=key: probe.counter(tag, key) > before[tag, key], 3.0), (
            f"{tag} did not report the malformed messages ({key})"
        )
    return burst_from


def test_system_survives_faults(start_node, rclpy_node):
    graph = rclpy_node
    parameters = robot_parameters(
        seed=7,
        sim_world={"odometry_dropout_s": list(ODOMETRY_DROPOUT_S)},
        driver={"sim_occlusion_windows": [float(OCCLUDED_BEACON), *OCCLUSION_S]},
    )
    probe = RobotProbe("")
    probe.attach(graph)
    nodes = start_robot(start_node, parameters)
    assert graph.spin_until(lambda: len(probe.ekf) > 20, START_TIMEOUT_S), "no EKF estimate at start-up"

    figures = check_restarts(graph, start_node, nodes, parameters, probe)
    restarts_over_s = figures.pop("restarts over at (stamp s)")
    hidden_to, occlusion = check_occlusion(graph, probe)
    hidden_from = hidden_to - (OCCLUSION_S[1] - OCCLUSION_S[0])
    assert hidden_from > restarts_over_s, "the restarts took so long that they overlapped the occlusion"
    silent_from, silent_to = check_odometry_dropout(graph, probe)
    figures |= occlusion
    figures["EKF RMS after occlusion (m)"] = assert_ekf_back(
        probe, hidden_to + SETTLE_S, silent_from, "the occlusion"
    )
    graph.spin_until(lambda: probe.latest_truth_stamp() > silent_to + 2 * SETTLE_S, 10.0)
    burst_from = check_malformed_burst(graph, probe)
    figures["EKF RMS after dropout (m)"] = assert_ekf_back(
        probe, silent_to + SETTLE_S, burst_from, "the odometry dropout"
    )
    graph.spin_until(lambda: probe.latest_truth_stamp() > burst_from + 2 * SETTLE_S, 10.0)
    figures["EKF RMS after burst (m)"] = assert_ekf_back(
        probe, burst_from + SETTLE_S, math.inf, "the malformed burst"
    )
    for name, node in nodes.items():
        assert node.process.poll() is None, f"{name} died:\n{node.log()}"
    total_position, total_heading = probe.total_errors()
    assert np.all(np.isfinite(probe.total)), "ToTal accepted a non-finite pose"
    assert rms(total_position) < TOTAL_RMS_BOUND_M and rms(total_heading) < TOTAL_HEADING_RMS_BOUND_RAD
    figures["non-finite ToTal poses (rejected)"] = probe.total_non_finite
    print("system faults: " + ", ".join(f"{k} {v:.4g}" for k, v in figures.items()))


# Beacons 3 and 4 on the right side of the table: driving down to the bottom-right corner, the robot
# looks at them along that side, almost aligned, and their windows merge (compound, thesis 2.4.5).
ALIGNED_BEACONS = {"ids": [1, 2, 3, 4], "x": [-0.062, -0.062, 3.062, 3.062], "y": [-0.062, 2.062, 1.0, 1.3]}
# From the table's centre to the corner (compound windows from about 3.8 s to 5.3 s), back, then still.
CORNER_WAYPOINTS = {"x": [1.0, 2.0, 2.8, 2.8, 2.0, 1.0, 1.0], "y": [1.0, 0.6, 0.2, 0.2, 0.6, 1.0, 1.2]}
ALIGNED_MATCH_S = 14.0


def test_system_rides_through_compound_windows(start_node, rclpy_node):
    beacons = {
        "beacon_ids": ALIGNED_BEACONS["ids"],
        "beacon_x": ALIGNED_BEACONS["x"],
        "beacon_y": ALIGNED_BEACONS["y"],
    }
    parameters = robot_parameters(
        seed=5,
        sim_world={
            "trajectory": "waypoints",
            "waypoints_x": CORNER_WAYPOINTS["x"],
            "waypoints_y": CORNER_WAYPOINTS["y"],
            "duration_s": ALIGNED_MATCH_S,
        },
        driver={f"sim_{key}": value for key, value in beacons.items()},
        triangulation=beacons,
        ekf=beacons,
    )
    probe = RobotProbe("")
    probe.attach(rclpy_node)
    # the match clock starts with sim_world: start it once the others listen, so the EKF sees it all
    nodes = {
        name: start_node(*NODE_EXECUTABLES[name], parameters[name])
        for name in ("driver", "triangulation", "ekf")
    }
    for name, node in nodes.items():
        wait_for_log(rclpy_node, node, "ready" if name != "driver" else "publishing", START_TIMEOUT_S)
    start_node(*NODE_EXECUTABLES["sim_world"], parameters["sim_world"])
    assert rclpy_node.spin_until(lambda: len(probe.truth) > 0, START_TIMEOUT_S)
    match_start_s = probe.truth[0][0]
    assert rclpy_node.spin_until(
        lambda: probe.latest_truth_stamp() > match_start_s + ALIGNED_MATCH_S, 2 * ALIGNED_MATCH_S
    )
    rclpy_node.spin_for(1.5)  # the last diagnostics

    merged = [t for t, ids in probe.revolutions if 3 not in ids and 4 not in ids and {1, 2} <= set(ids)]
    assert len(merged) >= 5, f"only {len(merged)} revolutions lost beacons 3 and 4 together"
    assert probe.counter("driver", "rejected_compound") >= len(merged), "compound windows not reported"
    assert probe.counter("triangulation", "no_pose") >= len(merged) // 2
    during, _ = probe.ekf_errors(merged[0], merged[-1])
    assert len(during) > 10, "the EKF stopped publishing during the compound windows"
    after_m = assert_ekf_back(probe, merged[-1] + SETTLE_S, math.inf, "the compound windows")
    print(
        f"compound windows: {len(merged)} revolutions over {merged[-1] - merged[0]:.1f} s, EKF RMS during "
        f"{rms(during):.4f} m (max {during.max():.4f}), after {after_m:.4f} m"
    )


@pytest.mark.parametrize(
    ("package", "executable", "parameters", "message"),
    [
        ("beams_driver", "driver_node", {"sim_occlusion_windows": [3.0, 5.0]}, "triples"),
        ("beams_driver", "driver_node", {"sim_occlusion_windows": [3.0, 5.0, 2.0]}, "start_s < end_s"),
        ("beams_sim", "sim_world_node", {"odometry_dropout_s": [5.0, 1.0]}, "start_s <= end_s"),
        ("beams_driver", "driver_node", {"sim_other_robots": ["beams/sim/ground_truth"]}, "own ground truth"),
    ],
)
def test_fault_parameters_are_validated(start_node, package, executable, parameters, message):
    node = start_node(package, executable, parameters)
    assert node.wait_exit(20) == 2
    assert message in node.log() and "Traceback" not in node.log()
