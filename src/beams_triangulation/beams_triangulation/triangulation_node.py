"""triangulation_node: ToTal (thesis ch. 6) on every BeAMS revolution, with 1/|D| gating and a covariance.

Its topics, services and parameters: docs/nodes.md. With `use_odometry`, a revolution's bearings are brought
to one instant with `odom` (a revolution the odometry does not cover yet waits for it, at most until the
next one: `pipeline.TriangulationPipeline`). Every pose is published, rejected ones with the reason; bad
input (`beams_common.intake`: a bearing refused, fewer than three beacons, a stamp beyond the plausibility
tolerance) gives no pose, with the reason on /diagnostics. Its status (`triangulation_health`) is on
/diagnostics and beams/triangulation/status (docs/status.md).
"""

from __future__ import annotations

import math
import sys

import numpy as np
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from visualization_msgs.msg import Marker, MarkerArray

from beams_common.calibration.calibration_file import SensorCalibration
from beams_common.config.geometry_parameters import geometry_of_calibration, runtime_geometry
from beams_common.intake.bearing_intake import bearings_message_intake
from beams_common.intake.plausibility import StampCheck, stamp_tolerance_of
from beams_common.intake.validation import bounded, planar_estimate_problem
from beams_common.interfaces import topics
from beams_common.ros.callback_guard import GuardedCallbacks
from beams_common.ros.input_watch import WatchedInputs
from beams_common.ros.messages import (
    OdometrySample,
    ros_covariance,
    seconds_to_stamp,
    set_pose2d,
    stamp_to_seconds,
)
from beams_common.ros.node_support import (
    BEARINGS_QOS,
    Diagnostics,
    StampedInputs,
    run_node,
    serve_calibration_reload,
    startup_geometry,
)
from beams_common.ros.parameters import ApplyChange, apply_runtime_changes, declare_table
from beams_common.ros.status_topic import StatusTopic
from beams_msgs.msg import BeaconBearingArray, TriangulatedPose
from beams_triangulation.gating import NoPose, PoseEstimate
from beams_triangulation.parameters import TRIANGULATION_PARAMETERS
from beams_triangulation.pipeline import TriangulationPipeline, triangulation_settings
from beams_triangulation.revolution import RevolutionPose
from beams_triangulation.triangulation_health import TriangulationHealth


