"""The robot's nodes and where their parameters live: one list for the launch file and the demo (the
installed parameter file is found by beams_tools.replay_settings.installed_params_file)."""

from dataclasses import dataclass

PARAMS_FILE = "beams_params.yaml"
DISCOVERY_PROFILE = "fastdds_fast_discovery.xml"
# A node that dies is started again this long after (s): `ros2 launch` (respawn_delay) and the demo's
# supervisor alike. Short, so the EKF is back within about 2 s of a kill; long enough that a node dying
# at once at every start does not spin the CPU.
RESPAWN_DELAY_S = 1.0


@dataclass(frozen=True)
class RobotNode:
    """One node of a robot's BeAMS suite."""

    package: str
    executable: str
    # the simulated robot only runs with the simulated sensor
    simulation_only: bool = False
    # reads the calibration file (the driver's corrections, the geometry of the filters)
    takes_calibration: bool = True


ROBOT_NODES = (
    RobotNode("beams_sim", "sim_world_node", simulation_only=True, takes_calibration=False),
    RobotNode("beams_driver", "driver_node"),
    RobotNode("beams_triangulation", "triangulation_node"),
    RobotNode("beams_ekf", "ekf_node"),
)
