"""The suite through the real ROS 2 command line, as its users drive it (issue 14).

`ros2 launch` (start in a namespace, every node up, Ctrl-C to the process group: every node finishes
cleanly), `ros2 run`, `ros2 topic echo --once`, `ros2 param get/set/list`, `ros2 service call`, and
`ros2 lifecycle get/set` on the driver launched with `driver_autostart:=false`.
Runs wherever the `ros2` command, launch and launch_ros are installed (a robot with ROS 2 Jazzy from
apt); elsewhere, such as a venv with only the PyPI wheels, every test skips and says why.
Select it alone with `-m ros2_cli`.
"""

import functools
import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator

import pytest

pytestmark = pytest.mark.ros2_cli

# What the tier needs, importable by the venv's python (composition_interfaces: launch_ros imports it).
REQUIRED_MODULES = (
    "ros2cli",
    "ros2run",
    "ros2topic",
    "ros2param",
    "ros2service",
    "launch",
    "launch_ros",
    "ros2launch",
    "composition_interfaces.srv",
)
LAUNCHED_NODES = ("sim_world_node", "driver_node", "triangulation_node", "ekf_node")
# ekf_node runs as a hot standby pair by default (ekf_standby:=true): one process more
LAUNCHED_PROCESSES = len(LAUNCHED_NODES) + 1
UP_TIMEOUT_S = 40.0
STOP_TIMEOUT_S = 30.0
CLI_TIMEOUT_S = 60.0
STATIC_POSE = [1.5, 1.0, 0.3]


@functools.cache
def missing_tools() -> str:
    """Why the real command line cannot be used here ('' when it can)."""
    if shutil.which("ros2") is None:
        return "the `ros2` command is not on PATH"
    probe = subprocess.run(
        ["python", "-c", f"import {', '.join(REQUIRED_MODULES)}"], capture_output=True, text=True, timeout=60
    )
    if probe.returncode != 0:
        return f"cannot import the real ROS 2 tools ({probe.stderr.strip().splitlines()[-1]})"
    return ""


@pytest.fixture(autouse=True)
def real_ros2_tools() -> None:
    reason = missing_tools()
    if reason:
        pytest.skip(
            f"real ROS 2 command-line tier skipped: {reason}; the PyPI wheels lack ros2cli, launch and "
            "launch_ros (a robot's apt install of ROS 2 Jazzy has them)"
        )


class Group:
    """A command running in a process group of its own, as a shell runs a foreground job."""

    def __init__(self, command: list[str], env: dict[str, str], log_path) -> None:
        self.log_path = log_path
        with open(log_path, "w") as log_file:
            self.process = subprocess.Popen(
                command,
                env=env,
                stdout=log_file,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
            )

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def ctrl_c(self) -> int:
        """SIGINT to the whole group (the terminal's Ctrl-C); the leader's exit status."""
        os.killpg(self.process.pid, signal.SIGINT)
        try:
            return self.process.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            pytest.fail(f"still running {STOP_TIMEOUT_S} s after Ctrl-C:\n{self.log()}")

    def kill(self) -> None:
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(timeout=STOP_TIMEOUT_S)


@pytest.fixture
def group(ros_env, tmp_path) -> Iterator:
    started: list[Group] = []

    def start(*command: str) -> Group:
        started.append(Group(list(command), ros_env, tmp_path / f"group_{len(started)}.log"))
        return started[-1]

    yield start
    for job in started:
        job.kill()


def ros2(env: dict[str, str], *arguments: str) -> subprocess.CompletedProcess:
    """One `ros2` command, bounded; never the daemon (it would outlive the test)."""
    return subprocess.run(
        ["ros2", *arguments], env=env, capture_output=True, text=True, timeout=CLI_TIMEOUT_S
    )


# one_process:=true: sim_world_node's process and beams_bringup's robot (the three other nodes)
@pytest.mark.parametrize(("one_process", "processes"), [("false", LAUNCHED_PROCESSES), ("true", 2)])
def test_ros2_launch_in_a_namespace_starts_every_node_and_ctrl_c_stops_them_cleanly(
    rclpy_node, group, one_process, processes
):
    from diagnostic_msgs.msg import DiagnosticArray

    from beams_msgs.msg import BeaconBearingArray

    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    bearings = rclpy_node.subscribe(BeaconBearingArray, "/robot1/beams/bearings")
    launch = group(
        "ros2",
        "launch",
        "beams_bringup",
        "beams.launch.py",
        "namespace:=robot1",
        f"one_process:={one_process}",
    )

    def all_up() -> bool:
        names = {status.name for msg in diagnostics for status in msg.status}
        return all(any(f"/robot1/{node}" in name for name in names) for node in LAUNCHED_NODES)

    assert rclpy_node.spin_until(all_up, UP_TIMEOUT_S), launch.log()
    assert rclpy_node.spin_until(lambda: len(bearings) >= 5, UP_TIMEOUT_S), launch.log()
    assert all(len(msg.bearings) == 3 for msg in bearings[1:]), "the simulated robot sees all 3 beacons"
    status = launch.ctrl_c()
    output = launch.log()
    assert status == 0, output
    for bad in ("Traceback", "process has died", "deprecated", "UserWarning"):
        assert bad not in output, f"{bad!r} in the launch output:\n{output}"
    assert output.count("process has finished cleanly") == processes, output


