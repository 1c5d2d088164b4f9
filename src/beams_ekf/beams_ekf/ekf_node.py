"""ekf_node: wheel odometry and every BeAMS bearing fused in an EKF (thesis fig. 8.1), ToTal to initialise it.

Its topics, services and parameters: docs/nodes.md; its status (waiting, tracking, degraded, lost:
`ekf_health`, on /diagnostics and beams/ekf/status): docs/status.md. It publishes after each revolution's
bearings and, as odometry moves the estimate, at least at `publish_rate_hz` (the timer restarts at each
revolution's estimate); all data times are message stamps
(use_sim_time works), odometry going back in time resets the filter. Every input goes through its intake
(`beams_common.intake`: the bearing, pose and stamp-plausibility checks, each refusal counted with its reason
on /diagnostics), then the Localiser's door for it. A (re)start resumes from `checkpoint_file`
(beams_ekf.checkpoint), said in the log and as `checkpoint` on /diagnostics.
"""

import math
import os
import sys

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from beams_common.calibration.calibration_checks import BearingSample, RecentBearings
from beams_common.calibration.calibration_file import SensorCalibration
from beams_common.config.geometry_parameters import BeaconGeometry, geometry_of_calibration, runtime_geometry
from beams_common.intake.bearing_intake import RevolutionIntake, bearings_message_intake
from beams_common.intake.plausibility import StampCheck, stamp_tolerance_of
from beams_common.intake.pose_intake import KeptPose, PoseIntake, PoseSource, RefusedPose, pose_message_intake
from beams_common.intake.validation import bounded, planar_estimate_problem
from beams_common.interfaces import topics
from beams_common.ros.callback_guard import GuardedCallbacks
from beams_common.ros.input_watch import WatchedInputs
from beams_common.ros.messages import (
    OdometrySample,
    planar_tf_message,
    ros_covariance,
    seconds_to_stamp,
    set_planar_tf,
    set_pose2d,
    stamp_to_seconds,
)
from beams_common.ros.node_support import (
    BEARINGS_QOS,
    TF_QOS,
    Diagnostics,
    StampedInputs,
    run_node,
    serve_calibration_reload,
    startup_geometry,
)
from beams_common.ros.parameters import ApplyChange, apply_runtime_changes, declare_table
from beams_common.ros.status_topic import StatusTopic
from beams_common.status.health import Status
from beams_ekf.checkpoint import RuntimeChanges, checkpoint_path, resume_from, save_checkpoint
from beams_ekf.ekf_health import EkfHealth
from beams_ekf.localiser import build_localiser
from beams_ekf.outcomes import Estimate, OdometryOutcome, PoseOutcome
from beams_ekf.parameters import EKF_PARAMETERS, filter_settings
from beams_ekf.self_calibration import save_self_calibration
from beams_msgs.msg import BeaconBearingArray, TriangulatedPose
from beams_msgs.srv import SetPose

# a calibration that disagrees with the recent bearings keeps the status degraded this long (s): the NIS
# test then has a window of new bearings to judge it on
CALIBRATION_FLAG_HOLD_S = 10.0
FRAMES = ("map", "base", "odom")  # the <frame>_frame parameters


class Checkpointed:
    """ekf_node's checkpoint on the ROS side (beams_ekf.checkpoint): its runtime changes set back and its
    learnt states resumed at start, said in the log (WARN when some was refused) and as `checkpoint` on
    /diagnostics; saved every checkpoint_period_s and at a clean stop. Uses the node's `parameters`,
    `localiser`, `geometry` and `diagnostics`; `runtime_changes` records the changes as they are applied."""

    def _resume_checkpoint(self) -> None:
        self.runtime_changes, name = RuntimeChanges(self.parameters), self.get_fully_qualified_name()
        self.checkpoint_path = path = checkpoint_path(self.parameters["checkpoint_file"], name, os.environ)
        said, complete = resume_from(
            path, self.localiser.ekf, self.parameters, self._set_back, lambda: self.geometry
        )
        (self.get_logger().info if complete else self.get_logger().warning)(said)
        self.diagnostics.set("checkpoint", bounded(said))
        if path is not None:
            self.create_timer(self.parameters["checkpoint_period_s"], self._save_checkpoint)

    def _set_back(self, name: str, value: object) -> str:
        """A checkpoint's runtime change set back as `ros2 param set` sets it: why it was refused, or ''."""
        return self.set_parameters([Parameter(name, value=value)])[0].reason

    def _save_checkpoint(self) -> None:
        problem = save_checkpoint(
            self.checkpoint_path, self.localiser.ekf, self.geometry, self.runtime_changes
        )
        if problem:
            self.diagnostics.refuse("checkpoints_not_written", problem, level="error")

    def destroy_node(self) -> None:
        self._save_checkpoint()  # a clean stop keeps what was learnt since the last period
        super().destroy_node()


