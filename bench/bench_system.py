"""Whole-system benchmark ("Latency and throughput") and the budget of the three nodes a robot runs.

Starts sim_world_node, driver_node, triangulation_node and ekf_node from the install tree, one process each,
in ROS_DOMAIN_ID 68 unless the environment sets one; driver_node reads its serial source on a pty fed by a
simulated turret in its own process (beams_tools.serial_feed_node, on the world's truth). A probe node here
measures: the latency from a revolution's arrival to the first EKF output, and to its ToTal pose; each
node's CPU (/proc/<pid>/stat), the three robot nodes' together also per CPU second of a fixed numpy
workload run alongside (a loaded machine slows both), and their resident memory; a flood of 10x the
revolutions for 30 s (peak RSS, growth); kill -9 and SIGTERM restarts (delay to the first output). A
budget row says `met` or `MISSED` (exit 1). `--source sim`: the driver simulates the sensor (its CPU
includes the simulation); `virtual_turret`: the firmware in simavr (`make hil`). `--profile NODE[,NODE...]`:
each under cProfile during the latency window, NODE.prof written here (docs/performance.md), only those rows.

`--one-process`: driver_node, triangulation_node and ekf_node as nodes of one process (beams_bringup's
robot), its rows named `robot`. `--floor`: triangulation_node and ekf_node replaced by stand-ins with their
topics, rates and executor and no work of their own (bench/floor_node.py): what rclpy costs them; only
the latency and CPU rows.

Usage: python bench/bench_system.py [--flood-s S] [--source sim|virtual_turret] [--profile NODE]
[--one-process | --floor]   (`rows()`: bench/run_all.py)
"""

import os
import pathlib
import signal
import sys
import tempfile
import time
from copy import deepcopy
from dataclasses import dataclass, field

import numpy as np
from rows_table import RosProbe, Row, bench_main, budget_row

ROOT = pathlib.Path(__file__).resolve().parents[1]
INSTALL_BASE = pathlib.Path(os.environ.get("BEAMS_INSTALL_BASE", ROOT / "install"))
# the robot's nodes (beams_tools.robot_processes), one process each (no hot standby), with these overrides
# (triangulation_node's markers are left on, its default: nothing here reads them, so none is built)
ROS_ARGUMENTS = {"sim_world_node": ["-p", "duration_s:=300.0"]}
# the serial feed writes a revolution as it ends, and its closing zero reference comes with the next one:
# the driver publishes it a turn later than a turret would, its newest bearing ~0.2 s old (0.25 s refused)
FEED_ARGUMENTS = ["-p", "max_stamp_age_s:=0.5"]
DEFAULT_DOMAIN_ID = "68"  # 61-69 are the developers' (test/conftest.py); the tests never use it
START_TIMEOUT_S = 60.0
LATENCY_WINDOW_S = 15.0
FLOOD_RATE_FACTOR = 10
FLOOD_S = 30.0
RESTARTS = 4
RECOVERY = "recovery within 2 s"
REVOLUTION_RATE_HZ = 10.0
CLOCK_TICKS_HZ = os.sysconf("SC_CLK_TCK")
ROBOT = ("driver_node", "triangulation_node", "ekf_node")
# the budget of the three robot nodes together at 10 revolutions/s with 50 Hz odometry
CPU_BUDGET_PERCENT = 8.0
RSS_BUDGET_MIB = 250.0
LATENCY_BUDGET_MS = {50: 1.0, 99: 2.0}
# the reference workload's CPU time (s) here, 2026-11-27 (median of 10 runs, load 6-18): the budget's unit
REFERENCE_CPU_S_CALIBRATED = 0.046
CPU_BUDGET_REFERENCES = CPU_BUDGET_PERCENT / 100.0 / REFERENCE_CPU_S_CALIBRATED
# python -c PROFILED OUTPUT EXECUTABLE ARGS...: cProfile from SIGUSR1 to SIGUSR2 (the start-up left out)
PROFILED = (
    "import cProfile, runpy, signal, sys, time; "
    "profile, output = cProfile.Profile(time.process_time), sys.argv[1]; "
    "signal.signal(signal.SIGUSR1, lambda *_: profile.enable()); "
    "signal.signal(signal.SIGUSR2, lambda *_: (profile.disable(), profile.dump_stats(output))); "
    "sys.argv = sys.argv[2:]; runpy.run_path(sys.argv[0], run_name='__main__')"
)


