"""ekf_node: wheel odometry and every BeAMS bearing fused in an EKF (thesis fig. 8.1), ToTal to initialise it.

Subscribes (relative names): `odom` (nav_msgs/Odometry, odom frame), `beams/bearings`
(beams_msgs/BeaconBearingArray), `beams/pose` (beams_msgs/TriangulatedPose, accepted fixes initialise
the filter or re-initialise it after a kidnapping), `/initialpose`
(geometry_msgs/PoseWithCovarianceStamped, an operator's pose: always re-initialises; the service
`~/set_pose` (beams_msgs/SetPose) does the same).
Publishes `beams/ekf/odometry` (nav_msgs/Odometry, map -> base_link, pose and twist with covariance)
and `beams/ekf/pose` (PoseWithCovarianceStamped) after each revolution's bearings and at
`publish_rate_hz` as odometry moves it, the map -> odom transform on `/tf` (REP-105: the odometry's
source publishes odom -> base_link), plus `/diagnostics`.
Service `~/reset` (std_srvs/Trigger) forgets the estimate until the next pose.
All data times are message stamps (use_sim_time works); odometry going back in time resets the filter.
"""

import math
import sys

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from beams_common import topics
from beams_common.bearing import bearings_of_message
from beams_common.calibration_file import SensorCalibration
from beams_common.geometry_parameters import geometry_of_calibration, runtime_geometry
from beams_common.ros.callback_guard import GuardedCallbacks
from beams_common.ros.input_watch import WatchedInputs
from beams_common.ros.messages import (
    planar_covariance,
    planar_tf_message,
    pose2d_of,
    ros_covariance,
    seconds_to_stamp,
    set_pose2d,
    stamp_to_seconds,
)
from beams_common.ros.node_support import (
    BEARINGS_QOS,
    TF_QOS,
    Diagnostics,
    run_node,
    serve_calibration_reload,
    startup_geometry,
)
from beams_common.ros.parameters import apply_runtime_changes, declare_table
from beams_common.validation import (
    bounded,
    operator_pose_problem,
    planar_estimate_problem,
)
from beams_ekf.localiser import (
    Estimate,
    build_localiser,
    filter_settings,
)
from beams_ekf.parameters import EKF_PARAMETERS
from beams_msgs.msg import BeaconBearingArray, TriangulatedPose
from beams_msgs.srv import SetPose

WAITING_FOR_POSE = "waiting for an initial pose (beams/pose, /initialpose or the set_pose service)"


