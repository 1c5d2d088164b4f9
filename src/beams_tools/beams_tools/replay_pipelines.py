"""The two nodes' pipelines fed with a bag's events (ToTal as triangulation_node runs it, the Localiser
as ekf_node runs it), and what they produced."""

from __future__ import annotations

import math
import pathlib
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rosbags.rosbag2 import Reader

from beams_common.geometry.pose2d import Pose2D, is_finite_pose
from beams_common.intake.bearing_intake import bearings_message_intake
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake
from beams_common.ros.messages import planar_covariance, pose2d_of, seconds_to_stamp, stamp_to_seconds
from beams_common.status.health import Verdict
from beams_common.status.protection_level import ProtectionLevel
from beams_ekf.ekf_health import EkfHealth
from beams_ekf.localiser import build_localiser
from beams_ekf.outcomes import Estimate
from beams_tools.bag_events import LIVE_EKF_TOPIC, relative_topic, stamp_ns
from beams_tools.replay_settings import ReplaySettings
from beams_tools.trajectory_metrics import RunTracks
from beams_triangulation.gating import NoPose, PoseEstimate
from beams_triangulation.pipeline import TriangulationPipeline
from beams_triangulation.revolution import RevolutionPose


# -- the pipelines --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LiveStart:
    """A live EKF estimate recorded in the bag: the replay's EKF can start from it at the odometry of the
    same stamp (ToTal's poses are not offered before), so that replay and live share the initial state."""

    pose: Pose2D
    covariance: np.ndarray


def live_estimates(input_bag: pathlib.Path, typestore: Any, namespace: str = "") -> dict[int, LiveStart]:
    """The live EKF's estimates (beams/ekf/odometry) of a bag by stamp (ns), each stamped exactly with the
    odometry message it followed."""
    estimates = {}
    with Reader(pathlib.Path(input_bag)) as reader:
        wanted = [c for c in reader.connections if relative_topic(c.topic, namespace) == LIVE_EKF_TOPIC]
        for connection, _, raw in reader.messages(connections=wanted) if wanted else ():
            message = typestore.deserialize_cdr(raw, connection.msgtype)
            estimates[stamp_ns(message.header.stamp)] = LiveStart(
                pose2d_of(message.pose.pose), planar_covariance(message.pose.covariance)
            )
    return estimates