@dataclass
class Arrivals:
    """Monotonic arrival times (s) at the probe, per topic."""

    bearings: list[float] = field(default_factory=list)
    # (first, last) bearing stamps (s) of each revolution, in arrival order
    bearing_spans: list[tuple[float, float]] = field(default_factory=list)
    ekf: list[float] = field(default_factory=list)
    total: list[float] = field(default_factory=list)
    total_stamps: list[float] = field(default_factory=list)
    last_bearings: object = None


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process and its running children (s), fields 14 and 15 of /proc/<pid>/stat."""
    fields = pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    children = pathlib.Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS_HZ + sum(cpu_seconds(int(c)) for c in children)


def memory_kb(pid: int) -> dict[str, int]:
    """VmRSS and VmHWM (peak RSS) of a process, kB."""
    fields = (line.partition(":") for line in pathlib.Path(f"/proc/{pid}/status").read_text().splitlines())
    return {key: int(rest.split()[0]) for key, _, rest in fields if key in ("VmRSS", "VmHWM")}


def reference_cpu_s(rounds: int = 5) -> float:
    """CPU time (s) of a fixed numpy workload, the median of `rounds`: 3000 small solves and products, the
    size and kind of an EKF update's, in a Python loop (the nodes' work is that mix)."""
    a, b = np.eye(7) + 0.01, np.ones((7, 2))
    times = []
    for _ in range(rounds):
        start = time.process_time()
        for _ in range(3000):
            np.linalg.solve(a, a @ b)
        times.append(time.process_time() - start)
    return float(np.median(times))


def latencies_ms(causes: list[float], effects: list[float]) -> np.ndarray:
    """For each cause, the delay (ms) to the first effect after it (causes with none after are left out)."""
    effects_array = np.asarray(effects)
    index = np.searchsorted(effects_array, causes, side="right")
    valid = index < len(effects_array)
    return 1e3 * (effects_array[index[valid]] - np.asarray(causes)[valid])


def pose_latencies_ms(arrivals: "Arrivals", since: float) -> np.ndarray:
    """Delay (ms) from each revolution's arrival to the arrival of the ToTal pose computed from it (the
    pose's stamp lies within its bearings' stamps); revolutions without a pose give none."""
    delays = []
    spans = np.array(arrivals.bearing_spans).reshape(-1, 2)
    for arrival, stamp in zip(arrivals.total, arrivals.total_stamps, strict=True):
        inside = np.flatnonzero((spans[:, 0] - 1e-6 <= stamp) & (stamp <= spans[:, 1] + 1e-6))
        if len(inside) and arrivals.bearings[inside[-1]] >= since:
            delays.append(1e3 * (arrival - arrivals.bearings[inside[-1]]))
    return np.array(delays)


class Probe(RosProbe):
    """The benchmark's rclpy node: arrival times of the bearings, EKF outputs and ToTal poses."""

    def __init__(self) -> None:
        from nav_msgs.msg import Odometry

        from beams_msgs.msg import BeaconBearingArray, TriangulatedPose

        super().__init__("beams_bench_probe")
        self.arrivals = Arrivals()
        self.node.create_subscription(BeaconBearingArray, "beams/bearings", self._on_bearings, 10)
        self.node.create_subscription(
            Odometry, "beams/ekf/odometry", lambda _: self.arrivals.ekf.append(time.monotonic()), 50
        )
        self.node.create_subscription(TriangulatedPose, "beams/pose", self._on_total, 50)
        self.flooding = False

    def _on_bearings(self, msg) -> None:
        if not self.flooding:  # the flood's own copies come back to the probe too
            self.arrivals.bearings.append(time.monotonic())
            stamps = [seconds(b.header.stamp) for b in msg.bearings] or [seconds(msg.header.stamp)]
            self.arrivals.bearing_spans.append((min(stamps), max(stamps)))
        self.arrivals.last_bearings = msg

    def _on_total(self, msg) -> None:
        self.arrivals.total.append(time.monotonic())
        self.arrivals.total_stamps.append(seconds(msg.header.stamp))

    def spin_for(self, duration_s: float) -> None:
        self.spin_until(lambda: False, duration_s)

    def flood(self, duration_s: float, rate_hz: float) -> int:
        """Republish the newest revolution at rate_hz, its stamps moved to now; the count published."""
        # only now: a second publisher on beams/bearings is an ERROR condition of the nodes (input_watch)
        publisher = self.node.create_publisher(type(self.arrivals.last_bearings), "beams/bearings", 10)
        count = 0
        self.flooding = True
        deadline = time.monotonic() + duration_s
        next_s = time.monotonic()
        while time.monotonic() < deadline:
            template = self.arrivals.last_bearings
            if template is not None:
                publisher.publish(restamped(template, self.node.get_clock().now().nanoseconds))
                count += 1
            next_s += 1.0 / rate_hz
            while time.monotonic() < next_s:
                self.executor.spin_once(timeout_sec=max(0.0, next_s - time.monotonic()))
        self.flooding = False
        return count