def test_ros2_run_topic_echo_param_and_service(ros_env, group):
    run = group(
        "ros2",
        "run",
        "beams_driver",
        "driver_node",
        "--ros-args",
        "-p",
        f"sim_static_pose:={STATIC_POSE}",
    )
    echo = ros2(ros_env, "topic", "echo", "--once", "--no-daemon", "--timeout", "40", "/beams/bearings")
    assert echo.returncode == 0, echo.stdout + echo.stderr + run.log()
    assert echo.stdout.count("beacon_id:") == 3 and "frame_id: beams_sensor" in echo.stdout, echo.stdout

    listed = ros2(ros_env, "param", "list", "--no-daemon", "/driver_node")
    assert {"code_count", "variance_mode", "natural_variance_rad2"} <= set(listed.stdout.split()), listed

    got = ros2(ros_env, "param", "get", "--no-daemon", "/driver_node", "code_count")
    assert got.stdout.strip() == "Integer value is: 5", got.stdout + got.stderr
    # The code list defines the sensor: read-only, refused with the reason, the value in use stays.
    refused = ros2(ros_env, "param", "set", "--no-daemon", "/driver_node", "code_count", "4")
    assert "Setting parameter failed" in refused.stderr and "read-only" in refused.stderr, (
        refused.stdout + refused.stderr
    )
    got = ros2(ros_env, "param", "get", "--no-daemon", "/driver_node", "code_count")
    assert got.stdout.strip() == "Integer value is: 5", got.stdout + got.stderr
    # A runtime parameter outside its range: refused; inside it: applied.
    refused = ros2(ros_env, "param", "set", "--no-daemon", "/driver_node", "natural_variance_rad2", "1.0")
    assert "Setting parameter failed" in refused.stderr and "out of range" in refused.stderr, (
        refused.stdout + refused.stderr
    )
    applied = ros2(ros_env, "param", "set", "--no-daemon", "/driver_node", "variance_mode", "bound")
    assert "Set parameter successful" in applied.stdout, applied.stdout + applied.stderr

    # No calibration_file: the reload is refused with the reason, not a false success.
    called = ros2(ros_env, "service", "call", "/driver_node/reload_calibration", "std_srvs/srv/Trigger")
    assert called.returncode == 0, called.stdout + called.stderr
    assert "success=False" in called.stdout and "calibration_file parameter is empty" in called.stdout, (
        called.stdout
    )

    started_s = time.monotonic()
    status = run.ctrl_c()
    output = run.log()
    assert status == 0 and "Traceback" not in output, output
    assert time.monotonic() - started_s < 5.0, "ros2 run took more than 5 s to stop on Ctrl-C"


def test_ros2_lifecycle_drives_the_driver_launched_for_a_lifecycle_manager(rclpy_node, ros_env, group):
    """`ros2 launch ... driver_autostart:=false`: every node up, the driver unconfigured and silent;
    `ros2 lifecycle get/set` configure (still silent), activate (bearings), deactivate and cleanup; a
    transition the state does not offer is refused; Ctrl-C stops every node cleanly. Launched with
    ekf_standby:=false too: one ekf_node process, no standby."""
    from beams_msgs.msg import BeaconBearingArray

    probe = subprocess.run(
        ["python", "-c", "import ros2lifecycle"], capture_output=True, text=True, timeout=60
    )
    if probe.returncode != 0:
        pytest.skip(
            f"`ros2 lifecycle` missing ({probe.stderr.strip().splitlines()[-1]}): ros2cli's ros2lifecycle"
        )
    bearings = rclpy_node.subscribe(BeaconBearingArray, "/robot1/beams/bearings")
    launch = group(
        "ros2",
        "launch",
        "beams_bringup",
        "beams.launch.py",
        "namespace:=robot1",
        "driver_autostart:=false",
        "ekf_standby:=false",
    )
    driver = "/robot1/driver_node"

    def lifecycle(verb: str, *arguments: str) -> subprocess.CompletedProcess:
        return ros2(ros_env, "lifecycle", verb, "--no-daemon", driver, *arguments)

    deadline = time.monotonic() + UP_TIMEOUT_S
    state = lifecycle("get")
    while "unconfigured [1]" not in state.stdout and time.monotonic() < deadline:
        time.sleep(0.5)  # "Node not found" until discovery
        state = lifecycle("get")
    assert state.stdout.strip() == "unconfigured [1]", state.stdout + state.stderr + launch.log()

    def silent() -> bool:
        count = len(bearings)
        rclpy_node.spin_for(1.5)
        return len(bearings) == count

    assert silent(), "bearings published while unconfigured"
    for transition, expected in (("configure", "inactive [2]"), ("activate", "active [3]")):
        changed = lifecycle("set", transition)
        assert "Transitioning successful" in changed.stdout, changed.stdout + changed.stderr
        assert lifecycle("get").stdout.strip() == expected
        if transition == "configure":
            assert silent(), "bearings published while inactive"
    assert rclpy_node.spin_until(lambda: len(bearings) >= 5, UP_TIMEOUT_S), launch.log()
    assert all(len(msg.bearings) == 3 for msg in bearings[-3:]), "the simulated robot sees all 3 beacons"
    ekf_processes = [c for c in descendants(launch.process.pid).values() if "/ekf_node " in c + " "]
    assert len(ekf_processes) == 1 and "--standby" not in ekf_processes[0], ekf_processes

    # a transition the state does not offer: the CLI lists the available ones, the node lives on
    refused = lifecycle("set", "cleanup")
    assert "Unknown transition requested" in refused.stdout + refused.stderr, refused.stdout + refused.stderr
    for transition, expected in (("deactivate", "inactive [2]"), ("cleanup", "unconfigured [1]")):
        changed = lifecycle("set", transition)
        assert "Transitioning successful" in changed.stdout, changed.stdout + changed.stderr
        assert lifecycle("get").stdout.strip() == expected
    rclpy_node.spin_for(0.3)  # bearings in flight at the deactivation
    assert silent(), "bearings published after the deactivation"

    status = launch.ctrl_c()
    output = launch.log()
    assert status == 0, output
    for bad in ("Traceback", "process has died", "deprecated", "UserWarning"):
        assert bad not in output, f"{bad!r} in the launch output:\n{output}"
    assert output.count("process has finished cleanly") == len(LAUNCHED_NODES), output


