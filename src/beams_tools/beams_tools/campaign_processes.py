"""The fault campaign's processes: the robot's (beams_tools.robot_processes: its nodes, its hot standby
pairs, its respawn delay) and the relay, each with the campaign's parameters and remaps; started, killed
and restarted by the faults, duplicated, respawned after a death as the launch file's respawn would."""

import pathlib
import signal
import subprocess
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import yaml

from beams_common.standby import role_holder_pid
from beams_tools.campaign_metrics import Death, rss_growth_mb
from beams_tools.robot_processes import RESPAWN_DELAY_S, ROBOT_NODES, RobotNode

STOP_TIMEOUT_S = 15.0
# a process's RSS counts from this long (s) after its start: its imports and first allocations are not growth
RSS_SETTLE_S = 10.0
# the campaign's name of each node (its schedule's and its overrides'), the relay between the publishers
# and the filters too
NODES = {**{node.name: node for node in ROBOT_NODES}, "relay": RobotNode("beams_tools", "fault_relay_node")}
# sim_world's odometry and truth and the driver's bearings go to raw topics; the relay republishes them
REMAPS = {
    "sim_world": ("odom:=odom_raw", "beams/sim/ground_truth:=beams/sim/ground_truth_raw"),
    "driver": ("beams/bearings:=beams/bearings_raw",),
}


def campaign_processes() -> dict[str, tuple[str, RobotNode, list[str]]]:
    """Each process the campaign starts, by name: its node's campaign name, the node, its arguments
    before --ros-args. A node's first process is named as the node (`ekf`), a hot standby's second as
    the description names it (`ekf_standby`)."""
    return {
        (name if process == node.executable else process): (name, node, arguments)
        for name, node in NODES.items()
        for process, arguments in node.processes().items()
    }


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


class CampaignProcesses:
    """The campaign's processes by name; `supervise` (called from the campaign's loop) counts a process
    that exits without being killed as dead and respawns it RESPAWN_DELAY_S later."""

    def __init__(
        self,
        install_base: pathlib.Path,
        log_dir: pathlib.Path,
        env: Mapping[str, str],
        parameters: Mapping[str, dict[str, Any]],
        host_prefix: Callable[[str], list[str]],
    ) -> None:
        self.install_base, self.log_dir, self.env = install_base, log_dir, dict(env)
        self.parameters = parameters
        self.processes = {
            process: ManagedProcess(
                process,
                [
                    *host_prefix(name),
                    *self.command(process, node, arguments, parameters[name], REMAPS.get(name, ())),
                ],
                log_dir,
            )
            for process, (name, node, arguments) in campaign_processes().items()
        }
        self.deaths: list[Death] = []
        self.stopping: list[tuple[ManagedProcess, float]] = []  # stopped, not yet exited (SIGINT sent)

    def command(
        self,
        process: str,
        node: RobotNode,
        arguments: list[str],
        parameters: dict[str, Any],
        remaps: tuple[str, ...] = (),
    ) -> list[str]:
        command = [node.installed(self.install_base), *arguments, "--ros-args"]
        if parameters:
            params_file = self.log_dir / f"{process}.params.yaml"
            params_file.write_text(yaml.safe_dump({"/**": {"ros__parameters": parameters}}))
            command += ["--params-file", str(params_file)]
        for remap in remaps:
            command += ["-r", remap]
        return command

    def start(self) -> None:
        for process in self.processes.values():
            process.start(self.env)

    def active(self, name: str) -> ManagedProcess:
        """The process that is the node `name` now: of a hot standby pair, the one holding the node's role
        (beams_common.standby), else the first of the pair still running."""
        process = self.processes[name]
        node = NODES[name]
        if not node.hot_standby:
            return process
        pair = [process, self.processes[node.standby_argument]]
        holder_pid = role_holder_pid(process.command, node.executable, self.env)
        holder = [p for p in pair if p.running and holder_pid is not None and p.process.pid == holder_pid]
        return (holder or [p for p in pair if p.running] or pair)[0]

    def start_duplicate(self, name: str, parameters: dict[str, Any]) -> None:
        """A second process of the node `name` (no --standby: it does not wait for the role)."""
        process = f"duplicate_{name}"
        command = self.command(process, NODES[name], [], parameters)
        self.processes[process] = ManagedProcess(process, command, self.log_dir)
        self.processes[process].start(self.env)

    def stop_duplicate(self, name: str) -> None:
        """SIGINT to the second node, reaped by `supervise`: waiting here for its exit (0.5 s and more
        under load) stalled the probe, and with it the truth the serial feed draws its revolutions
        from: the EKF followed the stale bearings (0.1-0.2 m "misleading", the harness's fault)."""
        process = self.processes.pop(f"duplicate_{name}")
        process.signal(signal.SIGINT)
        self.stopping.append((process, time.monotonic() + STOP_TIMEOUT_S))

    def supervise(self, now_s: float, fault: Callable[[], str]) -> None:
        """Reap the stopped duplicates, respawn the dead whose delay has passed, count the new dead
        (`fault`: the fault under way)."""
        for entry in list(self.stopping):
            process, deadline = entry
            if not process.running:
                self.stopping.remove(entry)
            elif time.monotonic() > deadline:
                process.process.kill()
        for process in list(self.processes.values()):
            if process.respawn_at_s is not None and now_s >= process.respawn_at_s:
                process.start(self.env)
            elif process.process is not None and not process.running and not process.killed:
                status = process.process.returncode
                self.deaths.append(Death(process.name, now_s, status, fault(), process.log_tail()))
                process.killed = True  # counted once; the respawn starts a new incarnation
                process.respawn_at_s = now_s + RESPAWN_DELAY_S

    def sample_rss(self, now_s: float) -> None:
        for process in self.processes.values():
            process.sample_rss(now_s)

    def rss_growth_mb(self) -> dict[str, float]:
        return {name: rss_growth_mb(process.rss_samples) for name, process in self.processes.items()}

    def stop(self) -> None:
        for process in [*self.processes.values(), *(entry[0] for entry in self.stopping)]:
            process.stop()
