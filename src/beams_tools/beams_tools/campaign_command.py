"""`fault_campaign`: plays a seeded schedule of faults against the whole running suite and
prints what it measured.

The robot's four nodes (sim_world_node, driver_node, triangulation_node, ekf_node) run as separate
processes over DDS, with fault_relay_node between the publishers and the filters (sim_world's odometry
and truth and the driver's bearings go to raw topics; the relay republishes them, wrong on request). A
probe node in this process records the simulator's truth (from the raw topic: only the real simulator
publishes there), the EKF's estimates and its /diagnostics, publishes the bad messages, makes the
service calls, parameter changes and lifecycle transitions (each answer awaited at most CALL_TIMEOUT_S,
while the probe keeps recording), and the campaign kills (kill -9), restarts, duplicates and supervises
the processes: a node that exits without being killed is counted dead and respawned after
RESPAWN_DELAY_S, as the launch file's respawn would. The figures come from beams_tools.campaign_metrics.

With --hosts, the driver runs on a second host (a network namespace joined to the main computer's by one
link, which the link_down faults cut); where namespaces cannot be made (root, iproute2) the class is
skipped and the report says so.

Usage: fault_campaign [--seed N] [--duration S] [--output DIR] [--serial] [--hosts] [-p ekf:NAME:=VALUE ...]
"""

import argparse
import collections
import concurrent.futures
import ctypes
import math
import multiprocessing
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import yaml

from beams_common.beacon_map import EUROBOT_BEACON_MAP
from beams_common.bearing_correction import BearingCorrection
from beams_common.calibration_file import SensorCalibration, save_calibration
from beams_common.standby import STANDBY_FLAG, role_holder_pid
from beams_driver.parameters import DRIVER_PARAMETERS
from beams_ekf.parameters import EKF_PARAMETERS
from beams_tools.campaign_metrics import CampaignFigures, campaign_figures, rss_growth_mb
from beams_tools.fault_schedule import (
    FAULT_CLASSES,
    LINK_CLASS,
    SERIAL_CLASS,
    Fault,
    ScheduleSettings,
    draw_schedule,
)
from beams_tools.serial_feed import SerialFeed
from beams_triangulation.parameters import TRIANGULATION_PARAMETERS

CALL_TIMEOUT_S = 5.0
# beams_bringup.system.RESPAWN_DELAY_S, the launch file's respawn_delay (test_respawn_delay_agrees checks)
RESPAWN_DELAY_S = 0.25
START_TIMEOUT_S = 90.0
STOP_TIMEOUT_S = 15.0
RSS_PERIOD_S = 5.0
# diagnostic_msgs/DiagnosticStatus levels, to name a status report's level in the reasons
LEVEL_NAMES = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
# a process's RSS counts from this long (s) after its start: its imports and first allocations are not growth
RSS_SETTLE_S = 10.0
BAD_MESSAGE_PERIOD_S = 0.1
# a bad message's publisher opens this long (s) before its first message: DDS discovery matches it
BAD_PUBLISHER_DISCOVERY_S = 0.5
# the relay's fault parameter and the fault's value of each class the relay plays
RELAY_FAULTS = {
    "odometry_jump": ("odometry_offset_x_m", "offset_x_m"),
    "odometry_delay": ("odometry_delay_s", "delay_s"),
    "bearing_stamp_offset": ("bearing_stamp_offset_s", "offset_s"),
}
# the serial feed extrapolates the truth at most this far (s) past its newest sample
MAX_EXTRAPOLATION_S = 0.2
# the simulator's longest match (its duration_s maximum); the robot stands still after it
SIM_MAX_MATCH_S = 600.0

# (package, executable, remappings) of each process the campaign starts
PROCESSES = {
    "sim_world": (
        "beams_sim",
        "sim_world_node",
        ("odom:=odom_raw", "beams/sim/ground_truth:=beams/sim/ground_truth_raw"),
    ),
    "driver": ("beams_driver", "driver_node", ("beams/bearings:=beams/bearings_raw",)),
    "triangulation": ("beams_triangulation", "triangulation_node", ()),
    "ekf": ("beams_ekf", "ekf_node", ()),
    "ekf_standby": ("beams_ekf", "ekf_node", ()),
    "relay": ("beams_tools", "fault_relay_node", ()),
}
# the nodes that run as a hot standby pair, as the launch file and the demo run them (beams_bringup.system's
# RobotNode.hot_standby; test/static/test_hot_standby_pairs.py checks that the two agree): the first
# process's name -> the second's; both start with --standby, a node_kill kills the one holding the role
HOT_STANDBY = {"ekf": "ekf_standby"}
NODE_NAMES = {name: executable for name, (_, executable, _) in PROCESSES.items()}
# A parameter per node for the parameter faults: (name, good value, out-of-range value, read-only name)
PARAMETER_FAULTS = {
    "ekf": ("gate_probability", 0.9995, 2.0, "odometry_history_s"),
    "triangulation": ("max_position_std_m", 0.06, -1.0, "use_odometry"),
    "driver": ("natural_variance_rad2", 2.0e-6, 1.0, "bit_time_s"),
}
TABLES = {"ekf": EKF_PARAMETERS, "triangulation": TRIANGULATION_PARAMETERS, "driver": DRIVER_PARAMETERS}
# a second ekf_node's child frame: the same launch twice but for this, so the probe tells the two
# estimate streams apart (the real one's is judged; the user of beams/ekf/odometry receives both)
DUPLICATE_EKF_FRAME = "base_link_duplicate_ekf"
# an operator's mistake: a pose this far (m) from the truth, claimed to this precision (m)
WRONG_PLACE_M = 0.5
WRONG_PLACE_SIGMA_M = 0.01
# a pose the ekf's operator services receive: the truth, with a covariance (m^2, rad^2) on the diagonal
OPERATOR_COVARIANCE = {"set_pose_huge_covariance": 1e12, "initialpose_huge_covariance": 1e300}


@dataclass
class CampaignConfig:
    """What one campaign runs: its seed and length, where its logs go, its DDS domain, parameters added
    to the nodes' (node -> {name: value}), instead of the seeded draw a schedule of its own, and whether
    driver_node reads a simulated sensor on a serial port (beams_tools.serial_feed: the line's faults are
    then drawn too) instead of its built-in simulated source, and whether the robot runs on two hosts
    (`Hosts`: the link_down faults are then drawn too)."""

    seed: int = 18
    duration_s: float = 120.0
    output_dir: pathlib.Path | None = None
    domain_id: int = 66  # 61-69 are the developers (test/conftest.py); the tests never use it
    overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    schedule: tuple[Fault, ...] | None = None
    warmup_s: float = 10.0
    install_base: pathlib.Path | None = None
    serial: bool = False
    # the robot on two hosts (network namespaces) joined by a link the link_down faults cut; skipped, and
    # said so, where namespaces cannot be made (hosts_problem)
    hosts: bool = False