def seconds(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


def restamped(msg, now_ns: int):
    """A copy of a revolution whose newest bearing is stamped now (the others keep their offsets)."""
    copy = deepcopy(msg)
    headers = [copy.header, *(b.header for b in copy.bearings)]
    shift = now_ns - max(h.stamp.sec * 1_000_000_000 + h.stamp.nanosec for h in headers[1:] or headers)
    for header in headers:
        moved = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec + shift
        header.stamp.sec, header.stamp.nanosec = divmod(moved, 1_000_000_000)
    return copy


def rows(
    flood_s: float = FLOOD_S,
    source: str = "serial_feed",
    profile: str = "",
    one_process: bool = False,
    floor: bool = False,
) -> list[Row]:
    if floor and one_process:
        raise ValueError(
            "--floor stands in for triangulation_node and ekf_node: a process each, not --one-process"
        )
    os.environ.setdefault("ROS_DOMAIN_ID", DEFAULT_DOMAIN_ID)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    from beams_ekf.parameters import EKF_PARAMETERS
    from beams_tools.robot_processes import ONE_PROCESS, process_commands, robot_processes
    from beams_tools.supervisor import NodeSupervisor

    with tempfile.TemporaryDirectory(prefix="beams_bench_system_") as log_dir:
        env = dict(os.environ, PYTHONUNBUFFERED="1", ROS_HOME=f"{log_dir}/ros_home")  # its own checkpoint
        probe = Probe()
        commands = process_commands(INSTALL_BASE, ROS_ARGUMENTS, robot_processes(one_process), standby=False)
        link, turret = pathlib.Path(log_dir) / "turret", {}
        if source == "virtual_turret":  # it runs the world (its arguments), first: driver_node opens its link
            executable = INSTALL_BASE / "beams_sim/lib/beams_sim/virtual_turret"
            turret = {source: [str(executable), "--link", str(link), *commands.pop("sim_world_node")[1:]]}
        elif source == "serial_feed":
            turret = {source: [sys.executable, "-m", "beams_tools.serial_feed_node", str(link)]}
        elif source != "sim":
            raise ValueError(f"source: serial_feed, sim or virtual_turret, not {source!r}")
        driver = ONE_PROCESS.executable if one_process else "driver_node"
        if turret:
            commands[driver] += ["-p", "source:=serial", "-p", f"device:={link}"]
        if source == "serial_feed":
            for name in {driver} if one_process else ("triangulation_node", "ekf_node"):
                commands[name] += FEED_ARGUMENTS
        for role in ("triangulation", "ekf") if floor else ():
            rate_hz = EKF_PARAMETERS.defaults()["publish_rate_hz"]
            stand_in = [sys.executable, str(ROOT / "bench/floor_node.py"), role, str(rate_hz)]
            commands[f"{role}_node"] = [*stand_in, "--ros-args", "-r", f"__node:={role}_node"]
        profiled = [name for name in profile.split(",") if name]
        for name in profiled:
            commands[name][:0] = [sys.executable, "-c", PROFILED, f"{os.getcwd()}/{name}.prof"]
        # the bench restarts a node itself (restart_rows): it never polls the supervisor
        supervisor = NodeSupervisor(turret, env, pathlib.Path(log_dir))
        supervisor.start()
        try:
            if turret and not probe.spin_until(link.exists, START_TIMEOUT_S):
                raise RuntimeError(f"no turret at {link}; logs in {log_dir}")
            for name, command in commands.items():
                supervisor.add(name, command)
            if not probe.spin_until(lambda: len(probe.arrivals.ekf) > 50, START_TIMEOUT_S):
                raise RuntimeError(f"no EKF output within {START_TIMEOUT_S} s; logs in {log_dir}")
            for name in profiled:
                os.kill(supervisor.pid(name), signal.SIGUSR1)
            table = latency_and_cpu_rows(probe, supervisor)
            for name in profiled:
                os.kill(supervisor.pid(name), signal.SIGUSR2)
            if not (profiled or floor):
                table += [memory_row(supervisor), *flood_rows(probe, supervisor, flood_s)]
                table += restart_rows(probe, supervisor)
            table = [(f"floor: {f}", *rest) for f, *rest in table] if floor else table
            return table if source == "serial_feed" else [(f"{source}: {f}", *rest) for f, *rest in table]
        finally:
            supervisor.stop()
            probe.close()


def latency_and_cpu_rows(probe: Probe, supervisor) -> list[Row]:
    """Latencies over LATENCY_WINDOW_S at the nominal rate, each node's CPU share over that window, the
    robot nodes' resident memory at its end, each beside its budget; the reference workload before and
    after the window (not during it: it would take a core from the nodes)."""
    pids = {name: supervisor.pid(name) for name in supervisor.nodes}
    arrivals = probe.arrivals
    reference_s = [reference_cpu_s()]
    first = len(arrivals.bearings)
    cpu_before = {name: cpu_seconds(pid) for name, pid in pids.items()}
    window_start = time.monotonic()
    probe.spin_for(LATENCY_WINDOW_S)
    window_s = time.monotonic() - window_start
    cpu_after = {name: cpu_seconds(pid) for name, pid in pids.items()}
    robot_names = [name for name in (*ROBOT, "robot") if name in pids]
    resident_mib = sum(memory_kb(pids[name])["VmRSS"] for name in robot_names) / 1024
    reference_s.append(reference_cpu_s())
    causes = arrivals.bearings[first:-2]
    rows = []
    for what, delays in (
        ("revolution -> EKF output", latencies_ms(causes, arrivals.ekf)),
        ("revolution -> its ToTal pose", pose_latencies_ms(arrivals, causes[0])),
    ):
        for percentile, limit in LATENCY_BUDGET_MS.items():
            value = float(np.percentile(delays, percentile))
            row = budget_row(f"latency {what}, p{percentile}", value, "ms", limit)
            rows.append(row if what.endswith("EKF output") else (*row[:3], "-"))
    received = len(causes) / window_s
    rows.append(
        ("revolutions received during the latency window", received, "1/s", f"nominal {REVOLUTION_RATE_HZ:g}")
    )
    share = {name: (cpu_after[name] - cpu_before[name]) / window_s for name in pids}
    for name in pids:
        rows.append((f"CPU {name} at 10 revolutions/s", 100.0 * share[name], "% of one core", "-"))
    robot = sum(share[name] for name in robot_names)
    reference = float(np.median(reference_s))
    rows += [
        budget_row("CPU driver + triangulation + EKF", 100.0 * robot, "% of one core", CPU_BUDGET_PERCENT),
        (
            "reference workload (numpy), CPU time",
            1e3 * reference,
            "ms",
            f"{1e3 * REFERENCE_CPU_S_CALIBRATED:g} ms calibrated",
        ),
        budget_row(
            "CPU driver + triangulation + EKF / reference",
            robot / reference,
            "references/s",
            CPU_BUDGET_REFERENCES,
        ),
        budget_row("resident memory driver + triangulation + EKF", resident_mib, "MiB", RSS_BUDGET_MIB),
    ]
    return rows


def flood_rows(probe: Probe, supervisor, flood_s: float) -> list[Row]:
    """10x the revolutions for flood_s: each node's CPU share, peak RSS and RSS growth."""
    rows = []
    pids = {name: supervisor.pid(name) for name in supervisor.nodes}
    rss_before = {name: memory_kb(pid)["VmRSS"] for name, pid in pids.items()}
    cpu_before = {name: cpu_seconds(pid) for name, pid in pids.items()}
    published = probe.flood(flood_s, FLOOD_RATE_FACTOR * REVOLUTION_RATE_HZ)
    cpu_after = {name: cpu_seconds(pid) for name, pid in pids.items() if supervisor.pid(name) is not None}
    probe.spin_for(1.0)
    compared = f"{FLOOD_RATE_FACTOR}x nominal, on top of the driver's"
    rows.append(
        (f"flood: revolutions published by the bench in {flood_s:g} s", published / flood_s, "1/s", compared)
    )
    for name, pid in pids.items():
        alive = supervisor.pid(name) is not None
        memory = memory_kb(pid) if alive else {"VmHWM": float("nan"), "VmRSS": float("nan")}
        state = "bounded" if alive else "NODE DIED"
        rows.append((f"flood: {name} peak RSS (VmHWM)", memory["VmHWM"] / 1024, "MiB", state))
        growth_mib = (memory["VmRSS"] - rss_before[name]) / 1024
        share = 100.0 * (cpu_after.get(name, float("nan")) - cpu_before[name]) / flood_s
        rows.append((f"flood: CPU {name}", share, "% of one core", "2-core machine"))
        rows.append((f"flood: {name} RSS growth during the flood", growth_mib, "MiB", "about 0 when bounded"))
    return rows


def memory_row(supervisor) -> Row:
    """The resident memory of the robot's processes together (VmRSS, the simulated robot's included)."""
    pids = [supervisor.pid(name) for name in supervisor.nodes]
    rss_mib = sum(memory_kb(pid)["VmRSS"] for pid in pids) / 1024
    return ("RSS of the robot's processes, sum", rss_mib, "MiB", f"{len(pids)} processes")


def restart_rows(probe: Probe, supervisor) -> list[Row]:
    """Stop and restart the triangulation and the EKF RESTARTS times each, by kill -9 and by SIGTERM: the
    delay from the new process's "ready" log line to its first output at the probe (DDS discovery
    included), and from its start (Python and rclpy start-up included)."""
    rows = []
    outputs = {"triangulation_node": probe.arrivals.total, "ekf_node": probe.arrivals.ekf}
    outputs = outputs if "ekf_node" in supervisor.nodes else {"robot": probe.arrivals.ekf}
    for stop_signal, how in ((signal.SIGKILL, "kill -9"), (signal.SIGTERM, "SIGTERM")):
        for executable, arrivals in outputs.items():
            from_ready, from_start = [], []
            for _ in range(RESTARTS):
                node = supervisor.nodes[executable]
                supervisor.signal(executable, stop_signal)
                node.process.wait(timeout=15)
                started = time.monotonic()
                supervisor.resume(executable)
                if not probe.spin_until(lambda node=node: "ready" in node.log_tail(1000), START_TIMEOUT_S):
                    raise RuntimeError(f"{executable} not ready {START_TIMEOUT_S} s after its restart")
                ready = time.monotonic()
                probe.spin_until(lambda ready=ready, arrivals=arrivals: arrivals[-1] > ready, START_TIMEOUT_S)
                first = next(t for t in arrivals if t > ready)
                from_ready.append(first - ready)
                from_start.append(first - started)
                probe.spin_for(1.0)
            for what, value, compared in (
                (f"ready -> first output, median of {RESTARTS}", float(np.median(from_ready)), RECOVERY),
                (f"ready -> first output, max of {RESTARTS}", max(from_ready), RECOVERY),
                (
                    f"process start -> first output, max of {RESTARTS}",
                    max(from_start),
                    "Python and rclpy start-up included",
                ),
            ):
                rows.append((f"restart after {how}: {executable} {what}", value, "s", compared))
    return rows


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
