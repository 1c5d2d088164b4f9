"""Node-level integrity: how fast the EKF is back after a node dies, and how fast a second publisher is said.

The robot's nodes run under the demo's supervisor (respawn after RESPAWN_DELAY_S), ekf_node as its hot
standby pair; each node (of the pair, the active one) is killed with SIGKILL KILL_ROUNDS times, timing the
EKF's next beams/ekf/odometry message and its longest silence within SILENCE_WINDOW_S; the standby's RSS and
CPU over STANDBY_WATCH_S; then a second driver_node, ROUNDS times: the delay to ERROR on ekf_node's and
triangulation_node's /diagnostics. In ROS_DOMAIN_ID 69 unless the environment sets one; needs `make build`.
"""

import itertools
import os
import pathlib
import signal
import sys
import tempfile
import time

from rows_table import RosProbe, Row, bench_main

ROOT = pathlib.Path(__file__).resolve().parents[1]
DEFAULT_DOMAIN_ID = "69"  # 61-69 are the developers' (test/conftest.py); the tests never use it
KILL_ROUNDS = 3
SECOND_DRIVER_ROUNDS = 3
UP_TIMEOUT_S = 60.0
BACK_TIMEOUT_S = 20.0
SETTLE_S = 2.0
SILENCE_WINDOW_S = 8.0
STANDBY_WATCH_S = 10.0


class Probe(RosProbe):
    """An rclpy node timing the EKF's output and the watchers' /diagnostics."""

    def __init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry

        super().__init__("integrity_bench_probe")
        self.ekf_outputs: list[float] = []
        self.statuses: dict[str, list] = {"ekf_node": [], "triangulation_node": []}
        self.node.create_subscription(Odometry, "/beams/ekf/odometry", self._on_ekf, 10)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)

    def _on_ekf(self, _msg) -> None:
        self.ekf_outputs.append(time.monotonic())

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            for name, seen in self.statuses.items():
                if f"/{name}:" in status.name:
                    seen.append((time.monotonic(), status))


def longest_silence(arrivals: list[float], start: float, end: float) -> float:
    """The longest interval without an arrival within [start, end] (s)."""
    inside = [start, *sorted(t for t in arrivals if start < t < end), end]
    return max(later - earlier for earlier, later in itertools.pairwise(inside))


def kill_delays(probe: Probe, supervisor, node_names: list[str]) -> tuple[dict, dict]:
    """For each node, KILL_ROUNDS times: SIGKILL, then the delay to the EKF's next output and the
    longest EKF silence in the SILENCE_WINDOW_S after the kill (s)."""
    delays: dict[str, list[float]] = {name: [] for name in node_names}
    silences: dict[str, list[float]] = {name: [] for name in node_names}
    for _ in range(KILL_ROUNDS):
        for name in node_names:
            probe.spin_until(lambda: False, SETTLE_S, supervisor.poll)
            process = supervisor.active(name)  # of a hot standby pair, the active one
            if process is None:
                raise RuntimeError(f"no process of {name} holds its role")
            killed_at = time.monotonic()
            os.kill(supervisor.pid(process), signal.SIGKILL)
            # messages already in flight at the kill do not count
            if not probe.spin_until(
                lambda since=killed_at + 0.2: any(t > since for t in probe.ekf_outputs),
                BACK_TIMEOUT_S,
                supervisor.poll,
            ):
                raise RuntimeError(f"no EKF output within {BACK_TIMEOUT_S} s of killing {name}")
            delays[name].append(min(t for t in probe.ekf_outputs if t > killed_at + 0.2) - killed_at)
            # the killed node must be running again before the next kill
            probe.spin_until(lambda p=process: supervisor.pid(p) is not None, BACK_TIMEOUT_S, supervisor.poll)
            end = killed_at + SILENCE_WINDOW_S
            probe.spin_until(lambda end=end: time.monotonic() > end, 60.0, supervisor.poll)
            silences[name].append(longest_silence(probe.ekf_outputs, killed_at, end))
    return delays, silences


def standby_figures(probe: Probe, supervisor, executable: str) -> tuple[float, float]:
    """The waiting standby of a node's pair: its resident memory (MiB) and its CPU over STANDBY_WATCH_S
    (% of one core), from /proc."""
    active = supervisor.active(executable)
    waiting = next(name for name in supervisor.processes_of(executable) if name != active)
    pid = supervisor.pid(waiting)
    started_s, cpu_start_s = time.monotonic(), process_cpu_s(pid)
    probe.spin_until(lambda: False, STANDBY_WATCH_S, supervisor.poll)
    cpu_percent = 100.0 * (process_cpu_s(pid) - cpu_start_s) / (time.monotonic() - started_s)
    with open(f"/proc/{pid}/status") as status:
        rss_kib = next(int(line.split()[1]) for line in status if line.startswith("VmRSS:"))
    return rss_kib / 1024.0, cpu_percent


