"""ekf_node's hot standby over DDS (issue 18, beams_common.ros.standby through run_node): a process started
with --standby while the role is held waits outside the ROS graph (no DDS participant: one socket, the
watch on the holder; no CPU: it blocks), takes over when the active one is killed, and a stop signal
ends it with 0 however it comes (Ctrl-C to its process group, twice as under `ros2 launch`, SIGTERM).
A second ekf_node started without --standby runs anyway, with one WARN line, and the graph shows two."""

import os
import signal
import time

import pytest

pytestmark = pytest.mark.dds

UP_TIMEOUT_S = 30.0
WAITING_TIMEOUT_S = 30.0
STOP_TIMEOUT_S = 10.0
WATCH_S = 2.0  # how long a waiting standby is watched (graph, sockets, CPU)
SECOND_SIGNAL_DELAY_S = 0.05  # launch's second SIGINT follows the terminal's at once
STANDBY = ["--standby"]
WAITING = "standby: waiting for the role of /ekf_node"
TOOK_OVER = "standby: took the role of /ekf_node"


def ekf_nodes_in_graph(rclpy_node) -> int:
    return [name for name, _ns in rclpy_node.node.get_node_names_and_namespaces()].count("ekf_node")


def sockets_of(pid: int) -> int:
    """How many sockets the process holds (a DDS participant opens several UDP sockets)."""
    links = []
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            links.append(os.readlink(f"/proc/{pid}/fd/{fd}"))
        except FileNotFoundError:  # closed meanwhile
            continue
    return sum(link.startswith("socket:") for link in links)


def cpu_s(pid: int) -> float:
    """The CPU time of every thread of the process so far (s; the scheduler's nanoseconds, not ticks)."""
    total_ns = 0
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/schedstat") as schedstat:
            total_ns += int(schedstat.read().split()[0])
    return total_ns * 1e-9


def start_active(rclpy_node, start_node):
    """A plain ekf_node holding the role, in the graph."""
    from beams_common.ros.standby import NodeIdentity, RoleLock, domain_id_of, role_name

    active = start_node("beams_ekf", "ekf_node")
    assert rclpy_node.spin_until(lambda: ekf_nodes_in_graph(rclpy_node) == 1, UP_TIMEOUT_S), active.log()
    role = RoleLock(role_name(NodeIdentity("/", "ekf_node"), domain_id_of(os.environ)))
    assert role.holder_pid() == active.process.pid
    return active, role


def wait_for_log(rclpy_node, node, text: str, timeout_s: float) -> None:
    assert rclpy_node.spin_until(lambda: text in node.log(), timeout_s), node.log()


def test_a_standby_waits_outside_the_graph_and_takes_over_when_the_active_is_killed(rclpy_node, start_node):
    from diagnostic_msgs.msg import DiagnosticArray

    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    active, role = start_active(rclpy_node, start_node)
    standby = start_node("beams_ekf", "ekf_node", arguments=STANDBY)
    wait_for_log(rclpy_node, standby, WAITING, WAITING_TIMEOUT_S)
    assert f"held by process {active.process.pid}" in standby.log()
    cpu_before_s = cpu_s(standby.process.pid)
    rclpy_node.spin_for(WATCH_S)
    waiting_cpu_s = cpu_s(standby.process.pid) - cpu_before_s
    assert ekf_nodes_in_graph(rclpy_node) == 1
    assert rclpy_node.node.count_publishers("/beams/ekf/odometry") == 1
    assert sockets_of(standby.process.pid) == 1, "a waiting standby holds only its watch on the holder"
    # blocked in select with no timeout: nothing runs (a 0.1-s poll cost 1.2 ms a second)
    assert waiting_cpu_s < 0.001, f"{waiting_cpu_s} s of CPU in {WATCH_S} s of waiting"
    assert TOOK_OVER not in standby.log()

    killed_at = time.monotonic()
    assert active.stop(signal.SIGKILL) == -signal.SIGKILL
    wait_for_log(rclpy_node, standby, TOOK_OVER, UP_TIMEOUT_S)
    assert role.holder_pid() == standby.process.pid
    statuses_since = len(diagnostics)

    def new_ekf_reports() -> bool:
        return any("/ekf_node:" in s.name for msg in diagnostics[statuses_since:] for s in msg.status)

    # the killed one cannot publish: a status from an ekf_node now is the standby's, become the node
    assert rclpy_node.spin_until(new_ekf_reports, UP_TIMEOUT_S), standby.log()
    print(f"standby's first /diagnostics {time.monotonic() - killed_at:.2f} s after the kill")
    # at teardown the fixture stops it with SIGINT: exit 0, no traceback


@pytest.mark.parametrize(
    "pattern",
    [(signal.SIGINT,), (signal.SIGINT, signal.SIGINT), (signal.SIGTERM,)],
    ids=["ctrl_c", "ctrl_c_twice_as_launch", "sigterm"],
)
def test_a_waiting_standby_ends_with_0_on_a_stop_signal(rclpy_node, start_node, pattern):
    start_active(rclpy_node, start_node)
    standby = start_node("beams_ekf", "ekf_node", arguments=STANDBY, own_process_group=True)
    wait_for_log(rclpy_node, standby, WAITING, WAITING_TIMEOUT_S)
    for k, sig in enumerate(pattern):
        if k:
            time.sleep(SECOND_SIGNAL_DELAY_S)
        if standby.process.poll() is None:
            os.killpg(standby.process.pid, sig)
    started_s = time.monotonic()
    assert standby.wait_exit(STOP_TIMEOUT_S) == 0, standby.log()
    stop_s = time.monotonic() - started_s
    assert stop_s < 1.0, f"{stop_s:.2f} s to stop"  # the signal wakes its wait at once (0.2 s idle)
    assert "Traceback" not in standby.log() and TOOK_OVER not in standby.log(), standby.log()
    assert ekf_nodes_in_graph(rclpy_node) == 1


def test_a_second_ekf_node_without_standby_runs_anyway_with_a_warning(rclpy_node, start_node):
    active, _role = start_active(rclpy_node, start_node)
    careless = start_node("beams_ekf", "ekf_node")
    assert rclpy_node.spin_until(lambda: ekf_nodes_in_graph(rclpy_node) == 2, UP_TIMEOUT_S), careless.log()
    warnings = [line for line in careless.log().splitlines() if "running anyway" in line]
    assert len(warnings) == 1 and "[WARN]" in warnings[0], careless.log()
    assert f"held by process {active.process.pid}" in warnings[0]
