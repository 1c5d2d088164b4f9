"""triangulation_node: ToTal (thesis ch. 6) on every BeAMS revolution, with 1/|D| gating and a covariance.

Subscribes (relative names): `beams/bearings` (beams_msgs/BeaconBearingArray, one revolution per
message, each bearing stamped with its own instant) and, when `use_odometry` is true, `odom`
(nav_msgs/Odometry) to bring the bearings of a revolution to one instant before ToTal.
Publishes `beams/pose` (beams_msgs/TriangulatedPose, every pose, rejected ones with `accepted = false`
and the reason), `beams/pose_cov` (geometry_msgs/PoseWithCovarianceStamped, accepted poses only), both
stamped with the bearings' mean instant in the map frame; `beams/markers` (visualization_msgs/
MarkerArray: beacons, pose arrow, 2-sigma covariance ellipse) and `/diagnostics`.
Bad input (unknown beacon id, NaN bearing, duplicated beacon, fewer than three beacons) gives a log line
and no pose. The beacon map and turret offset come from the calibration file when one is given.
"""

from __future__ import annotations

import collections
import math
import sys

import numpy as np
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import PoseWithCovariance, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from visualization_msgs.msg import Marker, MarkerArray

from beams_driver.calibration_file import SensorCalibration
from beams_driver.node_support import (
    Diagnostics,
    declare_beacon_geometry,
    declare_parameter,
    run_node,
    serve_calibration_reload,
)
from beams_driver.pose2d import compose
from beams_driver.ros_messages import pose2d_of, pose_with_covariance, seconds_to_stamp, stamp_to_seconds
from beams_msgs.msg import BeaconBearingArray, TriangulatedPose
from beams_triangulation.gating import (
    DEFAULT_MAX_INVERSE_ABS_D,
    DEFAULT_MAX_POSITION_STD_M,
    Bearing,
    GateConfig,
    NoPose,
    PoseEstimate,
    RevolutionEstimator,
)
from beams_triangulation.motion_compensation import arc_increment, interpolate_pose


def estimate_pose_with_covariance(estimate: PoseEstimate) -> PoseWithCovariance:
    """The estimate as geometry_msgs/PoseWithCovariance."""
    return pose_with_covariance((estimate.x, estimate.y, estimate.heading), estimate.covariance)


class OdometryBuffer:
    """Recent odometry poses (odom frame) by stamp, with a short extrapolation by the last twist."""

    def __init__(self, span_s: float, max_extrapolation_s: float) -> None:
        self.span_s = span_s
        self.max_extrapolation_s = max_extrapolation_s
        self._samples: collections.deque[tuple[float, tuple[float, float, float]]] = collections.deque()
        self._twist = (0.0, 0.0)

    def add(self, stamp_s: float, pose: tuple[float, float, float], twist: tuple[float, float]) -> None:
        if self._samples and stamp_s <= self._samples[-1][0]:
            if stamp_s < self._samples[-1][0] - 1.0:  # the clock went back (bag or simulation restarted)
                self._samples.clear()
            else:
                return
        self._samples.append((stamp_s, pose))
        self._twist = twist
        while self._samples and self._samples[0][0] < stamp_s - self.span_s:
            self._samples.popleft()

    def pose_at(self, t: float) -> tuple[float, float, float] | None:
        """Odometry pose at t, or None when t is older than the buffer or too far past its end."""
        if not self._samples:
            return None
        newest_s, newest = self._samples[-1]
        if t > newest_s:
            dt = t - newest_s
            if dt > self.max_extrapolation_s:
                return None
            return compose(newest, arc_increment(self._twist[0], self._twist[1], dt))
        stamps = [s for s, _ in self._samples]
        return interpolate_pose(stamps, [p for _, p in self._samples], t)


