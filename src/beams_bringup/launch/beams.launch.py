"""The BeAMS suite for robots with ROS 2 Jazzy from apt (`make demo` runs the same executables without it).

Simulated robot and sensor (the embedded default):
    ros2 launch beams_bringup beams.launch.py namespace:=robot1
A real robot (the serial sensor; the robot publishes its wheel odometry on `odom`):
    ros2 launch beams_bringup beams.launch.py source:=serial device:=/dev/ttyUSB0 \
        calibration_file:=/home/robot/beams_calibration.yaml
The turret's firmware in simavr (`make hil`) on a pty linked at `device`, following the simulated robot:
    ros2 launch beams_bringup beams.launch.py source:=serial device:=/tmp/beams_turret virtual_turret:=true
Leave the driver (a lifecycle node) to a lifecycle manager: it then waits unconfigured for
`ros2 lifecycle set /<namespace>/driver_node configure` (then `activate`) or a manager's calls:
    ros2 launch beams_bringup beams.launch.py driver_autostart:=false
Each node reads its section of beams_bringup's config/beams_params.yaml; the calibration file, when given,
overrides the beacon coordinates and carries the turret offset and the bearing corrections. The nodes run
with the package's Fast DDS profile (config/fastdds_fast_discovery.xml: a node restarted after a kill -9
is back within 0.5 s) unless FASTRTPS_DEFAULT_PROFILES_FILE is already set.
A node that dies is started again RESPAWN_DELAY_S (0.25 s) later (respawn), the driver too: with
driver_autostart:=false it comes back unconfigured, which is what a lifecycle manager that reconnects
to respawned nodes (nav2's attempt_respawn_reconnection) expects; a dead driver would need one anyway.
ekf_node runs as a pair (hot standby, beams_common.ros.standby): both processes start with --standby, one
takes the node's role and runs, the other waits outside the ROS graph and becomes the EKF at once when
the first dies, which is respawned into the waiting place; the process that becomes the EKF resumes what
the last one learnt from its checkpoint (beams_ekf.checkpoint, ~/.ros/beams/). One ekf_node only:
    ros2 launch beams_bringup beams.launch.py ekf_standby:=false
driver_node, triangulation_node and ekf_node as nodes of one process (beams_bringup's `robot`, one
executor, as a C++ component container; respawned as a whole, without a standby; sim_world_node stays a
process of its own):
    ros2 launch beams_bringup beams.launch.py one_process:=true
"""

from launch import Condition, LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import (
    AndSubstitution,
    EnvironmentVariable,
    EqualsSubstitution,
    LaunchConfiguration,
    NotSubstitution,
    PathJoinSubstitution,
)
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from beams_tools.robot_processes import (
    DISCOVERY_PROFILE,
    ONE_PROCESS,
    ONE_PROCESS_NODES,
    PARAMS_FILE,
    RESPAWN_DELAY_S,
    ROBOT_NODES,
    RobotNode,
)

ARGUMENTS = (
    ("namespace", "", "namespace of this robot's nodes"),
    ("source", "sim", "sim (simulated robot and sensor) or serial (the real sensor)"),
    ("device", "/dev/ttyUSB0", "serial device of the sensor (source:=serial)"),
    ("calibration_file", "", "calibration file written by beams_calibration"),
    ("use_sim_time", "false", "follow /clock (rosbag replay)"),
    ("virtual_turret", "false", "true: the simulated robot, the turret's firmware in simavr on `device`"),
    (
        "driver_autostart",
        "true",
        "true: driver_node configures and activates itself; false: it waits unconfigured for a lifecycle "
        "manager (ros2 lifecycle set)",
    ),
    *(
        (
            node.standby_argument,
            "true",
            f"true: {node.executable} runs as a pair, the second process a hot standby that takes over at "
            "once when the first dies; false: one process, restarted after a death",
        )
        for node in ROBOT_NODES
        if node.hot_standby
    ),
    ("one_process", "false", "true: driver_node, triangulation_node and ekf_node as nodes of one process"),
)


