"""A second publisher on an input is said at ERROR on /diagnostics, naming the publishers (issue 18).

The issue's reproduction: a second driver_node started in the robot's namespace interleaved its
revolutions with the first one's (fused twice, lost detections, re-initialisations) while every status
said OK. Now ekf_node's and triangulation_node's /diagnostics say ERROR naming both within
DETECTION_BOUND_S of the second publisher appearing in the graph, and the ERROR clears once it is gone.
"""

import time

import pytest

pytestmark = pytest.mark.dds

UP_TIMEOUT_S = 60.0
GUARD_LINE = "the node keeps running"  # callback_guard's log line for an exception it caught
# the graph check runs every 0.5 s and /diagnostics is published once a second
DETECTION_BOUND_S = 2.0
CLEAR_BOUND_S = 8.0
WATCHERS = ("ekf_node", "triangulation_node")


def test_a_second_driver_is_said_at_error_naming_both_and_the_error_clears(start_node, rclpy_node):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    statuses: dict[str, list] = {name: [] for name in WATCHERS}

    def on_diagnostics(msg) -> None:
        for status in msg.status:
            for name in WATCHERS:
                if f"/{name}:" in status.name:
                    statuses[name].append((time.monotonic(), status))

    rclpy_node.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
    nodes = [
        start_node("beams_sim", "sim_world_node"),
        start_node("beams_driver", "driver_node"),
        start_node("beams_triangulation", "triangulation_node"),
        start_node("beams_ekf", "ekf_node"),
    ]

    def latest(name: str):
        return statuses[name][-1][1] if statuses[name] else None

    def says_two_drivers(status) -> bool:
        return (
            status is not None
            and status.level == DiagnosticStatus.ERROR
            and "/driver_node (x2)" in status.message
            and "publishers on /beams/bearings" in status.message
        )

    assert rclpy_node.spin_until(lambda: all(latest(n) is not None for n in WATCHERS), UP_TIMEOUT_S), [
        node.log() for node in nodes
    ]
    rclpy_node.spin_for(3.0)
    # one source each: no ERROR, no false alarm from the graph or the messages
    settled = [s for n in WATCHERS for t, s in statuses[n] if t > time.monotonic() - 2.5]
    assert settled and all(s.level != DiagnosticStatus.ERROR for s in settled), [s.message for s in settled]

    started = time.monotonic()
    second = start_node("beams_driver", "driver_node")

    def publishers() -> int:
        return rclpy_node.node.count_publishers("/beams/bearings")

    assert rclpy_node.spin_until(lambda: publishers() == 2, UP_TIMEOUT_S), second.log()
    appeared = time.monotonic()
    assert rclpy_node.spin_until(
        lambda: all(says_two_drivers(latest(n)) for n in WATCHERS), DETECTION_BOUND_S + 1.0
    ), [(n, latest(n).message) for n in WATCHERS]
    # a node may see the new publisher before the probe does (each hears the others' discovery
    # announcements on its own schedule): an ERROR said since its start and before the probe saw it counts,
    # its delay negative
    detected = {
        n: min(t for t, s in statuses[n] if t >= started and says_two_drivers(s)) - appeared for n in WATCHERS
    }
    print(f"second driver said at ERROR {detected} s after it appeared in the probe's graph")
    assert all(delay <= DETECTION_BOUND_S for delay in detected.values()), detected
    rclpy_node.spin_for(2.0)  # its revolutions interleave too: still ERROR, not flickering
    assert all(says_two_drivers(latest(n)) for n in WATCHERS), [latest(n).message for n in WATCHERS]

    second.assert_clean_exit()
    assert rclpy_node.spin_until(lambda: publishers() == 1, UP_TIMEOUT_S)
    gone = time.monotonic()

    def cleared(name: str) -> bool:
        return any(t > gone and s.level != DiagnosticStatus.ERROR for t, s in statuses[name])

    assert rclpy_node.spin_until(lambda: all(cleared(n) for n in WATCHERS), CLEAR_BOUND_S), [
        (n, latest(n).message) for n in WATCHERS
    ]
    values = {kv.key: kv.value for kv in latest("ekf_node").values}
    assert int(values.get("input_source_problems", 0)) >= 2, values  # the graph's and the messages'
    assert "/beams/" in values.get("last_input_publishers_problem", ""), values
    stop_every_node_reporting_guarded_exceptions(nodes)


