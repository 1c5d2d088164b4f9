"""The robot's process set, described once: which nodes (package, executable), which run only with the
simulated sensor, which read the calibration file, which run as a hot standby pair, which run in one process
with `one_process`, the respawn delay, the parameter file and the Fast DDS profile. beams_bringup's launch
file and the demo's supervisor, and the fault campaign, build their processes from it
(test/unit/test_process_set.py)."""

import pathlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from beams_common.ros.standby import STANDBY_FLAG

# beams_bringup's share/config files (the installed parameter file: replay_settings.installed_params_file)
PARAMS_FILE = "beams_params.yaml"
DISCOVERY_PROFILE = "fastdds_fast_discovery.xml"
# A node that dies is started again this long after (s): `ros2 launch` (respawn_delay), the demo's
# supervisor and the fault campaign alike. Why so short: docs/integrity.md ("A node that dies anyway").
RESPAWN_DELAY_S = 0.25


@dataclass(frozen=True)
class RobotNode:
    """One node of a robot's BeAMS suite."""

    package: str
    executable: str
    # the simulated robot only runs with the simulated sensor
    simulation_only: bool = False
    # reads the calibration file (the driver's corrections, the geometry of the filters)
    takes_calibration: bool = True
    # runs as a pair, one process a hot standby (beams_common.ros.standby): the node's own start-up is too
    # long for the 2 s goal under load, a waiting standby's takeover is not
    hot_standby: bool = False

    @property
    def name(self) -> str:
        """The node's short name (the fault campaign's, its schedule's): `ekf` for ekf_node."""
        return self.executable.removesuffix("_node")

    @property
    def standby_argument(self) -> str:
        """The launch argument that turns its standby off (`ekf_standby:=false`), also the name of the
        pair's second process."""
        return f"{self.name}_standby"

    def processes(self, standby: bool = True) -> dict[str, list[str]]:
        """Its processes: a name for each (the supervisor's, its log's) and its arguments before --ros-args.
        With its hot standby, two, both with --standby: the first to start finds the role free and takes
        it at once, and whichever dies is respawned into a role held by the other, so it waits."""
        if not (self.hot_standby and standby):
            return {self.executable: []}
        return {self.executable: [STANDBY_FLAG], self.standby_argument: [STANDBY_FLAG]}

    def installed(self, install_base: pathlib.Path) -> str:
        """Its installed executable (what `ros2 run` starts)."""
        path = install_base / self.package / "lib" / self.package / self.executable
        if not path.exists():
            raise FileNotFoundError(f"{path} is not installed: run `make build`")
        return str(path)


ROBOT_NODES = (
    RobotNode("beams_sim", "sim_world_node", simulation_only=True, takes_calibration=False),
    RobotNode("beams_driver", "driver_node"),
    RobotNode("beams_triangulation", "triangulation_node"),
    # filterpy's imports (scipy.stats) make the EKF's start-up 1.6 s of CPU: respawned, it was back
    # 2.2-2.7 s after a kill under a load of 4-6; its standby takes over in 0.41-0.50 s (BENCHMARKS.md)
    RobotNode("beams_ekf", "ekf_node", hot_standby=True),
)


# `one_process`: the robot's nodes but the simulated robot as nodes of one process on one executor
# (beams_bringup.robot), as a C++ component container runs components; respawned as a whole, no standby
ONE_PROCESS = RobotNode("beams_bringup", "robot")
ONE_PROCESS_NODES = tuple(node for node in ROBOT_NODES if not node.simulation_only)


def robot_processes(one_process: bool = False) -> tuple[RobotNode, ...]:
    """The robot's processes: a node each, or with `one_process` the simulated robot and ONE_PROCESS."""
    if not one_process:
        return ROBOT_NODES
    return (*(node for node in ROBOT_NODES if node.simulation_only), ONE_PROCESS)


def process_commands(
    base: pathlib.Path,
    ros_arguments: Mapping[str, Sequence[str]],
    nodes: Sequence[RobotNode] = ROBOT_NODES,
    standby: bool = True,
) -> dict[str, list[str]]:
    """The command of each process of `nodes` by process name (RobotNode.processes): the executable
    installed under `base`, its arguments, then --ros-args and `ros_arguments` of its node (by executable)."""
    return {
        name: [node.installed(base), *arguments, "--ros-args", *ros_arguments.get(node.executable, ())]
        for node in nodes
        for name, arguments in node.processes(standby).items()
    }