def node_action(
    node: RobotNode, arguments: list[str] | None = None, condition: Condition | None = None
) -> Node:
    """One process of a node (or ONE_PROCESS): `arguments` before --ros-args, `condition` when it runs
    (the simulated robot's is that the source is sim)."""
    parameters = [
        PathJoinSubstitution([FindPackageShare("beams_bringup"), "config", PARAMS_FILE]),
        {"use_sim_time": LaunchConfiguration("use_sim_time")},
    ]
    if node.takes_calibration:
        parameters.append({"calibration_file": LaunchConfiguration("calibration_file")})
    if node.executable in ("driver_node", ONE_PROCESS.executable):
        parameters.append(
            {
                "source": LaunchConfiguration("source"),
                "device": LaunchConfiguration("device"),
                "autostart": LaunchConfiguration("driver_autostart"),
            }
        )
    if node.simulation_only:
        # (IfCondition(EqualsSubstitution): LaunchConfigurationEquals is deprecated since Jazzy.)
        condition = IfCondition(EqualsSubstitution(LaunchConfiguration("source"), "sim"))
    return Node(
        package=node.package,
        executable=node.executable,
        arguments=arguments or [],
        namespace=LaunchConfiguration("namespace"),
        parameters=parameters,
        output="screen",
        # whatever kills a node (a fault past its callback guard, the OOM killer, kill -9)
        respawn=True,
        respawn_delay=RESPAWN_DELAY_S,
        condition=condition,
    )


def virtual_turret() -> Node:
    """virtual_turret:=true: sim_world_node's match and the turret firmware in simavr following it
    (docs/firmware.md), its pty linked at `device`."""
    return Node(
        package="beams_sim",
        executable="virtual_turret",
        arguments=["--link", LaunchConfiguration("device")],
        namespace=LaunchConfiguration("namespace"),
        parameters=[PathJoinSubstitution([FindPackageShare("beams_bringup"), "config", PARAMS_FILE])],
        output="screen",
        condition=IfCondition(LaunchConfiguration("virtual_turret")),
    )


def node_actions(node: RobotNode) -> list[Node]:
    """A node's processes: with a hot standby, the pair when its launch argument is true, else one; the
    nodes of ONE_PROCESS only without one_process, ONE_PROCESS only with it."""
    one_process = LaunchConfiguration("one_process")
    separate = NotSubstitution(one_process)
    if node == ONE_PROCESS:
        return [node_action(node, condition=IfCondition(one_process))]
    if not node.hot_standby:
        return [node_action(node, condition=IfCondition(separate) if node in ONE_PROCESS_NODES else None)]
    if node.simulation_only:
        raise ValueError(
            f"{node.executable}: a simulation-only node with a hot standby needs both conditions"
        )
    standby = LaunchConfiguration(node.standby_argument)
    pair = IfCondition(AndSubstitution(standby, separate))
    alone = IfCondition(AndSubstitution(NotSubstitution(standby), separate))
    return [
        *(node_action(node, arguments, pair) for arguments in node.processes().values()),
        node_action(node, condition=alone),
    ]


def discovery_profile() -> SetEnvironmentVariable:
    """The package's Fast DDS profile for the nodes, unless the robot already exports its own."""
    profile = PathJoinSubstitution([FindPackageShare("beams_bringup"), "config", DISCOVERY_PROFILE])
    return SetEnvironmentVariable(
        "FASTRTPS_DEFAULT_PROFILES_FILE",
        EnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE", default_value=profile),
    )


def generate_launch_description() -> LaunchDescription:
    arguments = [
        DeclareLaunchArgument(name, default_value=value, description=text) for name, value, text in ARGUMENTS
    ]
    nodes = [action for node in (*ROBOT_NODES, ONE_PROCESS) for action in node_actions(node)]
    return LaunchDescription([*arguments, discovery_profile(), *nodes, virtual_turret()])
