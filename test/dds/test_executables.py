"""Every executable starts from the install tree, answers over DDS (/diagnostics) and exits 0 without a
traceback under every way a launcher stops it (issues 2 and 14); a bad parameter or executor choice is
refused at start-up with one clear line.

Each node runs in a process group of its own and gets the signals as a terminal or `ros2 launch` sends
them to a group: SIGINT once, SIGTERM once, SIGINT twice (Ctrl-C under launch: from the terminal and
from launch), SIGINT then SIGTERM (launch's escalation). The delay between the two signals varies from
node to node and from pattern to pattern, so the second one lands before, during and after the
node's shutdown. The serial driver releases its port.
"""

import os
import signal
import time
from collections.abc import Iterator
from typing import Any

import pytest

UP_TIMEOUT_S = 30.0
ANSWER_TIMEOUT_S = 20.0
STOP_TIMEOUT_S = 15.0
# Node k of a batch waits SECOND_SIGNAL_DELAYS_S[(k + pattern) % n] between the two signals.
SECOND_SIGNAL_DELAYS_S = (0.0, 0.005, 0.03, 0.1, 0.3, 0.8)
NOT_CLEAN = ("Traceback", "Exception in", "Error occurred at", "Failed to publish")
PATTERNS = {
    "SIGINT": (signal.SIGINT,),
    "SIGTERM": (signal.SIGTERM,),
    "SIGINT-SIGINT": (signal.SIGINT, signal.SIGINT),
    "SIGINT-SIGTERM": (signal.SIGINT, signal.SIGTERM),
}


@pytest.fixture
def serial_pty() -> Iterator[str]:
    """A pseudo-terminal standing for the sensor (it sends nothing: the driver only has to open it)."""
    master, slave = os.openpty()
    yield os.ttyname(slave)
    os.close(master)
    os.close(slave)


def send_pattern(nodes: list[Any], signals: tuple[int, ...], delays_s: list[float]) -> None:
    """Send the pattern to each node's process group; the nodes' delays run side by side."""
    for node in nodes:
        os.killpg(node.process.pid, signals[0])
    if len(signals) == 1:
        return
    start = time.monotonic()
    for delay_s, node in sorted(zip(delays_s, nodes, strict=True), key=lambda pair: pair[0]):
        time.sleep(max(0.0, start + delay_s - time.monotonic()))
        if node.process.poll() is None:
            os.killpg(node.process.pid, signals[1])


@pytest.mark.parametrize("pattern", list(PATTERNS), ids=list(PATTERNS))
def test_every_node_stops_cleanly_under_every_signal_pattern(rclpy_node, start_node, serial_pty, pattern):
    from diagnostic_msgs.msg import DiagnosticArray

    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    # every installed executable (the driver with each built-in source), answering over DDS before the stop
    started = [
        ("beams_sim", "sim_world_node", None),
        ("beams_driver", "driver_node", {"sim_static_pose": [1.5, 1.0, 0.0]}),
        ("beams_driver", "driver_node", {"source": "serial", "device": serial_pty}),
        ("beams_triangulation", "triangulation_node", None),
        ("beams_ekf", "ekf_node", None),
        ("beams_calibration", "calibration_node", None),
    ]
    nodes = [
        start_node(package, executable, params, namespace=f"n{k}", own_process_group=True)
        for k, (package, executable, params) in enumerate(started)
    ]
    reporting = {f"/n{k}/" for k in range(len(nodes))}

    def all_up() -> bool:
        seen = {prefix for msg in diagnostics for s in msg.status for prefix in reporting if prefix in s.name}
        return seen == reporting

    assert rclpy_node.spin_until(all_up, UP_TIMEOUT_S), "\n".join(n.log() for n in nodes)
    shift = list(PATTERNS).index(pattern)
    delays_s = [SECOND_SIGNAL_DELAYS_S[(k + shift) % len(SECOND_SIGNAL_DELAYS_S)] for k in range(len(nodes))]
    send_pattern(nodes, PATTERNS[pattern], delays_s)
    failures = []
    for node, delay_s in zip(nodes, delays_s, strict=True):
        status = node.wait_exit(STOP_TIMEOUT_S)
        output = node.log()
        # An executor logs a failing callback's stack as "Error occurred at" rather than "Traceback".
        if status != 0 or any(mark in output for mark in NOT_CLEAN):
            failures.append(f"{node.name} ({pattern}, second signal after {delay_s} s): {status}\n{output}")
    assert not failures, "\n".join(failures)
    assert f"serial device {serial_pty} released" in nodes[2].log()


def test_invalid_parameter_is_refused_with_a_clear_message(start_node):
    node = start_node("beams_driver", "driver_node", params={"variance_mode": "guess"})
    status = node.wait_exit(ANSWER_TIMEOUT_S)
    output = node.log()
    assert status == 2, output
    assert "variance_mode" in output and "Traceback" not in output, output


def test_executor_choice_falls_back_and_refuses_nonsense(rclpy_node, start_node, ros_env):
    """BEAMS_EXECUTOR=single_threaded runs a streaming node on rclpy's SingleThreadedExecutor (the
    fallback from the EventsExecutor); an unknown value is refused at start-up with a clear message."""
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data

    ros_env["BEAMS_EXECUTOR"] = "single_threaded"
    odometry = rclpy_node.subscribe(Odometry, "odom", qos_profile_sensor_data)
    fallback = start_node("beams_sim", "sim_world_node")
    assert rclpy_node.spin_until(lambda: len(odometry) > 20, ANSWER_TIMEOUT_S), fallback.log()
    fallback.assert_clean_exit(signal.SIGTERM)
    ros_env["BEAMS_EXECUTOR"] = "fastest"
    refused = start_node("beams_ekf", "ekf_node")
    assert refused.wait_exit(ANSWER_TIMEOUT_S) == 2, refused.log()
    assert "BEAMS_EXECUTOR='fastest'" in refused.log() and "Traceback" not in refused.log()