def stop_every_node_reporting_guarded_exceptions(nodes) -> None:
    """Every node exits 0 on SIGINT with no traceback, except one the callback guard logged: the
    interleaved revolutions of two drivers are inputs the pipelines were not written for, so an
    exception they raise is caught, counted and shown (test_callback_guard.py), and printed here
    for whoever reads the test's output; an exception that escaped still fails the test."""
    for node in nodes:
        status = node.stop()
        output = node.log()
        assert status == 0, f"{node.name} exited {status}:\n{output}"
        guarded = output.count(GUARD_LINE)
        assert output.count("Traceback") <= guarded, f"{node.name}: a traceback not from the guard:\n{output}"
        if guarded:
            print(f"{node.name}: {guarded} exception(s) caught by the callback guard:\n{output}")


def test_a_second_simulated_world_is_said_by_every_node_that_reads_odometry_or_ground_truth(
    start_node, rclpy_node
):
    """Two sim_world_nodes on one clock: their odometry stamps still increase merged, so the graph says
    it: ekf_node and triangulation_node (odom) and driver_node (ground truth) ERROR, naming both."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    watchers = {"ekf_node": "/odom", "triangulation_node": "/odom", "driver_node": "/beams/sim/ground_truth"}
    latest: dict[str, object] = {}

    def on_diagnostics(msg) -> None:
        for status in msg.status:
            for name in watchers:
                if f"/{name}:" in status.name:
                    latest[name] = status

    rclpy_node.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
    start_node("beams_sim", "sim_world_node")
    for package, executable in (
        ("beams_driver", "driver_node"),
        ("beams_triangulation", "triangulation_node"),
        ("beams_ekf", "ekf_node"),
    ):
        start_node(package, executable)
    assert rclpy_node.spin_until(lambda: len(latest) == len(watchers), UP_TIMEOUT_S)
    second = start_node("beams_sim", "sim_world_node")

    def said(name: str) -> bool:
        status = latest[name]
        return (
            status.level == DiagnosticStatus.ERROR
            and f"2 publishers on {watchers[name]}: /sim_world_node (x2)" in status.message
        )

    assert rclpy_node.spin_until(lambda: rclpy_node.node.count_publishers("/odom") == 2, UP_TIMEOUT_S)
    assert rclpy_node.spin_until(lambda: all(said(n) for n in watchers), DETECTION_BOUND_S + 1.0), {
        n: latest[n].message for n in watchers
    }
    second.assert_clean_exit()
    assert rclpy_node.spin_until(lambda: not any(said(n) for n in watchers), CLEAR_BOUND_S), {
        n: latest[n].message for n in watchers
    }


def test_a_second_ekf_is_said_by_the_ekf_itself_naming_both(start_node, rclpy_node):
    """No node of the suite reads beams/ekf/odometry, so a second ekf_node (the same launch twice) is said
    by the EKFs themselves: each sees a second publisher on its own output (input_watch's output check)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    reports: list[tuple[float, object]] = []

    def on_diagnostics(msg) -> None:
        reports.extend((time.monotonic(), s) for s in msg.status if "/ekf_node:" in s.name)

    rclpy_node.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
    first = start_node("beams_ekf", "ekf_node")
    assert rclpy_node.spin_until(lambda: bool(reports), UP_TIMEOUT_S), first.log()
    rclpy_node.spin_for(1.5)
    expected = "2 publishers on /beams/ekf/odometry (this node's output): /ekf_node (x2)"
    assert not any(expected in s.message for _t, s in reports)  # one EKF: no alarm
    second = start_node("beams_ekf", "ekf_node")
    assert rclpy_node.spin_until(
        lambda: rclpy_node.node.count_publishers("/beams/ekf/odometry") == 2, UP_TIMEOUT_S
    ), second.log()
    appeared = time.monotonic()

    def said_since(since: float) -> bool:
        return any(
            t > since and s.level == DiagnosticStatus.ERROR and expected in s.message for t, s in reports
        )

    assert rclpy_node.spin_until(lambda: said_since(appeared), DETECTION_BOUND_S + 1.0), [
        s.message for _t, s in reports[-4:]
    ]
    said_at = min(t for t, s in reports if t > appeared and expected in s.message)
    print(f"second ekf_node said at ERROR {said_at - appeared:.2f} s after it appeared")
    assert said_at - appeared <= DETECTION_BOUND_S
    second.assert_clean_exit()
    gone = time.monotonic()
    assert rclpy_node.spin_until(
        lambda: any(t > gone + 1.0 and expected not in s.message for t, s in reports), CLEAR_BOUND_S
    ), [s.message for _t, s in reports[-4:]]
    first.assert_clean_exit()
