"""The robot's nodes and where their parameters live: one list for the launch file and the demo (the
installed parameter file is found by beams_tools.replay_settings.installed_params_file)."""

from dataclasses import dataclass

PARAMS_FILE = "beams_params.yaml"
DISCOVERY_PROFILE = "fastdds_fast_discovery.xml"
# A node that dies is started again this long after (s): `ros2 launch` (respawn_delay), the demo's
# supervisor and the fault campaign alike. Issue 18 wants the EKF back within 2 s of any kill, and a
# Python node's own start-up already takes 0.5-1.6 s of it (imports, DDS discovery; the EKF's
# is the longest), so the delay must be short. What bounds a respawn storm (a node that dies at every
# start) is that start-up, not the delay: a start costs at least 0.5 s of CPU, so a crash loop restarts
# at most 1 / (0.25 + 0.5) = 1.3 times a second, and the participants it leaves in the DDS graph (each
# until its 5-s lease ends, fastdds_fast_discovery.xml) number at most 5 / 0.75, about 7. A longer delay
# would only move that bound a little (1 s: 0.7 starts/s, 3 participants) and cost the EKF its 2 s.
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


ROBOT_NODES = (
    RobotNode("beams_sim", "sim_world_node", simulation_only=True, takes_calibration=False),
    RobotNode("beams_driver", "driver_node"),
    RobotNode("beams_triangulation", "triangulation_node"),
    RobotNode("beams_ekf", "ekf_node"),
)