def descendants(pid: int) -> dict[int, str]:
    """Every process under `pid` (children, grandchildren...) with its command line, from /proc."""
    parents: dict[int, int] = {}
    commands: dict[int, str] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as stat:
                # the command name is in parentheses and may hold spaces: the parent id follows it
                parents[int(entry)] = int(stat.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{entry}/cmdline", "rb") as cmdline:
                commands[int(entry)] = cmdline.read().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError, ValueError):  # a process that ended meanwhile
            continue
    found: dict[int, str] = {}
    frontier = [pid]
    while frontier:
        parent = frontier.pop()
        for child, its_parent in parents.items():
            if its_parent == parent and child not in found:
                found[child] = commands.get(child, "")
                frontier.append(child)
    return found


def test_ros2_launch_respawns_each_killed_node_and_the_ekf_comes_back(rclpy_node, ros_env, group):
    """Issue 18: each node launched with respawn, ekf_node as its hot standby pair; kill -9 each in turn
    (of the EKF, the active process), the EKF's output is back within 2 s (test_respawn.py), the launch
    log says the process died, the killed one is respawned, and Ctrl-C still stops everything."""
    from nav_msgs.msg import Odometry

    from beams_common.ros.standby import NodeIdentity, RoleLock, domain_id_of, role_name

    arrivals: list[float] = []
    rclpy_node.node.create_subscription(
        Odometry, "/robot1/beams/ekf/odometry", lambda _msg: arrivals.append(time.monotonic()), 10
    )
    launch = group("ros2", "launch", "beams_bringup", "beams.launch.py", "namespace:=robot1")
    assert rclpy_node.spin_until(lambda: len(arrivals) > 5, UP_TIMEOUT_S), launch.log()

    def processes(name: str) -> list[int]:
        return [
            pid for pid, command in descendants(launch.process.pid).items() if f"/{name} " in command + " "
        ]

    for node in LAUNCHED_NODES:
        pids = processes(node)
        assert len(pids) == (2 if node == "ekf_node" else 1), (node, descendants(launch.process.pid))
        # every node holds its role (beams_common.ros.standby): of the EKF's pair, the active one
        holder = RoleLock(role_name(NodeIdentity("/robot1", node), domain_id_of(ros_env))).holder_pid()
        assert holder in pids, (node, holder, pids)
        killed_at = time.monotonic()
        os.kill(holder, signal.SIGKILL)
        assert rclpy_node.spin_until(lambda since=killed_at: any(t > since + 0.2 for t in arrivals), 2.0), (
            f"no EKF output within 2 s of killing {node}:\n{launch.log()}"
        )

        def respawned(name: str = node, before: list[int] = pids, killed: int = holder) -> bool:
            now = processes(name)
            return len(now) == len(before) and killed not in now

        assert rclpy_node.spin_until(respawned, UP_TIMEOUT_S), f"{node} not respawned:\n{launch.log()}"
    output = launch.log()
    assert output.count("process has died") == len(LAUNCHED_NODES), output
    status = launch.ctrl_c()
    assert status == 0, launch.log()
    assert "Traceback" not in launch.log(), launch.log()