class TriangulationNode(WatchedInputs, GuardedCallbacks, StampedInputs, Node):
    """ROS wiring of `pipeline.TriangulationPipeline` (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__("triangulation_node")
        self.parameters = declare_table(self, TRIANGULATION_PARAMETERS)
        settings = triangulation_settings(self.parameters)
        self.geometry = geometry = startup_geometry(self.parameters)
        self.map_frame = self.parameters["map_frame"]
        self.use_odometry = settings.use_odometry
        self.publish_markers = self.parameters["publish_markers"]
        self.pipeline = TriangulationPipeline(geometry.beacon_map, settings, geometry.turret_offset_m)
        apply_runtime_changes(self, TRIANGULATION_PARAMETERS, self.parameters, self._prepare_parameters)
        serve_calibration_reload(self, self._apply_calibration)
        self.diagnostics = Diagnostics(self, "triangulation")
        self.status_topic = StatusTopic(self, topics.TRIANGULATION_STATUS, self.diagnostics)
        self.stamp_check = StampCheck(stamp_tolerance_of(self.parameters))
        self.health = TriangulationHealth(self.parameters, self._now_s(), use_odometry=self.use_odometry)
        self.diagnostics.refresh_values = self._report_values
        # the status follows the clock even when no pose comes (lost after a second without one)
        self.create_timer(1.0, self._update_status)
        self._accepted_stamp = None  # the last accepted pose's header stamp
        self._update_status()  # waiting, said at once

        self.pose_publisher = self.create_publisher(TriangulatedPose, topics.POSE, 10)
        self.pose_cov_publisher = self.create_publisher(PoseWithCovarianceStamped, topics.POSE_COV, 10)
        self.marker_publisher = self.create_publisher(MarkerArray, topics.MARKERS, 10)
        # the outputs, built once (rclpy builds a message field by field) and filled at each pose
        self._pose = TriangulatedPose()
        self._pose_cov = PoseWithCovarianceStamped(header=self._pose.header, pose=self._pose.pose)
        self.create_subscription(BeaconBearingArray, topics.BEARINGS, self._on_bearings, BEARINGS_QOS)
        if self.use_odometry:
            self.create_odometry_subscription(topics.ODOMETRY, self._on_odometry, qos_profile_sensor_data)
        config = settings.gates
        self.get_logger().info(
            f"triangulation_node ready: beacons {list(geometry.beacon_map.ids)}, turret offset "
            f"{geometry.turret_offset_m} m, gates 1/|D| < {config.max_inverse_abs_d:g} m^-2 and std < "
            f"{config.max_position_std_m:g} m, odometry {'on' if self.use_odometry else 'off'}"
        )

    def recover_from_callback_exception(self, site: str) -> str:
        """A callback failed halfway (GuardedCallbacks): a new pipeline, without the waiting revolution."""
        old, geometry = self.pipeline, self.geometry
        self.pipeline = TriangulationPipeline(geometry.beacon_map, old.settings, geometry.turret_offset_m)
        # a count of the node's life, as /diagnostics' others are
        self.pipeline.revolutions_before_odometry = old.revolutions_before_odometry
        return "pipeline reset: the waiting revolution and the odometry history dropped"

    # -- parameters -----------------------------------------------------------------------------------
    def _prepare_parameters(self, values: dict, changed: set[str]) -> ApplyChange:
        """A runtime change (validated by the table): the beacon geometry (a calibration file read) and
        the gates built now (ValueError, OSError: refused), applied with the frame and the markers by the
        returned step."""
        geometry = runtime_geometry(values, changed, self.geometry)
        settings = triangulation_settings(values)
        tolerance = stamp_tolerance_of(values)

        def apply() -> None:
            self.geometry, self.stamp_check.tolerance = geometry, tolerance
            offset, limits = geometry.turret_offset_m, settings.motion_limits
            self.pipeline.configure(geometry.beacon_map, settings.gates, offset, limits)
            self.health.configure(values, self._now_s())
            self.map_frame = values["map_frame"]
            self.publish_markers = values["publish_markers"]

        return apply

    def _apply_calibration(self, calibration: SensorCalibration) -> str:
        self.geometry = geometry = geometry_of_calibration(calibration, self.parameters)
        offset = geometry.turret_offset_m
        self.pipeline.configure(geometry.beacon_map, self.pipeline.settings.gates, offset)
        return f"beacons {list(calibration.beacon_map.ids)} and turret offset {tuple(offset)} m replaced"

    # -- inputs ---------------------------------------------------------------------------------------
    def _on_odometry(self, sample: OdometrySample) -> None:
        now_s = self._now_s()
        self.health.on_odometry(now_s)
        stamp_s = sample.stamp_s
        if self._implausible_stamp("odometry", f"odometry at {stamp_s:.3f} s", stamp_s, now_s):
            return
        refused, completed = self.pipeline.take_odometry(stamp_s, sample.pose, sample.twist)
        if refused:
            self.diagnostics.refuse("odometry_rejected_non_finite", refused)
        jump = self.pipeline.last_odometry_jump
        if jump:  # the odometry starts over: no revolution is compensated across the jump
            self.diagnostics.refuse("odometry_jumps", f"{jump}: odometry history restarted")
            self.health.fault("odometry_jump", now_s, jump)
        self._handle(completed)

    def _on_bearings(self, msg: BeaconBearingArray) -> None:
        now_s = self._now_s()
        self.health.on_bearings(now_s)
        self.diagnostics.increment("revolutions")
        intake = bearings_message_intake(msg, stamp_to_seconds, self.pipeline.estimator.known_ids)
        if self._implausible_stamp("bearings", f"revolution {msg.revolution}", intake.newest_stamp_s, now_s):
            return
        if intake.too_many:  # refused before any per-bearing work
            self.diagnostics.refuse(
                "revolutions_too_many_bearings", f"revolution {msg.revolution}: {intake.too_many}"
            )
            return
        # counted; a conflicting or invalid bearing makes the revolution bad input (no pose), a repeated
        # sighting or an unknown beacon (another team's) is only left out
        for key, count in intake.counts().items():
            self.diagnostics.increment(key, count)
        self._handle(self.pipeline.on_intake(msg.revolution, intake))

    def _handle(self, completed: list[tuple[int, RevolutionPose]]) -> None:
        """Publish the revolutions the pipeline completed (or say why they gave no pose)."""
        for revolution, outcome in completed:
            if isinstance(outcome.result, NoPose):
                self._report_no_pose(outcome.result, revolution)
            else:
                self._publish(outcome.result, outcome.stamp_s, outcome.compensated)

    def _report_no_pose(self, no_pose: NoPose, revolution: int) -> None:
        reason = bounded(no_pose.reason)
        if no_pose.bad_input:
            self.diagnostics.refuse("bad_input", f"revolution {revolution}: no pose, bad input: {reason}")
        else:
            self.diagnostics.increment("no_pose")
            self.get_logger().debug(f"revolution {revolution}: no pose: {reason}")
        self.diagnostics.set("last_no_pose_reason", reason)

    # -- outputs --------------------------------------------------------------------------------------
    def _publish(self, estimate: PoseEstimate, stamp_s: float, compensated: bool) -> None:
        problem = planar_estimate_problem((estimate.x, estimate.y, estimate.heading), estimate.covariance)
        if problem or not math.isfinite(stamp_s):  # the invariant of every published pose
            self.diagnostics.refuse("poses_not_published_invalid", problem or f"non-finite stamp {stamp_s}")
            return
        message = self._pose
        message.header.stamp = seconds_to_stamp(stamp_s)  # a new Time: _accepted_stamp keeps the old one
        message.header.frame_id = self.map_frame
        set_pose2d(message.pose.pose, (estimate.x, estimate.y, estimate.heading))
        message.pose.covariance = ros_covariance(estimate.covariance)
        message.inverse_abs_d = float(estimate.inverse_abs_d)
        message.beacon_ids = [int(i) for i in estimate.beacon_ids]
        message.accepted = bool(estimate.accepted)
        message.reason = estimate.reason
        self.pose_publisher.publish(message)
        if estimate.accepted:
            self._accepted_stamp = message.header.stamp
            self.pose_cov_publisher.publish(self._pose_cov)
        # built only while something displays them (RViz, a bag): a robot's run has no reader, and the
        # array costs more than the pose's two messages
        if self.publish_markers and self.marker_publisher.get_subscription_count():
            self.marker_publisher.publish(self._markers(estimate, message.header))
        self._update_diagnostics(estimate, compensated)

    def _update_diagnostics(self, estimate: PoseEstimate, compensated: bool) -> None:
        self.diagnostics.increment("poses_accepted" if estimate.accepted else "poses_rejected")
        self.diagnostics.increment("motion_compensated" if compensated else "not_compensated")
        self.diagnostics.set("last_inverse_abs_d", float(estimate.inverse_abs_d))
        self.diagnostics.set("last_position_std_m", float(estimate.position_std_m))
        if not estimate.accepted:
            self.diagnostics.set("last_rejection", estimate.reason)
        self.health.on_pose(self._now_s(), bool(estimate.accepted), estimate.covariance)
        self._update_status()

    def _report_values(self) -> None:
        """The pipeline's count and the bearing rate, as /diagnostics is sent (not at every pose)."""
        early = self.pipeline.revolutions_before_odometry
        self.diagnostics.set("revolutions_estimated_before_their_odometry", early)
        self.diagnostics.set("bearing_rate_hz", self.health.bearing_rate.rate_hz(self._now_s()))

    def _update_status(self) -> None:
        """The status (`triangulation_health`): its level and message, and `status` (waiting, tracking,
        degraded or lost) as a value of its own; each pose carries its own verdict (accepted, reason)."""
        verdict = self.health.verdict(self._now_s())
        self.status_topic.say(verdict, self.health.integrity, self.health.protection, self._accepted_stamp)

    def _markers(self, estimate: PoseEstimate, header) -> MarkerArray:
        """Beacons (spheres), the pose (arrow) and its 2-sigma position ellipse (flat cylinder)."""
        markers = MarkerArray()
        lifetime = Duration(sec=1)
        for index, (x, y) in enumerate(self.pipeline.estimator.beacon_map.xy):
            beacon = self._marker(header, "beacons", index, Marker.SPHERE, (0.2, 0.4, 1.0))
            beacon.pose.position.x, beacon.pose.position.y = float(x), float(y)
            beacon.scale.x = beacon.scale.y = beacon.scale.z = 0.08
            markers.markers.append(beacon)
        colour = (0.1, 0.8, 0.1) if estimate.accepted else (0.9, 0.2, 0.1)
        arrow = self._marker(header, "pose", 0, Marker.ARROW, colour)
        set_pose2d(arrow.pose, (estimate.x, estimate.y, estimate.heading))
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