@dataclass
class CallRecord:
    """One service call (or parameter change, or lifecycle transition) and its answer."""

    fault: str
    service: str
    answered: bool = False
    success: bool | None = None
    expected_success: bool | None = None
    detail: str = ""
    latency_s: float = math.nan


@dataclass
class Death:
    """A process that exited without the campaign killing it."""

    name: str
    campaign_s: float
    status: int
    fault: str
    log_tail: str


@dataclass
class CampaignResult:
    schedule: tuple[Fault, ...]
    figures: CampaignFigures
    calls: list[CallRecord]
    deaths: list[Death]
    rss_growth_mb: dict[str, float]
    output_dir: pathlib.Path
    notes: tuple[str, ...] = ()  # what the campaign left out, and why (a class it could not play here)

    @property
    def unanswered(self) -> list[CallRecord]:
        return [call for call in self.calls if not call.answered]

    @property
    def unexpected_answers(self) -> list[CallRecord]:
        """Answered, but not as expected: a bad change accepted, a good one refused."""
        return [c for c in self.calls if c.answered and c.expected_success not in (None, c.success)]

    def report(self) -> str:
        f = self.figures
        lines = [
            f"fault campaign: {len(self.schedule)} faults over {f.span_s:.0f} s measured "
            f"(logs in {self.output_dir})",
            f"misleading time {f.misleading_s:.2f} s (outside fault windows {f.misleading_outside_s:.2f} s, "
            f"largest misleading error {f.max_misleading_error_m:.3g} m)",
            f"availability {100 * f.availability:.1f} % (outside fault windows "
            f"{100 * f.availability_outside:.1f} % of {f.outside_s:.0f} s)",
            f"nodes dead {len(self.deaths)}, service calls {len(self.calls)}, unanswered "
            f"{len(self.unanswered)}, answered against expectation {len(self.unexpected_answers)}",
            "RSS growth (MB): " + ", ".join(f"{k} {v:+.1f}" for k, v in self.rss_growth_mb.items()),
            *self.notes,
            "per class: class | faults | window s | misleading s | availability % | "
            "largest misleading error m",
        ]
        for figures in f.per_class.values():
            lines.append(
                f"  {figures.kind} | {figures.faults} | {figures.window_s:.1f} | "
                f"{figures.misleading_s:.2f} | {100 * figures.availability:.1f} | "
                f"{figures.max_misleading_error_m:.3g}"
            )
        if f.unavailable_outside_by_reason:
            lines.append("unavailable outside fault windows, by the EKF's status: seconds | reason")
            lines += [
                f"  {seconds:.2f} | {reason}" for reason, seconds in f.unavailable_outside_by_reason.items()
            ]
        lines += [
            f"  dead: {d.name} at {d.campaign_s:.1f} s (exit {d.status}) during {d.fault}"
            for d in self.deaths
        ]
        lines += [f"  unanswered: {c.service} during {c.fault} ({c.detail})" for c in self.unanswered]
        lines += [
            f"  unexpected answer: {c.service} during {c.fault}: success={c.success} ({c.detail})"
            for c in self.unexpected_answers
        ]
        return "\n".join(lines)


# -- processes -------------------------------------------------------------------------------------------
@dataclass
class ManagedProcess:
    name: str
    command: list[str]
    log_dir: pathlib.Path
    process: subprocess.Popen | None = None
    incarnation: int = 0
    killed: bool = False  # by the campaign: its exit is not a death
    respawn_at_s: float | None = None
    rss_samples: list[tuple[float, float]] = field(default_factory=list)
    started_monotonic_s: float = 0.0

    def start(self, env: dict[str, str]) -> None:
        self.started_monotonic_s = time.monotonic()
        self.incarnation += 1
        self.killed = False
        self.respawn_at_s = None
        self.rss_samples = []
        log_path = self.log_dir / f"{self.name}.{self.incarnation}.log"
        with open(log_path, "w") as log:
            self.process = subprocess.Popen(
                self.command, env=env, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
            )

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def log_tail(self, lines: int = 15) -> str:
        path = self.log_dir / f"{self.name}.{self.incarnation}.log"
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:]) if path.exists() else ""

    def signal(self, sig: int) -> None:
        self.killed = True
        if self.running:
            self.process.send_signal(sig)

    def stop(self) -> int | None:
        if self.process is None:
            return None
        self.signal(signal.SIGINT)
        try:
            return self.process.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.process.kill()
            return self.process.wait(timeout=STOP_TIMEOUT_S)

    def sample_rss(self, now_s: float) -> None:
        if not self.running or time.monotonic() - self.started_monotonic_s < RSS_SETTLE_S:
            return
        try:
            status = pathlib.Path(f"/proc/{self.process.pid}/status").read_text()
        except OSError:
            return
        for line in status.splitlines():
            if line.startswith("VmRSS:"):
                self.rss_samples.append((now_s, int(line.split()[1]) / 1024.0))


def _executable(install_base: pathlib.Path, package: str, executable: str) -> str:
    path = install_base / package / "lib" / package / executable
    if not path.exists():
        raise FileNotFoundError(f"{path} is not installed: run `make build`")
    return str(path)


def node_parameters(config: CampaignConfig, serial_link: pathlib.Path) -> dict[str, dict[str, Any]]:
    """Each node's parameters: a random match seeded from the campaign's seed, plus the overrides."""
    parameters: dict[str, dict[str, Any]] = {
        "sim_world": {
            "trajectory": "random",
            "trajectory_seed": config.seed,
            "odometry_seed": config.seed + 1,
            "duration_s": min(SIM_MAX_MATCH_S, config.duration_s + 60.0),
        },
        "driver": (
            {"source": "serial", "device": str(serial_link)}
            if config.serial
            else {"sim_sensor_seed": config.seed + 2}
        ),
        "triangulation": {"publish_markers": False},
        "ekf": {},
        "relay": {},
    }
    for name, values in config.overrides.items():
        parameters[name].update(values)
    for first, second in HOT_STANDBY.items():  # one node, two processes
        parameters[second] = parameters[first]
    return parameters


