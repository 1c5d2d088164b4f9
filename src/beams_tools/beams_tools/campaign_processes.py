"""The fault campaign's processes: the robot's (beams_tools.robot_processes: its nodes, its hot standby
pairs) and the relay, each with the campaign's parameters and remaps, run by the demo's supervisor
(beams_tools.supervisor: a death respawned after RESPAWN_DELAY_S, as the launch file's respawn would);
killed and restarted by the faults, duplicated. A process is named as its node without `_node` (`ekf`,
the schedule's name), a hot standby's second as the description names it (`ekf_standby`). Their ROS_HOME
(ekf_node's checkpoint) is in the campaign's log directory, so that no run resumes from another's."""

import pathlib
from collections.abc import Callable, Mapping
from typing import Any

import yaml

from beams_tools.campaign_metrics import Death, rss_growth_mb
from beams_tools.robot_processes import ROBOT_NODES, RobotNode, process_commands
from beams_tools.supervisor import NodeSupervisor, SupervisedNode

# a process's RSS counts from this long (s) after its start: its imports and first allocations are not growth
RSS_SETTLE_S = 10.0
# the robot's nodes, the relay between the publishers and the filters, and the calibration node (an
# operator's captures), by the campaign's name
CAMPAIGN_NODES = (
    RobotNode("beams_tools", "fault_relay_node"),
    RobotNode("beams_calibration", "calibration_node"),
)
NODES = {node.name: node for node in (*ROBOT_NODES, *CAMPAIGN_NODES)}
# sim_world's odometry and truth and the driver's bearings go to raw topics; the relay republishes them
REMAPS = {
    "sim_world": ("odom:=odom_raw", "beams/sim/ground_truth:=beams/sim/ground_truth_raw"),
    "driver": ("beams/bearings:=beams/bearings_raw",),
}


class CampaignProcesses(NodeSupervisor):
    """The campaign's processes; one that exits without being killed is counted dead (`deaths`, with
    `fault()`: the fault under way) and respawned."""

    def __init__(
        self,
        install_base: pathlib.Path,
        log_dir: pathlib.Path,
        env: Mapping[str, str],
        parameters: Mapping[str, dict[str, Any]],
        host_prefix: Callable[[str], list[str]],
        campaign_s: Callable[[], float],
        fault: Callable[[], str],
    ) -> None:
        self.install_base, self.log_dir, self.parameters = install_base, log_dir, parameters
        ros_arguments = {
            node.executable: self.ros_arguments(name, parameters[name]) for name, node in NODES.items()
        }
        commands = process_commands(install_base, ros_arguments, tuple(NODES.values()))
        self.deaths: list[Death] = []

        def on_exit(process: SupervisedNode, status: int) -> None:
            self.deaths.append(Death(process.name, campaign_s(), status, fault(), process.log_tail()))

        super().__init__(
            {
                name.removesuffix("_node"): [*host_prefix(name.removesuffix("_node")), *command]
                for name, command in commands.items()
            },
            {**env, "ROS_HOME": str(log_dir / "ros_home")},
            log_dir,
            on_exit=on_exit,
        )

    def ros_arguments(self, name: str, parameters: dict[str, Any]) -> list[str]:
        """A node's parameters, in a file of its own, and its remaps."""
        arguments = [part for remap in REMAPS.get(name, ()) for part in ("-r", remap)]
        if not parameters:
            return arguments
        params_file = self.log_dir / f"{name}.params.yaml"
        params_file.write_text(yaml.safe_dump({"/**": {"ros__parameters": parameters}}))
        return ["--params-file", str(params_file), *arguments]

    def active_of(self, name: str) -> str:
        """The process that is the node `name` now: of a hot standby pair, the one holding the node's role
        (beams_common.ros.standby), else the first of the pair still running."""
        node = NODES[name]
        pair = [process for process in (name, node.standby_argument) if process in self.nodes]
        running = [process for process in pair if self.pid(process) is not None]
        return self.active(node.executable, pair) or (running or pair)[0]

    def duplicate(self, name: str, parameters: dict[str, Any]) -> None:
        """A second process of the node `name` (no --standby: it does not wait for the role)."""
        process = f"duplicate_{name}"
        arguments = self.ros_arguments(process, parameters)
        self.add(process, [NODES[name].installed(self.install_base), "--ros-args", *arguments])

    def sample_rss(self, now_s: float) -> None:
        """Each process's resident memory (VmRSS), from RSS_SETTLE_S after its current process started."""
        for name, node in self.nodes.items():
            pid = self.pid(name)
            if pid is None or self.clock() - node.started_s < RSS_SETTLE_S:
                continue
            try:
                status = pathlib.Path(f"/proc/{pid}/status").read_text()
            except OSError:
                continue
            rss = [int(line.split()[1]) / 1024.0 for line in status.splitlines() if line.startswith("VmRSS:")]
            node.rss_samples += [(now_s, value) for value in rss]

    def rss_growth_mb(self) -> dict[str, float]:
        """Each process's RSS growth over its current process's samples."""
        return {name: rss_growth_mb(node.rss_samples) for name, node in self.nodes.items()}
