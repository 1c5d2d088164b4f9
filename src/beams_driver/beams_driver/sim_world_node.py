"""sim_world_node: the simulated robot on the Eurobot table, its true pose and its drifting wheel odometry.

Publishes at `rate_hz` (50 Hz by default), both nav_msgs/Odometry:
- `beams/sim/ground_truth`: the true pose (map -> base_link) and twist of an `EurobotTrajectory`;
- `odom`: what the wheel encoders give (`OdometrySimulator`): pose in the odom frame (its origin is
  the robot's start pose) and measured twist in base_link, with scale, wheel-base, slip and noise errors;
  with `publish_tf`, the same pose as odom -> base_link on `/tf`, as a robot's base controller does.

The match clock starts with the node's first tick on the node's clock (use_sim_time follows /clock);
after `duration_s` the robot stands still. When the clock jumps backwards (a bag or a simulation
restarted) the match starts over. Both topics are RELIABLE (depth 10), so every subscriber matches,
best-effort (sensor-data) ones included.
"""

import math
import sys

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.time import Time
from tf2_msgs.msg import TFMessage

from beams_driver.node_support import (
    TF_QOS,
    Diagnostics,
    ParameterValidationError,
    declare_choice,
    declare_parameter,
    run_node,
)
from beams_driver.ros_messages import planar_tf_message, ros_covariance, set_pose2d
from beams_driver.sim_world import EurobotTrajectory, MotionLimits, OdometryDrift, OdometrySimulator, Pose2D

TRAJECTORY_KINDS = ("random", "waypoints", "static")
QUEUE_DEPTH = 10
# Rough 1-sigma growth of odometry errors, for the covariance fields only (the EKF has its own model).
POSITION_SIGMA_PER_M = 0.01
HEADING_SIGMA_PER_RAD = 0.01


