"""sim_world_node's parameters: one spec each. All read-only: they define the simulated match, which a
change in the middle of it would make a different one (restart the node instead). The simulated world's
classes (`world.MotionLimits`, `OdometryDrift`, `OdometrySimulator`, `EurobotTrajectory`) take their
defaults and ranges from here."""

from collections.abc import Mapping
from typing import Any

from beams_common.config.parameters import ParameterSpec, ParameterTable

TRAJECTORY_KINDS = ("random", "waypoints", "static")
# OdometryDrift's fields (a small robot, roughly calibrated): default, description, minimum
ODOMETRY_DRIFT = {
    "left_scale_error": (0.01, "Left wheel: reported / travelled distance - 1.", -0.49),
    "right_scale_error": (0.011, "Right wheel: reported / travelled distance - 1.", -0.49),
    "wheel_base_error": (0.01, "Nominal / true wheel base - 1.", -0.49),
    "slip_std": (0.005, "Per-sample wheel slip, fraction of the wheel's travel (half-normal sigma).", 0.0),
    "noise_m_per_sqrt_m": (0.001, "Random-walk noise of each wheel's distance (m per sqrt(m)).", 0.0),
}


def _dropout_check(values: Mapping[str, Any]) -> str | None:
    start_s, end_s = values["odometry_dropout_s"]
    if not start_s <= end_s:
        return f"odometry_dropout_s must be [start_s, end_s] with start_s <= end_s, got {[start_s, end_s]}"
    return None


def _waypoints_check(values: Mapping[str, Any]) -> str | None:
    if len(values["waypoints_x"]) != len(values["waypoints_y"]):
        return (
            f"waypoints_x has {len(values['waypoints_x'])} values, waypoints_y {len(values['waypoints_y'])}"
        )
    return None


SIM_WORLD_PARAMETERS = ParameterTable(
    "sim_world_node",
    (
        ParameterSpec("map_frame", "map", "Frame of the table (ground truth)."),
        ParameterSpec("odom_frame", "odom", "Frame of the odometry."),
        ParameterSpec("base_frame", "base_link", "Frame of the robot."),
        ParameterSpec("rate_hz", 50.0, "Publication rate (Hz).", minimum=1.0, maximum=1000.0),
        ParameterSpec("publish_tf", True, "Publish the odometry as odom -> base_link on /tf."),
        ParameterSpec("trajectory", "random", "Robot motion.", choices=TRAJECTORY_KINDS),
        ParameterSpec(
            "duration_s",
            90.0,
            "Length of the match (s); the robot then stands still.",
            minimum=1.0,
            maximum=600.0,
        ),
        ParameterSpec("trajectory_seed", 0, "Seed of the random trajectory.", minimum=0, maximum=2**31),
        ParameterSpec(
            "start_pose",
            [0.4, 1.0, 0.0],
            "Start pose [x, y, theta] (m, m, rad) of the random trajectory.",
            minimum=-100.0,
            maximum=100.0,
            length=3,
        ),
        ParameterSpec(
            "static_pose",
            [1.5, 1.0, 0.0],
            "Pose [x, y, theta] of the static trajectory.",
            minimum=-100.0,
            maximum=100.0,
            length=3,
        ),
        ParameterSpec(
            "waypoints_x",
            [0.4, 1.2, 2.2, 2.4, 1.5, 0.6],
            "x of the B-spline control points (m).",
            minimum=-100.0,
            maximum=100.0,
            length=(2, 1000),
        ),
        ParameterSpec(
            "waypoints_y",
            [1.0, 1.0, 0.6, 1.4, 1.6, 0.7],
            "y of the B-spline control points (m).",
            minimum=-100.0,
            maximum=100.0,
            length=(2, 1000),
        ),
        ParameterSpec("max_speed_mps", 0.5, "Top speed (m/s).", minimum=0.01, maximum=5.0),
        ParameterSpec("max_yaw_rate_radps", 2.0, "Top yaw rate (rad/s).", minimum=0.01, maximum=20.0),
        ParameterSpec(
            "robot_radius_m", 0.15, "Robot footprint radius kept on the table (m).", minimum=0.0, maximum=0.9
        ),
        *(
            ParameterSpec(f"odometry_{name}", default, description, minimum=low, maximum=0.49)
            for name, (default, description, low) in ODOMETRY_DRIFT.items()
        ),
        ParameterSpec("odometry_seed", 2, "Seed of the odometry's slip and noise.", minimum=0, maximum=2**31),
        ParameterSpec("wheel_base_m", 0.3, "Nominal wheel base of the robot (m).", minimum=0.05, maximum=2.0),
        ParameterSpec(
            "odometry_dropout_s",
            [0.0, 0.0],
            "Match time window [start_s, end_s) with no odometry published (the encoders still count).",
            minimum=0.0,
            maximum=1e6,
            length=2,
        ),
    ),
    (_dropout_check, _waypoints_check),
)