class TriangulationNode(Node):
    """ROS wiring of `gating.RevolutionEstimator` (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__("triangulation_node")
        beacon_map, offset = declare_beacon_geometry(self)
        config = self._declare_gates()
        self.map_frame = declare_parameter(self, "map_frame", "map", "Frame of the published poses.")
        self.use_odometry = declare_parameter(
            self, "use_odometry", True, "Bring each revolution's bearings to one instant with `odom`.")
        span_s = declare_parameter(self, "odometry_history_s", 2.0, "Odometry kept for compensation (s).",
                                   minimum=0.1, maximum=60.0)
        extrapolation_s = declare_parameter(
            self, "max_odometry_extrapolation_s", 0.05,
            "How far past the newest odometry a bearing may be and still be compensated (s).",
            minimum=0.0, maximum=1.0)
        self.publish_markers = declare_parameter(self, "publish_markers", True, "Publish RViz markers.")
        self.estimator = RevolutionEstimator(beacon_map, config, offset)
        serve_calibration_reload(self, self._apply_calibration)
        self.odometry = OdometryBuffer(span_s, extrapolation_s)
        self.diagnostics = Diagnostics(self, "triangulation")
        self.diagnostics.set_level("warn", "waiting for bearings")

        self.pose_publisher = self.create_publisher(TriangulatedPose, "beams/pose", 10)
        self.pose_cov_publisher = self.create_publisher(PoseWithCovarianceStamped, "beams/pose_cov", 10)
        self.marker_publisher = self.create_publisher(MarkerArray, "beams/markers", 10)
        self.create_subscription(BeaconBearingArray, "beams/bearings", self._on_bearings,
                                 qos_profile_sensor_data)
        if self.use_odometry:
            self.create_subscription(Odometry, "odom", self._on_odometry, qos_profile_sensor_data)
        self.get_logger().info(
            f"triangulation_node ready: beacons {list(beacon_map.ids)}, turret offset {offset} m, gates "
            f"1/|D| < {config.max_inverse_abs_d:g} m^-2 and std < {config.max_position_std_m:g} m, "
            f"odometry {'on' if self.use_odometry else 'off'}")

    # -- parameters -----------------------------------------------------------------------------------
    def _apply_calibration(self, calibration: SensorCalibration) -> str:
        offset = calibration.turret_offset_m
        self.estimator = RevolutionEstimator(calibration.beacon_map, self.estimator.config, offset)
        return f"beacons {list(calibration.beacon_map.ids)} and turret offset {tuple(offset)} m replaced"

    def _declare_gates(self) -> GateConfig:
        return GateConfig(
            max_inverse_abs_d=declare_parameter(
                self, "max_inverse_abs_d", DEFAULT_MAX_INVERSE_ABS_D,
                "Gate on ToTal's reliability measure 1/|D| (m^-2).", minimum=1e-9, maximum=1e12),
            max_position_std_m=declare_parameter(
                self, "max_position_std_m", DEFAULT_MAX_POSITION_STD_M,
                "Gate on the propagated position std sqrt(var x + var y) (m).", minimum=1e-9, maximum=1e3),
        )

    # -- inputs ---------------------------------------------------------------------------------------
    def _on_odometry(self, msg: Odometry) -> None:
        pose = pose2d_of(msg.pose.pose)
        self.odometry.add(stamp_to_seconds(msg.header.stamp), pose,
                          (msg.twist.twist.linear.x, msg.twist.twist.angular.z))

    def _on_bearings(self, msg: BeaconBearingArray) -> None:
        self.diagnostics.increment("revolutions")
        revolution_s = stamp_to_seconds(msg.header.stamp)
        bearings = [Bearing(int(b.beacon_id), float(b.bearing), float(b.variance),
                            stamp_to_seconds(b.header.stamp) or revolution_s) for b in msg.bearings]
        outcome = self.estimator.update(bearings, self.odometry.pose_at if self.use_odometry else None)
        if isinstance(outcome.result, NoPose):
            self._report_no_pose(outcome.result, msg.revolution)
            return
        self._publish(outcome.result, outcome.stamp_s, outcome.compensated)

    def _report_no_pose(self, no_pose: NoPose, revolution: int) -> None:
        reason = no_pose.reason
        if no_pose.bad_input:
            self.diagnostics.increment("bad_input")
            self.get_logger().warn(f"revolution {revolution}: no pose, bad input: {reason}",
                                   throttle_duration_sec=1.0)
        else:
            self.diagnostics.increment("no_pose")
            self.get_logger().debug(f"revolution {revolution}: no pose: {reason}")
        self.diagnostics.set("last_no_pose_reason", reason)

    # -- outputs --------------------------------------------------------------------------------------
    def _publish(self, estimate: PoseEstimate, stamp_s: float, compensated: bool) -> None:
        message = TriangulatedPose()
        message.header.stamp = seconds_to_stamp(stamp_s)
        message.header.frame_id = self.map_frame
        message.pose = estimate_pose_with_covariance(estimate)
        message.inverse_abs_d = float(estimate.inverse_abs_d)
        message.beacon_ids = [int(i) for i in estimate.beacon_ids]
        message.accepted = bool(estimate.accepted)
        message.reason = estimate.reason
        self.pose_publisher.publish(message)
        if estimate.accepted:
            stamped = PoseWithCovarianceStamped(header=message.header, pose=message.pose)
            self.pose_cov_publisher.publish(stamped)
        if self.publish_markers:
            self.marker_publisher.publish(self._markers(estimate, message.header))
        self._update_diagnostics(estimate, compensated)

    def _update_diagnostics(self, estimate: PoseEstimate, compensated: bool) -> None:
        self.diagnostics.increment("poses_accepted" if estimate.accepted else "poses_rejected")
        self.diagnostics.increment("motion_compensated" if compensated else "not_compensated")
        self.diagnostics.set("last_inverse_abs_d", float(estimate.inverse_abs_d))
        self.diagnostics.set("last_position_std_m", float(estimate.position_std_m))
        if estimate.accepted:
            self.diagnostics.set_level("ok", "pose accepted")
        else:
            self.diagnostics.set_level("warn", f"pose rejected: {estimate.reason}")

    def _markers(self, estimate: PoseEstimate, header) -> MarkerArray:
        """Beacons (spheres), the pose (arrow) and its 2-sigma position ellipse (flat cylinder)."""
        markers = MarkerArray()
        lifetime = Duration(sec=1)
        for index, (x, y) in enumerate(self.estimator.beacon_map.xy):
            beacon = self._marker(header, "beacons", index, Marker.SPHERE, (0.2, 0.4, 1.0))
            beacon.pose.position.x, beacon.pose.position.y = float(x), float(y)
            beacon.scale.x = beacon.scale.y = beacon.scale.z = 0.08
            markers.markers.append(beacon)
        colour = (0.1, 0.8, 0.1) if estimate.accepted else (0.9, 0.2, 0.1)
        arrow = self._marker(header, "pose", 0, Marker.ARROW, colour)
        arrow.pose = estimate_pose_with_covariance(estimate).pose
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.2, 0.03, 0.03
        arrow.lifetime = lifetime
        markers.markers.append(arrow)
        values, vectors = np.linalg.eigh(estimate.covariance[:2, :2])
        if np.all(np.isfinite(values)):
            ellipse = self._marker(header, "covariance", 0, Marker.CYLINDER, colour, alpha=0.4)
            ellipse.pose.position.x, ellipse.pose.position.y = float(estimate.x), float(estimate.y)
            angle = math.atan2(vectors[1, 1], vectors[0, 1])  # the major axis
            ellipse.pose.orientation.z, ellipse.pose.orientation.w = math.sin(angle / 2), math.cos(angle / 2)
            minor, major = 4.0 * np.sqrt(np.maximum(values, 0.0))  # 2-sigma diameters
            ellipse.scale.x, ellipse.scale.y, ellipse.scale.z = max(major, 1e-3), max(minor, 1e-3), 0.005
            ellipse.lifetime = lifetime
            markers.markers.append(ellipse)
        return markers

    @staticmethod
    def _marker(header, namespace: str, marker_id: int, kind: int, rgb, alpha: float = 1.0) -> Marker:
        marker = Marker(header=header, ns=namespace, id=marker_id, type=kind, action=Marker.ADD)
        marker.pose.orientation.w = 1.0
        marker.color.r, marker.color.g, marker.color.b = (float(c) for c in rgb)
        marker.color.a = alpha
        return marker


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(TriangulationNode, args))


if __name__ == "__main__":
    main()