class EkfNode(WatchedInputs, GuardedCallbacks, Node):
    """ROS wiring of `Localiser` (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__("ekf_node")
        self.parameters = declare_table(self, EKF_PARAMETERS)
        self.settings = filter_settings(self.parameters)
        self.geometry = geometry = startup_geometry(self.parameters)
        beacons = geometry.beacon_map.as_dict()
        self.localiser = build_localiser(beacons, geometry.turret_offset_m, self.settings)
        self.map_frame = self.parameters["map_frame"]
        self.base_frame = self.parameters["base_frame"]
        self.odom_frame = self.parameters["odom_frame"]
        publish_tf = self.parameters["publish_tf"]
        rate_hz = self.parameters["publish_rate_hz"]
        self.diagnostics = Diagnostics(self, "ekf")
        self.diagnostics.set_level("warn", WAITING_FOR_POSE)
        self._last_twist = None
        # the newest odometry header stamp, republished exactly (a float loses nanoseconds at epoch scale)
        self._last_odometry_stamp: tuple[float, Time] | None = None
        self._published_stamp_s: float | None = None
        self._changed = False  # a bearing or pose changed the estimate since the last publication

        self.odometry_publisher = self.create_publisher(Odometry, topics.EKF_ODOMETRY, 10)
        self.pose_publisher = self.create_publisher(PoseWithCovarianceStamped, topics.EKF_POSE, 10)
        self.tf_publisher = self.create_publisher(TFMessage, topics.TF, TF_QOS) if publish_tf else None
        self.create_subscription(Odometry, topics.ODOMETRY, self._on_odometry, qos_profile_sensor_data)
        self.create_subscription(BeaconBearingArray, topics.BEARINGS, self._on_bearings, BEARINGS_QOS)
        self.create_subscription(TriangulatedPose, topics.POSE, self._on_total_pose, 10)
        self.create_subscription(PoseWithCovarianceStamped, topics.INITIAL_POSE, self._on_initial_pose, 10)
        self.create_service(SetPose, topics.SET_POSE, self._on_set_pose)
        self.create_service(Trigger, topics.RESET, self._on_reset)
        serve_calibration_reload(self, self._apply_calibration)
        apply_runtime_changes(self, EKF_PARAMETERS, self.parameters, self._apply_parameters)
        self.create_timer(1.0 / rate_hz, self._publish)
        self.get_logger().info(
            f"ekf_node ready: {len(self.localiser.ekf.beacons_xy)} beacons, turret offset "
            f"{self.localiser.ekf.sensor_offset_m} m, gate {self.localiser.ekf.gate:.2f}"
        )

    def recover_from_callback_exception(self, site: str) -> str:
        """A callback failed halfway (GuardedCallbacks): the filter may be half-updated, so it starts over."""
        self.localiser.reset("resets_after_callback_exception")
        self._published_stamp_s = None
        return "filter reset: it re-initialises from the next fix"

    # -- parameters -----------------------------------------------------------------------------------
    def _apply_parameters(self, values: dict, changed: set[str]) -> None:
        """A runtime change (validated by the table): the beacon geometry, the process noise, the gate."""
        self.geometry = geometry = runtime_geometry(values, changed, self.geometry)
        self.settings = filter_settings(values)
        self.localiser.configure(geometry.beacon_map.as_dict(), geometry.turret_offset_m, self.settings)

    # -- inputs ---------------------------------------------------------------------------------------
    def _on_odometry(self, msg: Odometry) -> None:
        stamp_s = stamp_to_seconds(msg.header.stamp)
        outcome = self.localiser.on_odometry(stamp_s, pose2d_of(msg.pose.pose))
        if outcome == "invalid":
            self.diagnostics.refuse("odometry_refused", f"odometry at {stamp_s:.3f} s: non-finite pose")
        if outcome in ("reference", "predicted"):
            self._last_twist = msg.twist
            self._last_odometry_stamp = (stamp_s, msg.header.stamp)
        if outcome == "reference":  # a time jump resets what was published too
            self._published_stamp_s = None

    def _on_bearings(self, msg: BeaconBearingArray) -> None:
        if self.diagnostics.oversized_revolution(msg):  # refused before any per-bearing work
            return
        bearings = bearings_of_message(msg, stamp_to_seconds)
        counts = self.localiser.stats.counts
        invalid_before = counts["bearings_invalid measurement"] + counts["bearings_unknown beacon"]
        refused = self.localiser.on_revolution(bearings)
        if refused:
            self.diagnostics.refuse(
                "revolutions_conflicting_beacon", f"revolution {msg.revolution}: " + refused
            )
        invalid = counts["bearings_invalid measurement"] + counts["bearings_unknown beacon"] - invalid_before
        if invalid:
            self.diagnostics.refuse(
                "revolutions_with_invalid_bearings",
                f"revolution {msg.revolution}: "
                f"{invalid} bearing(s) refused (unknown beacon, non-finite value or "
                "non-physical variance)",
            )
        self._changed = True
        self._publish()  # at once: the end-to-end latency from a revolution to the estimate stays small

    def _on_total_pose(self, msg: TriangulatedPose) -> None:
        if not (self.settings.use_total_pose and msg.accepted):
            return
        if self._offer_pose(msg.header.stamp, msg.pose, operator=False) == "invalid":
            self.diagnostics.refuse("total_poses_refused", "accepted ToTal pose with a non-finite value")

    def _on_initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        self._operator_pose(msg)

    def _on_set_pose(self, request: SetPose.Request, response: SetPose.Response) -> SetPose.Response:
        response.success, response.message = self._operator_pose(request.pose)
        return response

    def _operator_pose(self, msg: PoseWithCovarianceStamped) -> tuple[bool, str]:
        """An operator's pose (RViz /initialpose or the set_pose service): (taken, what happened); taken
        only when the filter was initialised from it."""
        if msg.header.frame_id and msg.header.frame_id != self.map_frame:
            message = f"pose in frame {msg.header.frame_id!r} ignored (expected {self.map_frame!r})"
            self.diagnostics.refuse("poses_wrong_frame", message)
            return False, bounded(message)
        position, q = msg.pose.pose.position, msg.pose.pose.orientation
        problem = operator_pose_problem(
            (position.x, position.y, position.z), (q.x, q.y, q.z, q.w), msg.pose.covariance
        )
        if problem:
            self.diagnostics.refuse("operator_poses_refused", problem)
            return False, f"operator pose refused: {problem}"
        what = self._offer_pose(msg.header.stamp, msg.pose, operator=True)
        if what != "initialisations":
            self.diagnostics.refuse("operator_poses_refused", f"the filter did not take it: {what}")
            return False, f"operator pose refused by the filter: {what}"
        self.get_logger().info(f"operator pose: {what}")
        self._publish()
        return True, f"operator pose: {what}"

    def _apply_calibration(self, calibration: SensorCalibration) -> str:
        self.geometry = geometry = geometry_of_calibration(calibration)
        beacon_map, offset = geometry.beacon_map, geometry.turret_offset_m
        self.localiser.configure(beacon_map.as_dict(), offset, self.settings)
        return f"beacons {list(beacon_map.ids)} and turret offset {tuple(offset)} m replaced"

    def _offer_pose(self, stamp, pose_with_covariance, *, operator: bool) -> str:
        return self.localiser.offer_pose(
            stamp_to_seconds(stamp),
            pose2d_of(pose_with_covariance.pose),
            planar_covariance(pose_with_covariance.covariance),
            self.settings.default_pose_covariance,
            operator=operator,
        )

    def _on_reset(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.localiser.reset("manual_resets")
        self._published_stamp_s = None
        response.success = True
        response.message = "EKF reset: waiting for a pose (beams/pose, ~/set_pose or /initialpose)"
        self.get_logger().info(response.message)
        return response

    # -- outputs --------------------------------------------------------------------------------------
    def _publish(self) -> None:
        estimate = self.localiser.estimate()
        self._update_diagnostics(estimate)
        if estimate is None or not math.isfinite(estimate.stamp_s):
            return
        problem = planar_estimate_problem(estimate.pose, estimate.covariance)
        if problem:  # the invariant of every published estimate
            self.diagnostics.refuse("estimates_not_published_invalid", problem, level="error")
            return
        if estimate.stamp_s == self._published_stamp_s and not self._changed:  # nothing new since
            return
        self._published_stamp_s = estimate.stamp_s
        self._changed = False
        odometry = Odometry()
        exact = self._last_odometry_stamp
        same = exact is not None and exact[0] == estimate.stamp_s
        odometry.header.stamp = exact[1] if same else seconds_to_stamp(estimate.stamp_s)
        odometry.header.frame_id = self.map_frame
        odometry.child_frame_id = self.base_frame
        _fill_pose(odometry.pose, estimate)
        if self._last_twist is not None:
            odometry.twist = self._last_twist
        else:
            odometry.twist.twist.linear.x, odometry.twist.twist.linear.y = estimate.twist[:2]
            odometry.twist.twist.angular.z = estimate.twist[2]
        self.odometry_publisher.publish(odometry)
        pose = PoseWithCovarianceStamped()
        pose.header = odometry.header
        pose.pose = odometry.pose
        self.pose_publisher.publish(pose)
        map_to_odom = estimate.map_to_odom
        if self.tf_publisher is not None and map_to_odom is not None:
            self.tf_publisher.publish(planar_tf_message(odometry.header, self.odom_frame, map_to_odom))

    def _update_diagnostics(self, estimate: Estimate | None) -> None:
        stats = self.localiser.stats
        for key, value in stats.counts.items():
            self.diagnostics.set(key, value)
        if estimate is None:
            self.diagnostics.set_level("warn", WAITING_FOR_POSE)
            return
        self.diagnostics.set("covariance_trace", float(np.trace(estimate.covariance)))
        self.diagnostics.set("recent_gated_bearings", self.localiser.recent_gated_bearings)
        self.diagnostics.set("lost_nis_window_sum", self.localiser.nis_monitor.window_sum)
        since_s = (
            estimate.stamp_s - stats.last_bearing_stamp_s
            if stats.last_bearing_stamp_s is not None
            else float("inf")
        )
        self.diagnostics.set("time_since_last_bearing_s", since_s)
        if since_s > 1.0:
            self.diagnostics.set_level("warn", "no accepted bearing for more than 1 s: odometry only")
        elif self.localiser.nis_monitor.lost:
            self.diagnostics.set_level("warn", "lost: innovations too large, waiting for a ToTal pose")
        elif self.localiser.kidnap_suspected:
            self.diagnostics.set_level("warn", "bearings gated out: robot moved? waiting for a ToTal pose")
        else:
            self.diagnostics.set_level("ok", "tracking")


def _fill_pose(pose_with_covariance, estimate: Estimate) -> None:
    set_pose2d(pose_with_covariance.pose, estimate.pose)
    pose_with_covariance.covariance = ros_covariance(estimate.covariance)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(EkfNode, args))


if __name__ == "__main__":
    main()