class EkfNode(WatchedInputs, GuardedCallbacks, Checkpointed, StampedInputs, Node):
    """ROS wiring of `Localiser` (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__("ekf_node")
        self.parameters = declare_table(self, EKF_PARAMETERS)
        self.settings = filter_settings(self.parameters)
        self.geometry = geometry = startup_geometry(self.parameters)
        beacons, offset = geometry.beacon_map.as_dict(), geometry.turret_offset_m
        self.localiser = build_localiser(beacons, offset, self.settings)
        self.map_frame, self.base_frame, self.odom_frame = (self.parameters[f"{k}_frame"] for k in FRAMES)
        self.diagnostics = Diagnostics(self, "ekf")
        self.health = EkfHealth(self.parameters, self._now_s())
        # the estimate last judged and its bearing silence (s), reported with /diagnostics
        self._judged: tuple[Estimate | None, float] = (None, math.inf)
        self.diagnostics.refresh_values = self._report_values
        self.status_topic = StatusTopic(self, topics.EKF_STATUS, self.diagnostics)
        self.stamp_check = StampCheck(stamp_tolerance_of(self.parameters))
        self._update_diagnostics(None)  # waiting, said at once
        self.recent_bearings = RecentBearings()
        # the newest odometry header stamp, republished exactly (a float loses nanoseconds at epoch scale)
        self._last_odometry_stamp: tuple[float, Time] | None = None
        self._published_stamp_s: float | None = None
        self._changed = False  # a bearing or pose changed the estimate since the last publication
        self._tf_stamp_s: float | None = None

        self.odometry_publisher = self.create_publisher(Odometry, topics.EKF_ODOMETRY, 10)
        self.pose_publisher = self.create_publisher(PoseWithCovarianceStamped, topics.EKF_POSE, 10)
        self.tf_publisher = (
            self.create_publisher(TFMessage, topics.TF, TF_QOS) if self.parameters["publish_tf"] else None
        )
        # the outputs, built once and filled at each publication (rclpy builds a message field by field),
        # one header and one pose shared by the three
        self._odometry = Odometry(child_frame_id=self.base_frame)
        self._odometry.header.frame_id = self.map_frame
        self._pose = PoseWithCovarianceStamped(header=self._odometry.header, pose=self._odometry.pose)
        self._tf = planar_tf_message(self._odometry.header, self.odom_frame, (0.0, 0.0, 0.0))
        self.create_odometry_subscription(topics.ODOMETRY, self._on_odometry, qos_profile_sensor_data)
        self.create_subscription(BeaconBearingArray, topics.BEARINGS, self._on_bearings, BEARINGS_QOS)
        self.create_subscription(TriangulatedPose, topics.POSE, self._on_total_pose, 10)
        self.create_subscription(PoseWithCovarianceStamped, topics.INITIAL_POSE, self._operator_pose, 10)
        self.create_service(SetPose, topics.SET_POSE, self._on_set_pose)
        self.create_service(Trigger, topics.RESET, self._on_reset)
        self.create_service(Trigger, topics.SAVE_CALIBRATION, self._on_save_calibration)
        serve_calibration_reload(self, self._apply_calibration)
        apply_runtime_changes(self, EKF_PARAMETERS, self.parameters, self._prepare_parameters)
        self._resume_checkpoint()
        self._publish_timer = self.create_timer(1.0 / self.parameters["publish_rate_hz"], self._publish)
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
    def _prepare_parameters(self, values: dict, changed: set[str]) -> ApplyChange:
        """A runtime change (validated by the table): the new beacon geometry (a calibration file read)
        and settings, built now (ValueError, OSError: refused); the process noise and the gate applied
        by the returned step."""
        geometry = runtime_geometry(values, changed, self.geometry)
        settings = filter_settings(values)
        problem = next(filter(None, (b.problem(geometry.beacon_map.ids) for b in settings.blocks if b)), None)
        if problem:
            raise ValueError(problem)
        tolerance = stamp_tolerance_of(values)

        def apply() -> None:
            self.runtime_changes.record(values, changed)
            if geometry is not self.geometry:
                self._flag_worse_calibration(geometry, values["calibration_file"])
            self.geometry, self.settings, self.stamp_check.tolerance = geometry, settings, tolerance
            self.localiser.configure(geometry.beacon_map.as_dict(), geometry.turret_offset_m, settings)
            self.health.configure(values, self._now_s())

        return apply

    def _on_save_calibration(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """The power bias learnt so far as a chapter-7 calibration file (beams_ekf.self_calibration)."""
        path = self.parameters["self_calibration_file"]
        geometry = self.geometry
        try:
            save_self_calibration(self.localiser.ekf, geometry.beacon_map, geometry.turret_offset_m, path)
        except (ValueError, OSError) as error:
            response.success, response.message = False, bounded(f"not saved: {error}")
            return response
        response.success, response.message = True, f"power bias written to {path}"
        return response

    # -- inputs ---------------------------------------------------------------------------------------
    def _on_odometry(self, sample: OdometrySample) -> None:
        now_s = self._now_s()
        self.health.on_odometry(now_s)
        stamp_s = sample.stamp_s
        if self._implausible_stamp("odometry", f"odometry at {stamp_s:.3f} s", stamp_s, now_s):
            return
        outcome = self.localiser.on_odometry(stamp_s, sample.pose)
        if outcome is OdometryOutcome.INVALID:
            self.diagnostics.refuse("odometry_refused", f"odometry at {stamp_s:.3f} s: non-finite pose")
        if outcome is OdometryOutcome.JUMPED:  # counted by the localiser as odometry_jumps
            reason = f"{self.localiser.last_odometry_jump}: re-referenced, covariance grown"
            self.diagnostics.refuse("odometry_jumps_refused", reason)
            self.health.fault("odometry_jump", now_s, reason)
        if outcome.used:
            self._last_odometry_stamp = (stamp_s, Time(sec=sample.sec, nanosec=sample.nanosec))
        if outcome is OdometryOutcome.REFERENCE:  # a time jump resets what was published too
            self._published_stamp_s = None
        if self.localiser.unconfirmed and self.diagnostics.get("status") == Status.TRACKING:
            self._status_now()  # a continuity break (odometry jump or silence, time jump): no longer tracking

    def _on_bearings(self, msg: BeaconBearingArray) -> None:
        now_s = self._now_s()
        self.health.on_bearings(now_s)
        intake = bearings_message_intake(msg, stamp_to_seconds, self.localiser.ekf.beacons_xy)
        if self._implausible_stamp("bearings", f"revolution {msg.revolution}", intake.newest_stamp_s, now_s):
            return  # a bearing applied at the wrong instant is confidently wrong
        self.localiser.on_bearings(intake)  # counts the bearings and revolutions refused, applies those kept
        for key, reason in intake.revolution_refusals():  # the localiser's count, with the reason
            counted = self.localiser.stats.counts[key]
            self.diagnostics.refuse(key, f"revolution {msg.revolution}: {reason}", counted=counted)
        if intake.too_many:  # refused before any per-bearing work
            return
        self._remember_bearings(intake)
        self._changed = True
        # at once: the end-to-end latency from a revolution to the estimate stays small; the timer's next
        # estimate then comes a whole period after this one (at 10 revolutions/s and 20 Hz, 20 estimates a
        # second instead of 30)
        if self._publish():
            self._publish_timer.reset()

    def _on_total_pose(self, msg: TriangulatedPose) -> None:
        if self.settings.use_total_pose and msg.accepted:
            _, outcome = self._take_pose(PoseSource.TOTAL, msg.header, msg.pose)
            if outcome is not None and outcome.taken:
                self._status_now()

    def _status_now(self) -> None:
        """The estimate broke its continuity (or was re-initialised): publish it with its status now, so
        that no 1 Hz report says the old status once the new estimate exists."""
        self._changed = True
        self._publish()

    def _on_set_pose(self, request: SetPose.Request, response: SetPose.Response) -> SetPose.Response:
        response.success, response.message = self._operator_pose(request.pose)
        return response

    def _take_pose(
        self, source: PoseSource, header, pose_with_covariance
    ) -> tuple[PoseIntake, PoseOutcome | None]:
        """A pose message through the pose intake (`beams_common.intake.pose_intake`, as the offline replay's)
        and the localiser's pose door, which counts a refusal (shown here with its reason). None: a ToTal pose
        stamped beyond the tolerance against the node's clock (it would be brought to the filter's instant
        wrongly), refused before the door."""
        stamp_s = stamp_to_seconds(header.stamp)
        frame, beacons = header.frame_id, self.geometry.beacon_map.xy
        intake = pose_message_intake(source, frame, self.map_frame, stamp_s, pose_with_covariance, beacons)
        kept_total = source is PoseSource.TOTAL and isinstance(intake, KeptPose)
        if kept_total and self._implausible_stamp(
            "total_pose", f"ToTal pose at {stamp_s:.3f} s", stamp_s, self._now_s()
        ):
            return intake, None
        outcome = self.localiser.on_pose(intake)
        if isinstance(intake, RefusedPose):
            counted = self.localiser.stats.counts[intake.counter_key]
            self.diagnostics.refuse(intake.counter_key, intake.reason, counted=counted)
        return intake, outcome

    def _operator_pose(self, msg: PoseWithCovarianceStamped) -> tuple[bool, str]:
        """An operator's pose (RViz /initialpose or the set_pose service): (taken, what happened); taken
        only when the filter was initialised from it."""
        intake, what = self._take_pose(PoseSource.OPERATOR, msg.header, msg.pose)
        if isinstance(intake, RefusedPose):
            return False, f"refused: {intake.reason}"
        if what is not PoseOutcome.INITIALISED:
            self.diagnostics.refuse("operator_poses_not_taken", f"the filter did not take it: {what}")
            return False, f"operator pose refused by the filter: {what}"
        self.get_logger().info(f"operator pose: {what}")
        self._changed = True  # published even at the instant of the last publication
        self._publish()
        return True, f"operator pose: {what}"

    def _apply_calibration(self, calibration: SensorCalibration) -> str:
        geometry = geometry_of_calibration(calibration, self.parameters)  # ValueError: refused
        worse = self._flag_worse_calibration(geometry, self.parameters["calibration_file"])
        self.geometry = geometry
        beacon_map, offset = geometry.beacon_map, geometry.turret_offset_m
        self.localiser.configure(beacon_map.as_dict(), offset, self.settings)
        replaced = f"beacons {list(beacon_map.ids)} and turret offset {tuple(offset)} m replaced"
        return f"{replaced}; WARNING: {worse}" if worse else replaced

    def _remember_bearings(self, intake: RevolutionIntake) -> None:
        """Keep the revolution's bearings with the estimate at their instants (a new calibration is
        compared on them)."""
        for bearing in intake.kept:
            pose = self.localiser.pose_at(bearing.stamp_s)
            if pose is not None:
                self.recent_bearings.add(BearingSample(pose, bearing.beacon_id, bearing.bearing_rad))

    def _flag_worse_calibration(self, geometry: BeaconGeometry, path: str) -> str:
        """Why a new geometry makes the recent bearings worse (flagged: WARN on /diagnostics, the status
        degraded for CALIBRATION_FLAG_HOLD_S), or ''. Applied all the same: the estimate the bearings
        are compared with was made under the old geometry, and the NIS test judges the new one (named)."""
        old, new = self.geometry, geometry
        worse = self.recent_bearings.worse_problem(
            (old.beacon_map.as_dict(), old.turret_offset_m), (new.beacon_map.as_dict(), new.turret_offset_m)
        )
        self.recent_bearings.clear()  # the poses kept were estimated under the old geometry
        self.health.calibration_applied(self._now_s(), f"the new beacon geometry (calibration_file {path!r})")
        if worse:
            self.diagnostics.refuse("calibrations_flagged_worse", worse)
            self.health.fault("calibration_worse", self._now_s(), worse, CALIBRATION_FLAG_HOLD_S)
        return worse

    def _on_reset(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.localiser.reset("manual_resets")
        self.health.reset()
        self.recent_bearings.clear()
        self._published_stamp_s = None
        response.success = True
        response.message = "EKF reset: waiting for a pose (beams/pose, ~/set_pose or /initialpose)"
        self.get_logger().info(response.message)
        return response

    # -- outputs --------------------------------------------------------------------------------------
    def _publish(self) -> bool:
        """The estimate with its status; True when a new estimate went out."""
        estimate = self.localiser.estimate()
        self._update_diagnostics(estimate)
        if estimate is None or not math.isfinite(estimate.stamp_s):
            return False
        if estimate.stamp_s == self._published_stamp_s and not self._changed:  # the one published
            return False
        problem = planar_estimate_problem(estimate.pose, estimate.covariance)
        if problem:  # the invariant of every published estimate
            self.diagnostics.refuse("estimates_not_published_invalid", problem, level="error")
            return False
        self._published_stamp_s = estimate.stamp_s
        self._changed = False
        odometry = self._odometry
        odometry.header.stamp = self._stamp_of(estimate)
        set_pose2d(odometry.pose.pose, estimate.pose)
        odometry.pose.covariance = ros_covariance(estimate.covariance)
        # the velocity over the last odometry step the filter took: no input's twist passes through
        odometry.twist.twist.linear.x, odometry.twist.twist.linear.y = estimate.twist[:2]
        odometry.twist.twist.angular.z = estimate.twist[2]
        self.odometry_publisher.publish(odometry)
        self.pose_publisher.publish(self._pose)
        map_to_odom = estimate.map_to_odom
        # tf2 ignores (and logs) a transform at a stamp it holds: a refinement at the same instant (a
        # revolution's bearings, a re-initialisation) goes out with the next odometry's stamp
        if self.tf_publisher is not None and map_to_odom is not None and estimate.stamp_s != self._tf_stamp_s:
            self._tf_stamp_s = estimate.stamp_s
            set_planar_tf(self._tf, map_to_odom)
            self.tf_publisher.publish(self._tf)
        return True

    def _update_diagnostics(self, estimate: Estimate | None) -> None:
        """The status of each estimate (`ekf_health`): its level and message, and `status` (waiting,
        tracking, degraded or lost) as a value of its own; the counters wait for the report
        (`_report_values`)."""
        level, since_s, verdict = self.health.judge(self._now_s(), self.localiser, estimate)
        self._judged = (estimate, since_s)
        stamp = self._stamp_of(estimate) if estimate and math.isfinite(estimate.stamp_s) else None
        self.status_topic.say(verdict, self.health.integrity, level, stamp)

    def _report_values(self) -> None:
        """The counters, rates and the last judged estimate's figures, as /diagnostics is sent."""
        for key, value in self.localiser.stats.counts.items():
            self.diagnostics.set(key, value)
        now_s = self._now_s()
        estimate, since_s = self._judged
        if estimate is not None:
            self.diagnostics.set("covariance_trace", float(np.trace(estimate.covariance)))
            self.diagnostics.set("recent_gated_bearings", self.localiser.kidnap.recent_gated_bearings)
            self.diagnostics.set("lost_nis_window_sum", self.localiser.nis_monitor.window_sum)
            self.diagnostics.set("time_since_last_bearing_s", since_s)
        self.diagnostics.set("bearing_rate_hz", self.health.bearing_rate.rate_hz(now_s))
        self.diagnostics.set("odometry_rate_hz", self.health.odometry_rate.rate_hz(now_s))

    def _stamp_of(self, estimate: Estimate) -> Time:
        """The estimate's header stamp: the odometry's own at its instant (a float loses nanoseconds)."""
        exact = self._last_odometry_stamp
        if exact is not None and exact[0] == estimate.stamp_s:
            return exact[1]
        return seconds_to_stamp(estimate.stamp_s)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(EkfNode, args))


if __name__ == "__main__":
    main()