def command_of(
    config: CampaignConfig,
    name: str,
    parameters: dict[str, Any],
    remaps: tuple[str, ...],
    log_dir: pathlib.Path,
) -> list[str]:
    package, executable, _ = PROCESSES[name.removeprefix("duplicate_")]
    standby = [STANDBY_FLAG] if name in HOT_STANDBY or name in HOT_STANDBY.values() else []
    command = [_executable(config.install_base, package, executable), *standby, "--ros-args"]
    if parameters:
        params_file = log_dir / f"{name}.params.yaml"
        params_file.write_text(yaml.safe_dump({"/**": {"ros__parameters": parameters}}))
        command += ["--params-file", str(params_file)]
    for remap in remaps:
        command += ["-r", remap]
    return command


# -- two hosts -------------------------------------------------------------------------------------------
# The robot on two hosts: driver_node on the sensor's computer, everything else (the other nodes, the
# relay and the campaign's probe) on the main computer, each a network namespace, joined by one veth link
# in a private subnet that exists only inside them (test/dds/test_system_hosts.py builds the same for
# two robots and a base station). DDS discovers across it with ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET.
HOST_SUBNET = "10.214.0"
HOST_ADDRESS = {"main": 1, "sensor": 2}
HOST_LINK = "eth0"
MULTICAST_RANGE = "224.0.0.0/4"
IP_TIMEOUT_S = 10.0
CLONE_NEWNET = 0x40000000
# the processes on the sensor's host; the others run on the main computer's
SENSOR_HOST_PROCESSES = ("driver",)


def hosts_problem() -> str:
    """Why network namespaces cannot be made here ('' when they can): root and iproute2's `ip`."""
    if os.geteuid() != 0:
        return "network namespaces need root (CAP_NET_ADMIN, CAP_SYS_ADMIN)"
    if shutil.which("ip") is None:
        return "iproute2's `ip` is missing (scripts/bootstrap.sh installs it)"
    return ""


def _ip(*args: str) -> None:
    result = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=IP_TIMEOUT_S)
    if result.returncode != 0:
        raise RuntimeError(f"`ip {' '.join(args)}` failed: {result.stderr.strip()}")


def _setns(path: str) -> None:
    """This thread (the main one: the probe's DDS participant and the processes it starts) into the
    network namespace at path (Python 3.11 has no os.setns)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        if ctypes.CDLL(None, use_errno=True).setns(fd, CLONE_NEWNET) != 0:
            raise OSError(ctypes.get_errno(), f"setns({path})")
    finally:
        os.close(fd)


def _remove_stale_namespaces() -> None:
    """Delete the namespaces of an earlier campaign whose process is gone (killed before its clean-up)."""
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=IP_TIMEOUT_S)
    for line in listed.stdout.splitlines():
        name = line.split()[0] if line.strip() else ""
        pid = name.removeprefix("beams-campaign-").split("-")[0]
        if name.startswith("beams-campaign-") and pid.isdigit() and not pathlib.Path(f"/proc/{pid}").exists():
            subprocess.run(["ip", "netns", "delete", name], capture_output=True, timeout=IP_TIMEOUT_S)


class Hosts:
    """The two namespaces and their link; `enter` moves the campaign's main thread onto the main
    computer's host (and `leave` back), `set_link` cuts or restores the link."""

    def __init__(self, tag: str) -> None:
        self.namespaces = {host: f"beams-campaign-{tag}-{host}" for host in HOST_ADDRESS}
        self._home: int | None = None

    def build(self) -> None:
        _remove_stale_namespaces()
        main, sensor = self.namespaces["main"], self.namespaces["sensor"]
        for name in self.namespaces.values():
            _ip("netns", "add", name)
            _ip("-n", name, "link", "set", "lo", "multicast", "on", "up")
        _ip("-n", main, "link", "add", HOST_LINK, "type", "veth", "peer", "name", HOST_LINK, "netns", sensor)
        for host, name in self.namespaces.items():
            _ip("-n", name, "addr", "add", f"{HOST_SUBNET}.{HOST_ADDRESS[host]}/24", "dev", HOST_LINK)
            _ip("-n", name, "link", "set", HOST_LINK, "multicast", "on", "up")
            _ip("-n", name, "route", "add", MULTICAST_RANGE, "dev", HOST_LINK)

    def exec_prefix(self, host: str) -> list[str]:
        return ["ip", "netns", "exec", self.namespaces[host]]

    def enter(self) -> None:
        self._home = os.open("/proc/self/ns/net", os.O_RDONLY)
        _setns(f"/var/run/netns/{self.namespaces['main']}")

    def leave(self) -> None:
        if self._home is not None:
            try:
                if ctypes.CDLL(None, use_errno=True).setns(self._home, CLONE_NEWNET) != 0:
                    raise OSError(ctypes.get_errno(), "setns back")
            finally:
                os.close(self._home)
                self._home = None

    def set_link(self, up: bool) -> None:
        _ip("-n", self.namespaces["main"], "link", "set", HOST_LINK, "up" if up else "down")

    def remove(self) -> None:
        for name in self.namespaces.values():
            subprocess.run(["ip", "netns", "delete", name], capture_output=True, timeout=IP_TIMEOUT_S)


# -- calibration files -----------------------------------------------------------------------------------
def write_calibration_files(directory: pathlib.Path) -> dict[str, pathlib.Path]:
    """The calibration files of the reload faults: a good one (the map, no correction) and bad ones."""
    corrections = {
        "good": BearingCorrection(),
        "rotation_bias_3rad": BearingCorrection(rotation_bias_coefficients=(3.0, 0.0, 0.0, 0.0)),
        "power_bias_1e300": BearingCorrection(power_bias_coefficients=(0.0, 0.0, 0.0, 1e300)),
    }
    paths = {}
    for name, correction in corrections.items():
        paths[name] = directory / f"calibration_{name}.yaml"
        save_calibration(SensorCalibration(EUROBOT_BEACON_MAP, correction), paths[name])
    paths["malformed"] = directory / "calibration_malformed.yaml"
    paths["malformed"].write_text("format: beams-calibration\nversion: 1\nbeacons: [{id: 1, x_m: oops\n")
    return paths