class ReplayPipelines:
    """triangulation_node's and ekf_node's message handling, without ROS: one call per input message."""

    def __init__(self, settings: ReplaySettings) -> None:
        self.settings = settings
        self.localiser = build_localiser(settings.ekf_map.as_dict(), settings.ekf_offset_m, settings.ekf)
        self.counts: Counter = Counter()
        # set when the bag has odometry: revolutions before the first odometry are then skipped
        self.expect_odometry = False
        self.first_odometry_s: float | None = None
        # live EKF estimates by stamp: the EKF starts from the first one at an odometry stamp of the bag
        self.live_start: dict[int, LiveStart] | None = None
        # ekf_node's status of each estimate; its receiving clock is the newest stamp so far (a replay has
        # no other, and a stray message stamped in the past does not turn it back)
        self.health: EkfHealth | None = None
        self.clock_s = -math.inf
        self.judgement: tuple[ProtectionLevel | None, Verdict] | None = None
        self._new_triangulation()

    def _new_triangulation(self) -> None:
        s = self.settings
        self.triangulation = TriangulationPipeline(
            s.triangulation_map, s.triangulation, s.triangulation_offset_m
        )

    def reset(self) -> None:
        """A time jump: both pipelines start over (the EKF waits for a pose again); `flush` first."""
        self._new_triangulation()
        self.first_odometry_s = None
        self.health, self.clock_s = None, -math.inf
        self.localiser.reset("time_jump_resets", forget_learnt=True)

    def flush(self) -> list[RevolutionPose]:
        """The revolution ToTal still waits odometry for, estimated now (the streams ended or jumped)."""
        return self._total_poses(self.triangulation.flush())

    def on_odometry(self, message: Any) -> tuple[Estimate | None, list[RevolutionPose]]:
        """Odometry to both pipelines: the EKF estimate at this odometry's instant (None before a pose)
        and the revolutions ToTal completed (those that waited for this odometry)."""
        stamp_s, pose = stamp_to_seconds(message.header.stamp), pose2d_of(message.pose.pose)
        if self.first_odometry_s is None and is_finite_pose(pose):
            self.first_odometry_s = stamp_s
        twist = (message.twist.twist.linear.x, message.twist.twist.angular.z)
        completed = self.triangulation.on_odometry(stamp_s, pose, twist)
        outcome = self.localiser.on_odometry(stamp_s, pose)
        start = None if self.live_start is None else self.live_start.get(stamp_ns(message.header.stamp))
        if start is not None and outcome.used:
            self.localiser.on_pose(
                planar_pose_intake(PoseSource.OPERATOR, stamp_s, start.pose, start.covariance)
            )
            self.live_start = None
        now_s = self._received(stamp_s)
        self.health.on_odometry(now_s)
        estimate = self.localiser.estimate()
        poses = self._total_poses(completed)  # after the odometry, as ekf_node receives them
        if not outcome.used or estimate is None or estimate.stamp_s != stamp_s:
            return None, poses
        level, _, verdict = self.health.judge(now_s, self.localiser, estimate)
        self.judgement = (level, verdict)
        return estimate, poses

    def _received(self, stamp_s: float) -> float:
        """The receiving clock at a message of this stamp; ekf_node's status starts with the first."""
        self.clock_s = max(self.clock_s, stamp_s)
        if self.health is None:
            self.health = EkfHealth(self.settings.ekf_values, self.clock_s)
        return self.clock_s

    def on_bearings(self, message: Any) -> list[RevolutionPose]:
        """One revolution to ToTal and every bearing to the EKF; the revolutions ToTal completed, their
        accepted poses offered to the EKF. A revolution older than the bag's first odometry is skipped: a bag
        starts in the middle of the streams, which the nodes, started together, never meet."""
        first_odometry = self.first_odometry_s
        if self.expect_odometry and (
            first_odometry is None or stamp_to_seconds(message.header.stamp) < first_odometry
        ):
            self.counts["revolutions_before_odometry"] += 1
            return []
        self.counts["revolutions"] += 1
        self.counts["bearings"] += len(message.bearings)
        now_s = self._received(stamp_to_seconds(message.header.stamp))  # before self.health: it may make it
        self.health.on_bearings(now_s)
        # each node's intake, with its own beacon map, as the nodes take beams/bearings
        known_ids = self.triangulation.estimator.known_ids
        completed = self.triangulation.on_intake(
            None, bearings_message_intake(message, stamp_to_seconds, known_ids)
        )
        self.localiser.on_bearings(
            bearings_message_intake(message, stamp_to_seconds, self.localiser.ekf.beacons_xy)
        )
        return self._total_poses(completed)

    def _total_poses(self, completed: list[tuple[Any, RevolutionPose]]) -> list[RevolutionPose]:
        """Count ToTal's outcomes and offer its accepted poses to the EKF (as ekf_node takes beams/pose)."""
        for _, outcome in completed:
            result = outcome.result
            self._count_total(result)
            offer = self.settings.ekf.use_total_pose and self.live_start is None
            if offer and isinstance(result, PoseEstimate) and result.accepted:
                # ekf_node reads the stamp from the message, rounded to nanoseconds
                message_stamp_s = stamp_to_seconds(seconds_to_stamp(outcome.stamp_s))
                pose = (result.x, result.y, result.heading)
                intake = planar_pose_intake(PoseSource.TOTAL, message_stamp_s, pose, result.covariance)
                self.localiser.on_pose(intake)
        return [outcome for _, outcome in completed]

    def _count_total(self, result: PoseEstimate | NoPose) -> None:
        if isinstance(result, NoPose):
            self.counts["total_bad_input" if result.bad_input else "total_no_pose"] += 1
        else:
            self.counts["total_accepted" if result.accepted else "total_rejected"] += 1


# -- results --------------------------------------------------------------------------------------------
@dataclass
class ReplayResult(RunTracks):
    """What a replay produced: the tracks, the counts and how fast it ran."""

    counts: Counter = field(default_factory=Counter)
    messages_in: int = 0
    messages_out: int = 0
    wall_s: float = 0.0
    span_s: float = 0.0

    @property
    def messages_per_s(self) -> float:
        return self.messages_in / self.wall_s if self.wall_s > 0 else math.inf

    @property
    def real_time_factor(self) -> float:
        """Stamp span of the bag over the replay's wall time (x real time)."""
        return self.span_s / self.wall_s if self.wall_s > 0 else math.inf
