"""sim_world_node: the simulated robot on the Eurobot table, its true pose and its drifting wheel odometry.

Publishes at `rate_hz`, both nav_msgs/Odometry, RELIABLE (depth 10, so that best-effort subscribers match
too): `beams/sim/ground_truth` (map -> base_link, an `EurobotTrajectory`) and `odom` (an `OdometrySimulator`:
the odom frame's origin is the start pose), with `publish_tf` also odom -> base_link on `/tf`. The match clock
starts with the node's first tick (use_sim_time follows /clock) and starts over when the clock jumps
backwards; after `duration_s` the robot stands still."""

import math
import sys

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.time import Time
from tf2_msgs.msg import TFMessage

from beams_common.interfaces import topics
from beams_common.ros.callback_guard import GuardedCallbacks
from beams_common.ros.messages import planar_tf_message, ros_covariance, set_pose2d
from beams_common.ros.node_support import TF_QOS, Diagnostics, run_node
from beams_common.ros.parameters import ParameterValidationError, declare_table
from beams_common.ros.rate_status import RateStatus
from beams_common.status.health import RATE_WINDOW_S, RateMonitor
from beams_sim.parameters import SIM_WORLD_PARAMETERS
from beams_sim.world import OdometrySimulator, Pose2D, drift_of, trajectory_of

QUEUE_DEPTH = 10
# Rough 1-sigma growth of odometry errors, for the covariance fields only (the EKF has its own model).
POSITION_SIGMA_PER_M = 0.01
HEADING_SIGMA_PER_RAD = 0.01
# the odometry published is OK within +-50 % of rate_hz (a loaded machine delays timers); none for 2 s
# (odometry_dropout_s, a rehearsed fault) is ERROR
ODOMETRY_RATE_TOLERANCE = 0.5


class SimWorldNode(GuardedCallbacks, Node):
    def __init__(self) -> None:
        super().__init__("sim_world_node")
        self.diagnostics = Diagnostics(self, "sim_world")
        values = declare_table(self, SIM_WORLD_PARAMETERS)
        self.map_frame, self.odom_frame, self.base_frame = (
            values[f"{k}_frame"] for k in ("map", "odom", "base")
        )
        rate_hz = values["rate_hz"]
        try:
            self.trajectory = trajectory_of(values)
            self.drift = drift_of(values)
        except (ValueError, RuntimeError) as error:
            raise ParameterValidationError(f"trajectory: {error}") from None
        self.odometry_seed = values["odometry_seed"]
        self.wheel_base_m = values["wheel_base_m"]
        self.odometry_dropout_s = values["odometry_dropout_s"]
        self.truth_publisher = self.create_publisher(Odometry, topics.GROUND_TRUTH, QUEUE_DEPTH)
        self.odom_publisher = self.create_publisher(Odometry, topics.ODOMETRY, QUEUE_DEPTH)
        self.tf_publisher = (
            self.create_publisher(TFMessage, topics.TF, TF_QOS) if values["publish_tf"] else None
        )
        self.start_s: float | None = None
        self.last_s = -math.inf
        self.finished = False
        self.odometry = self._new_odometry()
        low, high = rate_hz * (1.0 - ODOMETRY_RATE_TOLERANCE), rate_hz * (1.0 + ODOMETRY_RATE_TOLERANCE)
        monitor = RateMonitor("odometry", RATE_WINDOW_S, low, high)
        self.odometry_rate = RateStatus(self.diagnostics, "odometry", monitor)
        self.create_timer(1.0 / rate_hz, self._tick)
        self.get_logger().info(
            f"{self.trajectory.duration_s:.0f} s trajectory starting at {self.trajectory.pose_at(0.0)}, "
            f"publishing {self.resolve_topic_name('beams/sim/ground_truth')} and "
            f"{self.resolve_topic_name('odom')} at {rate_hz} Hz"
        )

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
        self.odometry_rate.update(now_s)
        self.diagnostics.increment("samples")
        self.diagnostics.set("match_time_s", round(match_s, 3))
        if match_s >= self.trajectory.duration_s and not self.finished:
            self.finished = True
            self.get_logger().info("match over: the robot stands still")
            self.diagnostics.set_level("ok", "match over")

    def _publish_truth(self, now: Time, match_s: float) -> None:
        pose, twist = self.trajectory.pose_at(match_s), self.trajectory.twist_at(match_s)
        self.truth_publisher.publish(_odometry_message(now, self.map_frame, self.base_frame, pose, twist))

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
        self.odometry_rate.tick(now.nanoseconds * 1e-9)
        if self.tf_publisher is not None:
            self.tf_publisher.publish(planar_tf_message(msg.header, msg.child_frame_id, pose))


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