# -- the probe ------------------------------------------------------------------------------------------
class Probe:
    """The campaign's rclpy node: records, publishes the bad messages, calls the services."""

    def __init__(self, domain_id: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor

        from beams_common import topics
        from beams_common.ros.node_support import BEARINGS_QOS
        from beams_msgs.msg import BeaconBearingArray

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node("fault_campaign_probe", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.truth: list[tuple[float, float, float]] = []
        self.truth_orientation = None  # the newest true orientation (a quaternion message)
        # the recent true poses (t, x, y, theta), for the serial feed's thread
        self._recent_poses: collections.deque[tuple[float, float, float, float]] = collections.deque(
            maxlen=200
        )
        self._recent_lock = threading.Lock()
        self.ekf: list[tuple[float, ...]] = []
        self.duplicate_estimates = 0  # received from a second ekf_node (duplicate_publisher/ekf)
        self.status: list[tuple[float, float]] = []
        self.status_messages: list[tuple[float, int, str]] = []  # (stamp, level, message) of the EKF
        node = self.node
        node.create_subscription(Odometry, topics.GROUND_TRUTH + "_raw", self._on_truth, 100)
        node.create_subscription(Odometry, topics.EKF_ODOMETRY, self._on_ekf, 100)
        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diagnostics, 100)
        # bearings and odom have one publisher by design (a second is said at ERROR, input_watch): the
        # probe's exist only while a bad-message fault uses them (open_publisher, close_publisher)
        self._publisher_kinds = {
            "bearings": (BeaconBearingArray, topics.BEARINGS, BEARINGS_QOS),
            "odom": (Odometry, topics.ODOMETRY, 10),
        }
        self._publisher_users: dict[str, int] = {}
        self.publishers = {
            "initialpose": node.create_publisher(PoseWithCovarianceStamped, topics.INITIAL_POSE, 10),
        }
        self._clients: dict[str, Any] = {}
        self.pending: list[list[Any]] = []  # [record, client, request, deadline, sent, future, judge]
        self.calls: list[CallRecord] = []

    def now_s(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def open_publisher(self, name: str) -> None:
        """The probe's publisher on a single-publisher topic for a fault's window (counted: they overlap)."""
        if name not in self._publisher_kinds:
            return
        self._publisher_users[name] = self._publisher_users.get(name, 0) + 1
        if name not in self.publishers:
            self.publishers[name] = self.node.create_publisher(*self._publisher_kinds[name])

    def close_publisher(self, name: str) -> None:
        if name not in self._publisher_kinds or name not in self.publishers:
            return
        self._publisher_users[name] -= 1
        if self._publisher_users[name] == 0:
            self.node.destroy_publisher(self.publishers.pop(name))

    def spin(self, timeout_s: float) -> None:
        self.executor.spin_once(timeout_sec=timeout_s)

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    # recording
    def _on_truth(self, msg) -> None:
        from beams_common.ros.messages import stamp_to_seconds

        row = (stamp_to_seconds(msg.header.stamp), msg.pose.pose.position.x, msg.pose.pose.position.y)
        if all(math.isfinite(v) for v in row):
            self.truth.append(row)
            q = self.truth_orientation = msg.pose.pose.orientation
            heading = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
            with self._recent_lock:
                self._recent_poses.append((*row, heading))

    def _on_ekf(self, msg) -> None:
        from beams_common.ros.messages import stamp_to_seconds

        if msg.child_frame_id == DUPLICATE_EKF_FRAME:
            self.duplicate_estimates += 1
            return

        c = msg.pose.covariance
        p = msg.pose.pose.position
        self.ekf.append((stamp_to_seconds(msg.header.stamp), p.x, p.y, c[0], c[1], c[7]))

    def _on_diagnostics(self, msg) -> None:
        from diagnostic_msgs.msg import DiagnosticStatus

        from beams_common.ros.messages import stamp_to_seconds

        for status in msg.status:
            if status.name == f"/{NODE_NAMES['ekf']}: ekf":
                tracking = status.level == DiagnosticStatus.OK and status.message.startswith("tracking")
                stamp_s = stamp_to_seconds(msg.header.stamp)
                self.status.append((stamp_s, 1.0 if tracking else 0.0))
                self.status_messages.append((stamp_s, ord(status.level), status.message))

    def pose_at(self, host_s: float) -> tuple[float, float, float] | None:
        """The true pose at a host time: interpolated among the recent poses, extrapolated past the newest
        one with its velocity (the serial feed writes a revolution as it ends, a few ms ahead of the truth
        that reached the probe); None before any."""
        with self._recent_lock:
            recent = np.array(self._recent_poses, dtype=float).reshape(-1, 4)
        if len(recent) < 2:
            return None
        recent[:, 3] = np.unwrap(recent[:, 3])
        if host_s > recent[-1, 0]:
            rate = (recent[-1, 1:] - recent[-2, 1:]) / max(recent[-1, 0] - recent[-2, 0], 1e-6)
            x, y, theta = recent[-1, 1:] + rate * min(host_s - recent[-1, 0], MAX_EXTRAPOLATION_S)
        else:
            x, y, theta = (float(np.interp(host_s, recent[:, 0], recent[:, k])) for k in (1, 2, 3))
        return float(x), float(y), float(theta)

    def latest_truth(self) -> tuple[float, float]:
        return self.truth[-1][1:3] if self.truth else (1.5, 1.0)

    def truth_pose(self, stamp_s: float, variance: float, offset_x_m: float = 0.0, frame: str = "map"):
        """An operator's pose at the newest truth, moved offset_x_m along x, with the true heading."""
        x, y = self.latest_truth()
        msg = operator_pose(stamp_s, (x + offset_x_m, y), variance, frame)
        if self.truth_orientation is not None:
            msg.pose.pose.orientation = self.truth_orientation
        return msg

    # service calls, answered or not within CALL_TIMEOUT_S while the probe keeps spinning
    def call(
        self,
        fault: str,
        srv_type: Any,
        service: str,
        request: Any,
        expected: bool | None = None,
        judge: Callable[[Any], tuple[bool, str]] | None = None,
    ) -> None:
        client = self._clients.get(service)
        if client is None:
            client = self._clients[service] = self.node.create_client(srv_type, service)
        record = CallRecord(fault, service, expected_success=expected)
        self.calls.append(record)
        judge = judge or (lambda response: (bool(response.success), str(getattr(response, "message", ""))))
        self.pending.append(
            [record, client, request, self.now_s() + CALL_TIMEOUT_S, self.now_s(), None, judge]
        )

    def poll_calls(self) -> None:
        now_s = self.now_s()
        still = []
        for entry in self.pending:
            record, client, request, deadline_s, sent_s, future, judge = entry
            if future is None and client.service_is_ready():
                entry[5] = future = client.call_async(request)
            if future is not None and future.done():
                record.answered = True
                record.latency_s = now_s - sent_s
                try:
                    record.success, record.detail = judge(future.result())
                except Exception as error:  # a malformed answer is an answer; say what it was
                    record.detail = f"answer not understood: {error!r}"
                continue
            if now_s > deadline_s:
                record.detail = "no answer" if future is not None else "service not available"
                continue
            still.append(entry)
        self.pending = still

    def set_parameter(self, fault: str, node: str, name: str, value: Any, expected: bool | None) -> None:
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])

        def judge(response) -> tuple[bool, str]:
            result = response.results[0]
            return bool(result.successful), f"{name}={value!r}: {result.reason}"

        self.call(fault, SetParameters, f"/{NODE_NAMES[node]}/set_parameters", request, expected, judge)

    def change_state(self, fault: str, transition_id: int, expected: bool) -> None:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        request = ChangeState.Request(transition=Transition(id=transition_id))
        self.call(
            fault,
            ChangeState,
            f"/{NODE_NAMES['driver']}/change_state",
            request,
            expected,
            lambda response: (bool(response.success), f"transition {transition_id}"),
        )