def process_cpu_s(pid: int) -> float:
    """The CPU time of every thread of a process so far (s; the scheduler's nanoseconds: a tick is 10 ms)."""
    total_ns = 0
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/schedstat") as schedstat:
            total_ns += int(schedstat.read().split()[0])
    return total_ns * 1e-9


def second_driver_delays(probe: Probe, supervisor, command: list[str]) -> list[float]:
    """Start a second driver, time ERROR naming both on each watcher's /diagnostics, stop it."""
    from diagnostic_msgs.msg import DiagnosticStatus

    def says_two(status) -> bool:
        return status.level == DiagnosticStatus.ERROR and "/driver_node (x2)" in status.message

    delays = []
    for _ in range(SECOND_DRIVER_ROUNDS):
        # the previous round's ERROR gone (its hold, its graph entry)
        probe.spin_until(
            lambda: all(s and not says_two(s[-1][1]) for s in probe.statuses.values()), 15.0, supervisor.poll
        )
        supervisor.add("second_driver", command)
        try:
            if not probe.spin_until(
                lambda: probe.node.count_publishers("/beams/bearings") == 2, UP_TIMEOUT_S, supervisor.poll
            ):
                raise RuntimeError("the second driver never showed in the graph")
            appeared = time.monotonic()

            def said_after(name: str, since: float = appeared) -> float | None:
                return next((t for t, s in probe.statuses[name] if t >= since and says_two(s)), None)

            if not probe.spin_until(
                lambda: all(said_after(n) is not None for n in probe.statuses), 10.0, supervisor.poll
            ):
                raise RuntimeError("the second driver was not said at ERROR within 10 s")
            delays += [said_after(n) - appeared for n in probe.statuses]
        finally:
            supervisor.remove("second_driver")
    return delays


def rows() -> list[Row]:
    os.environ.setdefault("ROS_DOMAIN_ID", DEFAULT_DOMAIN_ID)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    from beams_bringup.demo import node_commands, sensor_setup
    from beams_sim.simulated_match import SENSOR_MODELS
    from beams_tools.robot_processes import RESPAWN_DELAY_S, ROBOT_NODES
    from beams_tools.supervisor import NodeSupervisor

    with tempfile.TemporaryDirectory() as directory:
        output = pathlib.Path(directory)
        env = {**os.environ, "ROS_HOME": str(output / "ros_home")}
        # the plain defaults a user gets: uncalibrated, self-calibrating (make demo without --calibrated)
        commands = node_commands(600.0, sensor_setup(SENSOR_MODELS[0], output, calibrated=False))
        supervisor = NodeSupervisor(commands, env, output)
        probe = Probe()
        supervisor.start()
        try:
            if not probe.spin_until(lambda: bool(probe.ekf_outputs), UP_TIMEOUT_S, supervisor.poll):
                logs = "\n".join(n.log_path.read_text()[-2000:] for n in supervisor.nodes.values())
                raise RuntimeError(f"no EKF output within {UP_TIMEOUT_S} s:\n{logs}")
            kills, silences = kill_delays(probe, supervisor, [node.executable for node in ROBOT_NODES])
            standby_mib, standby_cpu_percent = standby_figures(probe, supervisor, "ekf_node")
            second = second_driver_delays(probe, supervisor, commands["driver_node"])
        finally:
            supervisor.stop()
            probe.close()
    print(f"EKF back after each kill (s): {kills}; longest EKF silence (s): {silences}", file=sys.stderr)
    print(f"second driver said after (s): {second}", file=sys.stderr)
    print(f"ekf_node's standby: {standby_mib:.1f} MiB, {standby_cpu_percent:.3f} % CPU", file=sys.stderr)
    result: list[Row] = []
    standby_nodes = {node.executable for node in ROBOT_NODES if node.hot_standby}
    for name, delays in kills.items():
        how = (
            "its hot standby's takeover"
            if name in standby_nodes
            else f"{RESPAWN_DELAY_S:g} s respawn delay + start-up"
        )
        goal = f"goal 2 s ({how})"
        result.append(
            (f"EKF output again after kill -9 of {name}, worst of {KILL_ROUNDS}", max(delays), "s", goal)
        )
        window = f"{SILENCE_WINDOW_S:g} s"
        figure = f"longest EKF silence in the {window} after kill -9 of {name}, worst of {KILL_ROUNDS}"
        result.append((figure, max(silences[name]), "s", "0.05 s (publish_rate_hz 20) when nothing stops"))
    waiting = f"ekf_node's hot standby while it waits, over {STANDBY_WATCH_S:g} s"
    result.append((f"{waiting}: resident memory (VmRSS)", standby_mib, "MiB", "its modules imported, no DDS"))
    result.append((f"{waiting}: CPU", standby_cpu_percent, "% of one core", "about 0 (it blocks)"))
    result.append(
        (
            f"second driver_node said ERROR (ekf and triangulation), worst of {len(second)}",
            max(second),
            "s",
            "goal 1 s",
        )
    )
    return result


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