class SimWorldNode(Node):
    def __init__(self) -> None:
        super().__init__("sim_world_node")
        self.diagnostics = Diagnostics(self, "sim_world")
        self.map_frame = declare_parameter(self, "map_frame", "map", "Frame of the table (ground truth).")
        self.odom_frame = declare_parameter(self, "odom_frame", "odom", "Frame of the odometry.")
        self.base_frame = declare_parameter(self, "base_frame", "base_link", "Frame of the robot.")
        rate_hz = declare_parameter(
            self, "rate_hz", 50.0, "Publication rate (Hz).", minimum=1.0, maximum=1000.0
        )
        self.trajectory = self._declare_trajectory()
        self.drift = self._declare_drift()
        self.odometry_seed = declare_parameter(
            self, "odometry_seed", 2, "Seed of the odometry's slip and noise.", minimum=0, maximum=2**31
        )
        self.wheel_base_m = declare_parameter(
            self, "wheel_base_m", 0.3, "Nominal wheel base of the robot (m).", minimum=0.05, maximum=2.0
        )
        self.odometry_dropout_s = declare_parameter(
            self,
            "odometry_dropout_s",
            [0.0, 0.0],
            "Match time window [start_s, end_s) with no odometry published (the encoders still count).",
        )
        dropout = self.odometry_dropout_s
        if len(dropout) != 2 or not dropout[0] <= dropout[1]:
            raise ParameterValidationError(
                f"odometry_dropout_s must be [start_s, end_s] with start_s <= end_s, got {dropout}"
            )
        self.truth_publisher = self.create_publisher(Odometry, "beams/sim/ground_truth", QUEUE_DEPTH)
        self.odom_publisher = self.create_publisher(Odometry, "odom", QUEUE_DEPTH)
        publish_tf = declare_parameter(self, "publish_tf", True,
                                       "Publish the odometry as odom -> base_link on /tf.")
        self.tf_publisher = self.create_publisher(TFMessage, "/tf", TF_QOS) if publish_tf else None
        self.start_s: float | None = None
        self.last_s = -math.inf
        self.finished = False
        self.odometry = self._new_odometry()
        self.create_timer(1.0 / rate_hz, self._tick)
        self.get_logger().info(
            f"{self.trajectory.duration_s:.0f} s trajectory starting at {self.trajectory.pose_at(0.0)}, "
            f"publishing {self.resolve_topic_name('beams/sim/ground_truth')} and "
            f"{self.resolve_topic_name('odom')} at {rate_hz} Hz"
        )

    # ---- parameters ----

    def _declare_trajectory(self) -> EurobotTrajectory:
        kind = declare_choice(self, "trajectory", "random", TRAJECTORY_KINDS, "Robot motion.")
        duration_s = declare_parameter(
            self,
            "duration_s",
            90.0,
            "Length of the match (s); the robot then stands still.",
            minimum=1.0,
            maximum=600.0,
        )
        seed = declare_parameter(self, "seed", 0, "Seed of the random trajectory.", minimum=0, maximum=2**31)
        start_pose = declare_parameter(
            self,
            "start_pose",
            [0.4, 1.0, 0.0],
            "Start pose [x, y, theta] (m, m, rad) of the random trajectory.",
        )
        static_pose = declare_parameter(
            self, "static_pose", [1.5, 1.0, 0.0], "Pose [x, y, theta] of the static trajectory."
        )
        waypoints_x = declare_parameter(
            self, "waypoints_x", [0.4, 1.2, 2.2, 2.4, 1.5, 0.6], "x of the B-spline control points (m)."
        )
        waypoints_y = declare_parameter(
            self, "waypoints_y", [1.0, 1.0, 0.6, 1.4, 1.6, 0.7], "y of the B-spline control points (m)."
        )
        limits = self._declare_limits()
        try:
            if kind == "static":
                return EurobotTrajectory.static(_pose(static_pose, "static_pose"), duration_s)
            if kind == "waypoints":
                if len(waypoints_x) != len(waypoints_y):
                    raise ValueError(
                        f"waypoints_x has {len(waypoints_x)} values, waypoints_y {len(waypoints_y)}"
                    )
                points = list(zip(waypoints_x, waypoints_y, strict=True))
                return EurobotTrajectory.through_waypoints(points, duration_s, limits)
            return EurobotTrajectory.random(seed, duration_s, limits, _pose(start_pose, "start_pose"))
        except (ValueError, RuntimeError) as error:
            raise ParameterValidationError(f"trajectory: {error}") from None

    def _declare_limits(self) -> MotionLimits:
        try:
            return MotionLimits(
                max_speed_mps=declare_parameter(
                    self, "max_speed_mps", 0.5, "Top speed (m/s).", minimum=0.01, maximum=5.0
                ),
                max_yaw_rate_radps=declare_parameter(
                    self, "max_yaw_rate_radps", 2.0, "Top yaw rate (rad/s).", minimum=0.01, maximum=20.0
                ),
                robot_radius_m=declare_parameter(
                    self,
                    "robot_radius_m",
                    0.15,
                    "Robot footprint radius kept on the table (m).",
                    minimum=0.0,
                    maximum=0.9,
                ),
            )
        except ValueError as error:
            raise ParameterValidationError(str(error)) from None

    def _declare_drift(self) -> OdometryDrift:
        defaults = OdometryDrift()
        descriptions = {
            "left_scale_error": "Left wheel: reported / travelled distance - 1.",
            "right_scale_error": "Right wheel: reported / travelled distance - 1.",
            "wheel_base_error": "Nominal / true wheel base - 1.",
            "slip_std": "Per-sample wheel slip, fraction of the wheel's travel (half-normal sigma).",
            "noise_m_per_sqrt_m": "Random-walk noise of each wheel's distance (m per sqrt(m)).",
        }
        values = {
            name: declare_parameter(
                self, f"odometry_{name}", getattr(defaults, name), description, minimum=-0.49, maximum=0.49
            )
            for name, description in descriptions.items()
        }
        try:
            return OdometryDrift(**values)
        except ValueError as error:
            raise ParameterValidationError(str(error)) from None

    def _new_odometry(self) -> OdometrySimulator:
        return OdometrySimulator(
            self.trajectory, self.drift, seed=self.odometry_seed, wheel_base_m=self.wheel_base_m
        )

    # ---- the match ----

    def _tick(self) -> None:
        now = self.get_clock().now()
        now_s = now.nanoseconds * 1e-9
        if now.nanoseconds == 0:
            return  # use_sim_time and no /clock yet
        if now_s < self.last_s:
            self.get_logger().warning("clock went backwards: the match starts over")
            self.diagnostics.increment("restarts")
            self.start_s = None
        if self.start_s is None:
            self.start_s = now_s
            self.odometry = self._new_odometry()
            self.finished = False
        self.last_s = now_s
        match_s = now_s - self.start_s
        self._publish_truth(now, match_s)
        self._publish_odometry(now, match_s)
        self.diagnostics.increment("samples")
        self.diagnostics.set("match_time_s", round(match_s, 3))
        if match_s >= self.trajectory.duration_s and not self.finished:
            self.finished = True
            self.get_logger().info("match over: the robot stands still")
            self.diagnostics.set_level("ok", "match over")

    def _publish_truth(self, now: Time, match_s: float) -> None:
        msg = _odometry_message(
            now,
            self.map_frame,
            self.base_frame,
            self.trajectory.pose_at(match_s),
            self.trajectory.twist_at(match_s),
        )
        self.truth_publisher.publish(msg)

    def _publish_odometry(self, now: Time, match_s: float) -> None:
        sample = self.odometry.advance(match_s)
        pose, twist = sample.pose(-1), (float(sample.speed_mps[-1]), float(sample.yaw_rate_radps[-1]))
        msg = _odometry_message(now, self.odom_frame, self.base_frame, pose, twist)
        travelled_m = self.trajectory.distance_at(match_s)
        turned_rad = abs(
            self.trajectory.heading_unwrapped_at(match_s) - self.trajectory.heading_unwrapped_at(0.0)
        )
        position_var = (POSITION_SIGMA_PER_M * travelled_m) ** 2 + 1e-8
        heading_var = (HEADING_SIGMA_PER_RAD * turned_rad) ** 2 + 1e-8
        msg.pose.covariance = ros_covariance(np.diag([position_var, position_var, heading_var]))
        scale = max(abs(self.drift.left_scale_error), abs(self.drift.right_scale_error), self.drift.slip_std)
        linear_var, angular_var = (scale * twist[0]) ** 2 + 1e-8, (scale * twist[1]) ** 2 + 1e-8
        msg.twist.covariance = ros_covariance(np.diag([linear_var, linear_var, angular_var]))
        start_s, end_s = self.odometry_dropout_s
        if start_s <= match_s < end_s:
            self.diagnostics.increment("odometry_dropped")  # a rehearsed fault: the encoders' link is down
            return
        self.odom_publisher.publish(msg)
        if self.tf_publisher is not None:
            self.tf_publisher.publish(planar_tf_message(msg.header, msg.child_frame_id, pose))


def _pose(values: list[float], name: str) -> Pose2D:
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name} must be three finite numbers [x, y, theta], got {values}")
    return (float(values[0]), float(values[1]), float(values[2]))


def _odometry_message(
    now: Time, frame: str, child_frame: str, pose: Pose2D, twist: tuple[float, float]
) -> Odometry:
    msg = Odometry()
    msg.header.stamp = now.to_msg()
    msg.header.frame_id = frame
    msg.child_frame_id = child_frame
    set_pose2d(msg.pose.pose, pose)
    msg.twist.twist.linear.x = twist[0]
    msg.twist.twist.angular.z = twist[1]
    return msg


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(SimWorldNode, args))


if __name__ == "__main__":
    main()