# -- bad messages ---------------------------------------------------------------------------------------
def _revolution(stamp_s: float, bearings: list[tuple[int, float, float]]):
    from beams_common.ros.messages import seconds_to_stamp
    from beams_msgs.msg import BeaconBearing, BeaconBearingArray

    msg = BeaconBearingArray(period=0.1)
    msg.header.stamp, msg.header.frame_id = seconds_to_stamp(stamp_s), "beams_sensor"
    for beacon_id, bearing, variance in bearings:
        item = BeaconBearing(beacon_id=beacon_id, bearing=bearing, variance=variance)
        item.header.stamp = msg.header.stamp
        msg.bearings.append(item)
    return msg


def operator_pose(stamp_s: float, xy: tuple[float, float], variance: float, frame: str = "map"):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    from beams_common.ros.messages import seconds_to_stamp

    msg = PoseWithCovarianceStamped()
    msg.header.stamp, msg.header.frame_id = seconds_to_stamp(stamp_s), frame
    msg.pose.pose.position.x, msg.pose.pose.position.y = xy
    msg.pose.pose.orientation.w = 1.0
    for k in (0, 7, 35):
        msg.pose.covariance[k] = variance
    return msg


def bad_message_topic(variant: str) -> str:
    """The probe's publisher a bad message goes through (bad_message's first element)."""
    if variant.startswith("initialpose"):
        return "initialpose"
    return "odom" if variant == "nan_odometry" else "bearings"


def bad_message(variant: str, probe: Probe) -> tuple[str, Any]:
    """(publisher, message) of one bad message, stamped now."""
    from nav_msgs.msg import Odometry

    from beams_common.ros.messages import seconds_to_stamp

    now_s = probe.now_s()
    if variant == "nan_bearings":
        return "bearings", _revolution(now_s, [(1, math.nan, 1e-6), (2, 0.5, math.nan), (3, 1.0, 1e-6)])
    if variant == "unknown_beacon":
        return "bearings", _revolution(now_s, [(1, 0.1, 1e-6), (2, 1.5, 1e-6), (9, 2.0, 1e-6)])
    if variant == "empty_revolution":
        return "bearings", _revolution(now_s, [])
    if variant == "oversized_revolution":
        return "bearings", _revolution(now_s, [(1, 0.01 * k, 1e-6) for k in range(65)])
    if variant == "nan_odometry":
        msg = Odometry()
        msg.header.stamp, msg.header.frame_id, msg.child_frame_id = (
            seconds_to_stamp(now_s),
            "odom",
            "base_link",
        )
        msg.pose.pose.position.x = msg.pose.pose.orientation.w = math.nan
        return "odom", msg
    if variant == "initialpose_huge_covariance":
        return "initialpose", probe.truth_pose(now_s, OPERATOR_COVARIANCE[variant])
    if variant == "initialpose_nan":
        return "initialpose", operator_pose(now_s, (math.nan, 1.0), 0.01)
    raise ValueError(f"unknown bad message {variant!r}")


# -- the faults as timed actions -------------------------------------------------------------------------
class Campaign:
    """One campaign: processes, probe, timed actions; `run` returns the result."""

    def __init__(self, config: CampaignConfig) -> None:
        self.config = config
        if config.install_base is None:
            config.install_base = pathlib.Path(os.environ.get("BEAMS_INSTALL_BASE", "install")).resolve()
        if config.output_dir is None:
            config.output_dir = pathlib.Path(tempfile.mkdtemp(prefix="fault_campaign_"))
        self.log_dir = pathlib.Path(config.output_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        settings = ScheduleSettings(duration_s=config.duration_s, warmup_s=config.warmup_s)
        self.notes: list[str] = []
        problem = hosts_problem() if config.hosts else ""
        if problem:
            self.notes.append(f"{LINK_CLASS}: skipped here, {problem}")
            print(f"fault_campaign: {self.notes[-1]}", file=sys.stderr, flush=True)
        self.hosts = Hosts(str(os.getpid())) if config.hosts and not problem else None
        self.schedule = (
            config.schedule
            if config.schedule is not None
            else draw_schedule(config.seed, settings, campaign_classes(config.serial, self.hosts is not None))
        )
        self.serial_link = self.log_dir / "beams_sensor"
        self.feed: SerialFeed | None = None
        self.parameters = node_parameters(config, self.serial_link)
        self.env = dict(os.environ)
        self.env.update(
            ROS_DOMAIN_ID=str(config.domain_id),
            # across the hosts' link; the subnet exists only inside the campaign's namespaces
            ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST" if self.hosts is None else "SUBNET",
            PYTHONUNBUFFERED="1",
        )
        self.processes = {
            name: ManagedProcess(
                name,
                [
                    *self._host_prefix(name),
                    *command_of(config, name, self.parameters[name], remaps, self.log_dir),
                ],
                self.log_dir,
            )
            for name, (_, _, remaps) in PROCESSES.items()
        }
        self.calibration_files = write_calibration_files(self.log_dir)
        self.deaths: list[Death] = []
        self.stopping: list[tuple[ManagedProcess, float]] = []  # stopped, not yet exited (SIGINT sent)
        self.actions: list[tuple[float, int, str, Callable[[], None]]] = []
        self.t0_s = math.nan
        self.probe: Probe | None = None

    def _host_prefix(self, name: str) -> list[str]:
        """`ip netns exec` onto the sensor's host for its processes (the others inherit the main host's
        namespace from the campaign's main thread)."""
        if self.hosts is None or name not in SENSOR_HOST_PROCESSES:
            return []
        return self.hosts.exec_prefix("sensor")

    # timing
    def campaign_s(self) -> float:
        return self.probe.now_s() - self.t0_s

    def current_fault(self) -> str:
        now = self.campaign_s()
        for fault in self.schedule:
            if fault.window[0] <= now < fault.window[1]:
                return f"{fault.kind}/{fault.variant}"
        return "no fault"

    def at(self, campaign_s: float, label: str, action: Callable[[], None]) -> None:
        self.actions.append((campaign_s, len(self.actions), label, action))

    def plan(self, fault: Fault) -> None:
        """The fault's actions at their campaign times."""
        label = f"{fault.kind}/{fault.variant}"
        start, end = fault.start_s, fault.end_s
        probe = self.probe
        if fault.kind == "bad_message":
            first_s = start + BAD_PUBLISHER_DISCOVERY_S
            repeats = (
                1
                if fault.variant.startswith("initialpose")
                else max(1, int((end - first_s) / BAD_MESSAGE_PERIOD_S))
            )
            topic = bad_message_topic(fault.variant)
            # the probe's publisher is a second source from the moment it exists: it opens at the fault's
            # start (opened 0.5 s before it, the nodes' ERROR "2 publishers" fell outside the window), the
            # first message once discovery has matched it, closed at the fault's end
            self.at(start, label, lambda: probe.open_publisher(topic))
            for k in range(repeats):
                self.at(first_s + k * BAD_MESSAGE_PERIOD_S, label, lambda: self._publish_bad(fault.variant))
            self.at(end, label, lambda: probe.close_publisher(topic))
        elif fault.kind == "bad_service_call":
            self._plan_service_call(fault, label)
        elif fault.kind == "parameter_change":
            self._plan_parameter_change(fault, label)
        elif fault.kind == "calibration_reload":
            self._plan_calibration_reload(fault, label)
        elif fault.kind == "lifecycle":
            self._plan_lifecycle(fault, label)
        elif fault.kind in RELAY_FAULTS:
            name, value_name = RELAY_FAULTS[fault.kind]
            amount = float(fault.value(value_name))
            self.at(start, label, lambda: probe.set_parameter(label, "relay", name, amount, True))
            self.at(end, label, lambda: probe.set_parameter(label, "relay", name, 0.0, True))
        elif fault.kind == "duplicate_publisher":
            self.at(start, label, lambda: self._start_duplicate(fault))
            self.at(end, label, lambda: self._stop_duplicate(fault))
        elif fault.kind == SERIAL_CLASS:
            self.at(start, label, lambda: self.feed.set_fault(fault.variant))
            self.at(end, label, lambda: self.feed.set_fault(None))
        elif fault.kind == LINK_CLASS:
            self.at(start, label, lambda: self.hosts.set_link(False))
            self.at(end, label, lambda: self.hosts.set_link(True))
        elif fault.kind == "node_kill":
            killed: list[ManagedProcess] = []

            def kill(name: str = fault.variant) -> None:
                killed.append(self.active_process(name))
                killed[-1].signal(signal.SIGKILL)

            self.at(start, label, kill)
            self.at(end, label, lambda: killed and killed.pop().start(self.env))
        else:
            raise ValueError(f"no plan for fault class {fault.kind!r}")

    def _plan_parameter_change(self, fault: Fault, label: str) -> None:
        """A good, out-of-range, wrong-type or read-only change; the parameter's default back at the end."""
        probe, node = self.probe, fault.value("node")
        name, good, out_of_range, read_only = PARAMETER_FAULTS[node]
        default = TABLES[node][name].default
        if fault.variant == "read_only":
            current = TABLES[node][read_only].default
            changed = not current if isinstance(current, bool) else current * 2
            self.at(fault.start_s, label, lambda: probe.set_parameter(label, node, read_only, changed, False))
        else:
            value, expected = {
                "good": (good, True),
                "out_of_range": (out_of_range, False),
                "wrong_type": ("not a number", False),
            }[fault.variant]
            self.at(fault.start_s, label, lambda: probe.set_parameter(label, node, name, value, expected))
        self.at(fault.end_s, label, lambda: probe.set_parameter(label, node, name, default, True))

    def _plan_calibration_reload(self, fault: Fault, label: str) -> None:
        """The file through the parameter (what `ros2 param set` does), then the reload service; the good
        file back at the end."""
        probe, node = self.probe, fault.value("node")
        path = str(self.calibration_files[fault.variant])
        good = str(self.calibration_files["good"])
        self.at(
            fault.start_s, label, lambda: probe.set_parameter(label, node, "calibration_file", path, None)
        )
        self.at(fault.start_s + 0.5, label, lambda: self._reload(label, node, None))
        self.at(fault.end_s, label, lambda: probe.set_parameter(label, node, "calibration_file", good, True))
        self.at(fault.end_s + 0.5, label, lambda: self._reload(label, node, True))

    def _publish_bad(self, variant: str) -> None:
        publisher, message = bad_message(variant, self.probe)
        self.probe.publishers[publisher].publish(message)

    def _reload(self, label: str, node: str, expected: bool | None) -> None:
        from std_srvs.srv import Trigger

        self.probe.call(
            label, Trigger, f"/{NODE_NAMES[node]}/reload_calibration", Trigger.Request(), expected
        )

    def _set_pose(self, label: str, pose, expected: bool) -> None:
        from beams_msgs.srv import SetPose

        self.probe.call(
            label, SetPose, f"/{NODE_NAMES['ekf']}/set_pose", SetPose.Request(pose=pose), expected
        )

    def _plan_service_call(self, fault: Fault, label: str) -> None:
        start, probe = fault.start_s, self.probe
        variant = fault.variant
        # (pose factory, expected success) of the set_pose calls
        set_poses = {
            "set_pose_nan": (lambda: operator_pose(probe.now_s(), (math.nan, 1.0), 0.01), False),
            "set_pose_huge_covariance": (
                lambda: probe.truth_pose(probe.now_s(), OPERATOR_COVARIANCE["set_pose_huge_covariance"]),
                False,
            ),
            "set_pose_wrong_frame": (lambda: probe.truth_pose(probe.now_s(), 0.01, frame="odom"), False),
            # well-formed but wrong: an operator's pose off by WRONG_PLACE_M, claiming a 1 cm precision;
            # taken, then the filter must find it wrong (lost) and come back through ToTal
            "set_pose_wrong_place": (
                lambda: probe.truth_pose(probe.now_s(), WRONG_PLACE_SIGMA_M**2, WRONG_PLACE_M),
                True,
            ),
        }
        if variant in set_poses:
            make_pose, expected = set_poses[variant]
            self.at(start, label, lambda: self._set_pose(label, make_pose(), expected))
        elif variant == "reload_empty_then_set_pose_nan":
            # a reproduction: an ERROR refusal (a reload with an empty calibration_file), then
            # WARN ones (a NaN operator pose, a NaN revolution)
            node = fault.value("node")
            nan_pose = set_poses["set_pose_nan"][0]
            self.at(start, label, lambda: probe.set_parameter(label, node, "calibration_file", "", True))
            self.at(start + 0.3, label, lambda: self._reload(label, node, False))
            self.at(start + 0.6, label, lambda: self._set_pose(label, nan_pose(), False))
            # the probe's bearings publisher exists only while a fault uses it (it is a second source)
            self.at(start, label, lambda: probe.open_publisher("bearings"))
            self.at(start + 0.8, label, lambda: self._publish_bad("nan_bearings"))
            self.at(fault.end_s, label, lambda: probe.close_publisher("bearings"))
        elif variant == "reload_missing_file":
            # the change is refused (the file does not exist); the reload then reads the file in use
            node = fault.value("node")
            missing = str(self.log_dir / "no_such_calibration.yaml")
            self.at(
                start, label, lambda: probe.set_parameter(label, node, "calibration_file", missing, False)
            )
            self.at(start + 0.5, label, lambda: self._reload(label, node, None))
        else:
            raise ValueError(f"unknown service call fault {variant!r}")

    def _plan_lifecycle(self, fault: Fault, label: str) -> None:
        from lifecycle_msgs.msg import Transition

        probe, start, end = self.probe, fault.start_s, fault.end_s
        steps = {
            "deactivate_activate": [
                (start, Transition.TRANSITION_DEACTIVATE, True),
                (end, Transition.TRANSITION_ACTIVATE, True),
            ],
            "cleanup_configure_activate": [
                (start, Transition.TRANSITION_DEACTIVATE, True),
                (start + 0.5, Transition.TRANSITION_CLEANUP, True),
                (end, Transition.TRANSITION_CONFIGURE, True),
                (end + 0.5, Transition.TRANSITION_ACTIVATE, True),
            ],
            # transitions the active state does not offer: refused, answered
            "invalid_transition": [
                (start, Transition.TRANSITION_ACTIVATE, False),
                (end, Transition.TRANSITION_CONFIGURE, False),
            ],
        }[fault.variant]
        for when, transition, expected in steps:
            self.at(when, label, lambda t=transition, e=expected: probe.change_state(label, t, e))

    def active_process(self, name: str) -> ManagedProcess:
        """The process that is the node `name` now: of a hot standby pair, the one holding the node's role
        (beams_common.standby), else the first of the pair still running."""
        process = self.processes[name]
        if name not in HOT_STANDBY:
            return process
        pair = [process, self.processes[HOT_STANDBY[name]]]
        holder_pid = role_holder_pid(process.command, NODE_NAMES[name], self.env)
        holder = [p for p in pair if p.running and holder_pid is not None and p.process.pid == holder_pid]
        return (holder or [p for p in pair if p.running] or pair)[0]

    def _start_duplicate(self, fault: Fault) -> None:
        """A second driver_node, sim_world_node or ekf_node in the namespace, on the topics the real one
        uses."""
        name = f"duplicate_{fault.variant}"
        seed = int(fault.value("seed"))
        parameters = dict(self.parameters[fault.variant])
        # a second driver: the built-in simulated sensor (a second one on the pty is another fault)
        if fault.variant == "driver":
            parameters = {"sim_sensor_seed": seed}
        elif fault.variant == "sim_world":
            parameters.update(trajectory_seed=seed, odometry_seed=seed + 1)
        else:  # a second ekf_node: the same parameters (the same launch twice) but its child frame
            parameters["base_frame"] = DUPLICATE_EKF_FRAME
        command = command_of(self.config, name, parameters, (), self.log_dir)
        self.processes[name] = ManagedProcess(name, command, self.log_dir)
        self.processes[name].start(self.env)

    def _stop_duplicate(self, fault: Fault) -> None:
        """SIGINT to the second node, reaped by `supervise`: waiting here for its exit (0.5 s and more
        under load) stalled the probe, and with it the truth the serial feed draws its revolutions
        from: the EKF followed the stale bearings (0.1-0.2 m "misleading", the harness's fault)."""
        process = self.processes.pop(f"duplicate_{fault.variant}")
        process.signal(signal.SIGINT)
        self.stopping.append((process, time.monotonic() + STOP_TIMEOUT_S))

    # supervision
    def supervise(self) -> None:
        now = self.campaign_s()
        for entry in list(self.stopping):
            process, deadline = entry
            if not process.running:
                self.stopping.remove(entry)
            elif time.monotonic() > deadline:
                process.process.kill()
        for process in list(self.processes.values()):
            if process.respawn_at_s is not None and now >= process.respawn_at_s:
                process.start(self.env)
            elif process.process is not None and not process.running and not process.killed:
                self.deaths.append(
                    Death(
                        process.name,
                        now,
                        process.process.returncode,
                        self.current_fault(),
                        process.log_tail(),
                    )
                )
                process.killed = True  # counted once; the respawn starts a new incarnation
                process.respawn_at_s = now + RESPAWN_DELAY_S

    def run(self) -> CampaignResult:
        if any(fault.kind == LINK_CLASS for fault in self.schedule) and self.hosts is None:
            raise ValueError(f"{LINK_CLASS} faults need hosts=True where namespaces can be made")
        discovery_range = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
        if self.hosts is not None:
            self.hosts.build()
            self.hosts.enter()  # the probe's participant and every process started from here
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
        try:
            return self._run()
        finally:
            if self.hosts is not None:
                self.hosts.leave()
                self.hosts.remove()
                if discovery_range is None:
                    os.environ.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
                else:
                    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = discovery_range

    def _run(self) -> CampaignResult:
        self.probe = probe = Probe(self.config.domain_id)
        if self.config.serial:
            self.feed = SerialFeed(self.serial_link, probe.pose_at, self.config.seed + 2)
        try:
            for process in self.processes.values():
                process.start(self.env)
            deadline = time.monotonic() + START_TIMEOUT_S
            while not probe.ekf:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"no EKF estimate within {START_TIMEOUT_S} s; logs in {self.log_dir}")
                probe.spin(0.05)
            self.t0_s = probe.now_s()
            for fault in self.schedule:
                self.plan(fault)
            self.actions.sort(key=lambda action: action[:2])
            next_rss_s = self.config.warmup_s
            while self.campaign_s() < self.config.duration_s:
                probe.spin(0.01)
                now = self.campaign_s()
                while self.actions and self.actions[0][0] <= now:
                    self.actions.pop(0)[3]()
                probe.poll_calls()
                self.supervise()
                if now >= next_rss_s:
                    for process in self.processes.values():
                        process.sample_rss(now)
                    next_rss_s += RSS_PERIOD_S
            end_s = probe.now_s()
            while probe.pending and probe.now_s() < end_s + CALL_TIMEOUT_S:  # the last calls' answers
                probe.spin(0.05)
                probe.poll_calls()
            self.supervise()
        finally:
            for process in [*self.processes.values(), *(entry[0] for entry in self.stopping)]:
                process.stop()
            if self.feed is not None:
                self.feed.close()
            ekf, truth, status = (
                np.array(rows, dtype=float) for rows in (probe.ekf, probe.truth, probe.status)
            )
            messages = list(probe.status_messages)
            probe.close()
        windows = [(f.kind, self.t0_s + f.window[0], self.t0_s + f.window[1]) for f in self.schedule]
        figures = campaign_figures(
            ekf.reshape(-1, 6),
            truth.reshape(-1, 3),
            status.reshape(-1, 2),
            windows,
            self.t0_s + self.config.warmup_s,
            self.t0_s + self.config.duration_s,
            [(stamp, f"{LEVEL_NAMES.get(level, level)}: {text}") for stamp, level, text in messages],
        )
        np.savez(
            self.log_dir / "series.npz",
            ekf=ekf,
            truth=truth,
            status=status,
            t0_s=self.t0_s,
            status_stamps=np.array([row[0] for row in messages], dtype=float),
            status_levels=np.array([row[1] for row in messages], dtype=int),
            status_messages=np.array([row[2] for row in messages], dtype=str),
        )
        growth = {name: rss_growth_mb(process.rss_samples) for name, process in self.processes.items()}
        if probe.duplicate_estimates:
            self.notes.append(
                f"duplicate_publisher/ekf: {probe.duplicate_estimates} estimates of the second ekf_node "
                "received, not judged (its child frame tells them apart)"
            )
        result = CampaignResult(
            self.schedule, figures, probe.calls, self.deaths, growth, self.log_dir, tuple(self.notes)
        )
        (self.log_dir / "report.txt").write_text(
            "schedule:\n"
            + "\n".join("  " + f.describe() for f in self.schedule)
            + "\n"
            + result.report()
            + "\n"
        )
        return result


def campaign_classes(serial: bool, hosts: bool = False) -> tuple[str, ...]:
    """The fault classes a campaign draws: the serial line's too when the driver reads a serial port, the
    hosts' link's when the robot runs on two hosts."""
    return (*FAULT_CLASSES, *((SERIAL_CLASS,) if serial else ()), *((LINK_CLASS,) if hosts else ()))


def run_campaign(config: CampaignConfig) -> CampaignResult:
    """Play a campaign; on two hosts, in a process of its own: Fast DDS keeps per-process network state,
    and a participant created in this process after one in another namespace stayed deaf (measured:
    a second campaign in one pytest process never saw its EKF)."""
    if config.hosts and not hosts_problem():
        spawn = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=spawn) as pool:
            return pool.submit(_run_here, config).result()
    return _run_here(config)


def _run_here(config: CampaignConfig) -> CampaignResult:
    return Campaign(config).run()


def _override(text: str) -> tuple[str, str, Any]:
    node, _, assignment = text.partition(":")
    name, _, value = assignment.partition(":=")
    if not (node and name and value):
        raise argparse.ArgumentTypeError(f"expected NODE:NAME:=VALUE, got {text!r}")
    return node, name, yaml.safe_load(value)


def main(args: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seed", type=int, default=18)
    parser.add_argument("--duration", type=float, default=120.0, help="campaign length (s) after start-up")
    parser.add_argument(
        "--output", type=pathlib.Path, help="logs and series (default: a temporary directory)"
    )
    parser.add_argument("--domain-id", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "66")))
    parser.add_argument(
        "-p",
        dest="overrides",
        action="append",
        type=_override,
        default=[],
        help="a node's parameter, e.g. ekf:lost_nis_window_bearings:=0",
    )
    parser.add_argument("--schedule-only", action="store_true", help="print the schedule and stop")
    parser.add_argument(
        "--serial", action="store_true", help="driver_node on a simulated serial sensor; its line faults too"
    )
    parser.add_argument(
        "--hosts",
        action="store_true",
        help="the driver on a second host (a network namespace; root and iproute2) and its link's faults",
    )
    options = parser.parse_args(args)
    overrides: dict[str, dict[str, Any]] = {}
    for node, name, value in options.overrides:
        overrides.setdefault(node, {})[name] = value
    config = CampaignConfig(
        seed=options.seed,
        duration_s=options.duration,
        output_dir=options.output,
        domain_id=options.domain_id,
        overrides=overrides,
        serial=options.serial,
        hosts=options.hosts,
    )
    if options.schedule_only:
        settings = ScheduleSettings(duration_s=config.duration_s, warmup_s=config.warmup_s)
        hosts = config.hosts and not hosts_problem()
        schedule = draw_schedule(config.seed, settings, campaign_classes(config.serial, hosts))
        print("\n".join(fault.describe() for fault in schedule))
        return 0
    result = run_campaign(config)
    print("schedule:\n" + "\n".join("  " + fault.describe() for fault in result.schedule))
    print(result.report())
    return 0


if __name__ == "__main__":
    sys.exit(main())
