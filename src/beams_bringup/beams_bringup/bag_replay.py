"""replay_bag: the triangulation and the EKF (thesis fig. 8.1) over a recorded rosbag2 bag, offline.

    replay_bag INPUT_BAG OUTPUT_BAG [--plot PNG] [--storage mcap|sqlite3] [--start-like-live]
               [--triangulation-params YAML] [--ekf-params YAML]

Reads `beams/bearings`, `odom` and, when present, `beams/sim/ground_truth` (with or without the leading
slash) from a bag (sqlite3 or MCAP, with the `rosbags` library, no ROS graph), feeds them to the same
pure objects the nodes wrap (`gating.TriangulationPipeline` as triangulation_node does,
`localiser.Localiser` as ekf_node does) as fast as the CPU allows, and writes `beams/pose`,
`beams/pose_cov`, `beams/ekf/odometry` and `beams/ekf/pose` next to a copy of the inputs into a new
bag (MCAP by default; topics fully qualified, each with its offered QoS profiles, as `ros2 bag record`
writes them), plus a trajectory plot and a summary (RMS errors against the truth when the bag has it,
agreement with the live nodes' outputs when the bag recorded them).

Time is the messages' stamps, never their arrival: a revolution is due when it ends (header stamp, the
revolution's start, plus its period: when the driver publishes it), odometry and truth at their stamp;
messages are put back in that order within `REORDER_WINDOW_S`. Stamps going back by more than
`TIME_JUMP_S` (a bag played in a loop, a restarted simulation) reset both pipelines. Bad input (NaN,
unknown beacon ids, empty revolutions, undecodable messages) is counted and skipped. Revolutions older
than the bag's first odometry are skipped (a recording starts in the middle of the streams).
The parameters are the nodes' (their installed YAML files by default).
"""

from __future__ import annotations

import argparse
import heapq
import itertools
import math
import pathlib
import sys
import time
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rosbags.rosbag2 import Reader, ReaderError, WriterError

from beams_bringup.bag_io import BagRecorder, beams_typestore, fully_qualified, offered_qos
from beams_bringup.system import installed_params_file
from beams_bringup.trajectory_metrics import RunTracks, Track, plot_trajectories, rms, rms_table
from beams_common.angles import wrap_to_pi
from beams_common.beacon_map import EUROBOT_BEACON_MAP, BeaconMap
from beams_common.geometry_parameters import geometry_of
from beams_common.parameters import ROS_NODE_PARAMETERS, ParameterTable, load_parameter_file
from beams_common.pose2d import Pose2D, is_finite_pose
from beams_common.ros.messages import (
    planar_covariance,
    pose2d_of,
    ros_covariance,
    seconds_to_stamp,
    stamp_to_seconds,
)
from beams_common.time_jumps import StampOrder, TimeJumpDetector
from beams_ekf import localiser as ekf_inputs
from beams_ekf.localiser import Estimate, FilterSettings, build_localiser, filter_settings
from beams_ekf.parameters import EKF_PARAMETERS
from beams_triangulation import gating
from beams_triangulation.gating import (
    NoPose,
    PoseEstimate,
    RevolutionPose,
    TriangulationPipeline,
    TriangulationSettings,
)
from beams_triangulation.motion_compensation import ODOMETRY_TIME_JUMP_S
from beams_triangulation.parameters import TRIANGULATION_PARAMETERS, triangulation_settings

BEARINGS_TOPIC = "beams/bearings"
ODOMETRY_TOPIC = "odom"
TRUTH_TOPIC = "beams/sim/ground_truth"
# Outputs of the live nodes, when the bag recorded them: what the replay is compared with.
LIVE_POSE_TOPIC = "beams/pose"
LIVE_EKF_TOPIC = "beams/ekf/odometry"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
BEARINGS_TYPE = "beams_msgs/msg/BeaconBearingArray"
POSE_TYPE = "beams_msgs/msg/TriangulatedPose"
POSE_COV_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
# Processing order of messages due at the same instant: odometry first, so it covers the bearings.
_TOPIC_ORDER = {TRUTH_TOPIC: 0, ODOMETRY_TOPIC: 1, BEARINGS_TOPIC: 2}
_TOPIC_TYPES = {TRUTH_TOPIC: ODOMETRY_TYPE, ODOMETRY_TOPIC: ODOMETRY_TYPE, BEARINGS_TOPIC: BEARINGS_TYPE}
# The live nodes publish every topic the replay writes reliable, volatile, keep last 10 (driver_node's
# BEARINGS_QOS, sim_world_node's QUEUE_DEPTH, the others' depth 10): the bag says so, as ros2 bag record's do.
NODES_QOS = offered_qos(10)
# How far (s) a message may arrive after a later-stamped one and still be put back in stamp order.
REORDER_WINDOW_S = 1.0
# Stamps going back by more than this (s) are a new start (a bag loop): both pipelines reset.
TIME_JUMP_S = ODOMETRY_TIME_JUMP_S
_NS = 1_000_000_000


# -- settings -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReplaySettings:
    """What the two nodes take from their parameters (defaults: the nodes' defaults)."""

    triangulation_map: BeaconMap = EUROBOT_BEACON_MAP
    triangulation_offset_m: tuple[float, float] = (0.0, 0.0)
    triangulation: TriangulationSettings = field(default_factory=TriangulationSettings)
    ekf_map: BeaconMap = EUROBOT_BEACON_MAP
    ekf_offset_m: tuple[float, float] = (0.0, 0.0)
    ekf: FilterSettings = field(default_factory=FilterSettings)


def load_node_parameters(path: pathlib.Path | None, table: ParameterTable) -> dict[str, Any]:
    """The parameters a ROS parameter file gives the table's node, validated exactly as the node validates
    them (ParameterError naming the parameter otherwise); the node's defaults for None."""
    return table.validate({}) if path is None else load_parameter_file(path, table)


def settings_from_parameters(triangulation: Mapping[str, Any], ekf: Mapping[str, Any]) -> ReplaySettings:
    """Settings from the two nodes' parameter values by name (a missing one takes its default), validated
    by the nodes' own tables and mapped by the functions the nodes use."""
    triangulation = TRIANGULATION_PARAMETERS.validate(triangulation, ignore=ROS_NODE_PARAMETERS)
    ekf = EKF_PARAMETERS.validate(ekf, ignore=ROS_NODE_PARAMETERS)
    tri_geometry, ekf_geometry = geometry_of(triangulation), geometry_of(ekf)
    return ReplaySettings(
        triangulation_map=tri_geometry.beacon_map,
        triangulation_offset_m=tri_geometry.turret_offset_m,
        triangulation=triangulation_settings(triangulation),
        ekf_map=ekf_geometry.beacon_map,
        ekf_offset_m=ekf_geometry.turret_offset_m,
        ekf=filter_settings(ekf),
    )


# -- message time ---------------------------------------------------------------------------------------
def stamp_ns(stamp: Any) -> int:
    """builtin_interfaces/Time in integer nanoseconds (exact, for ordering and matching)."""
    return int(stamp.sec) * _NS + int(stamp.nanosec)


def due_ns(topic: str, message: Any) -> int:
    """When a message is due (ns): a revolution when it ends (start + period), the others at their stamp."""
    start_ns = stamp_ns(message.header.stamp)
    if topic != BEARINGS_TOPIC:
        return start_ns
    period_s = float(message.period)
    # a revolution with a nonsense period is due at its start: its bearings wait for odometry anyway
    return start_ns + (round(period_s * 1e9) if math.isfinite(period_s) and 0.0 <= period_s <= 1.0 else 0)


@dataclass(order=True)
class Event:
    """One input message, ordered by (due instant, topic order, position in the bag)."""

    due_ns: int
    topic_order: int
    sequence: int
    topic: str = field(compare=False)
    bag_ns: int = field(compare=False)
    msgtype: str = field(compare=False)
    raw: bytes = field(compare=False, repr=False)
    message: Any = field(compare=False, repr=False)
    # the profiles its publishers offered, as the bag recorded them (none in older bags)
    offered_qos: tuple = field(compare=False, repr=False, default=())


# Marker yielded by `in_stamp_order` where the stamps went back: the pipelines start over.
TIME_JUMP = None


def in_stamp_order(
    events: Iterable[Event],
    window_ns: int = round(REORDER_WINDOW_S * _NS),
    jump_ns: int = round(TIME_JUMP_S * _NS),
) -> Iterator[Event | None]:
    """Events by due instant within a reorder window; TIME_JUMP where the stamps go back by > jump_ns
    in two consecutive messages (a bag loop; one stray message is not: `beams_common.time_jumps`).

    A message later than the window is passed on late (the pipelines drop or absorb it as the nodes do).
    """
    pending: list[Event] = []
    newest_ns: int | None = None
    time_jumps = TimeJumpDetector(jump_ns * 1e-9)
    for event in events:
        order = time_jumps.classify(event.due_ns * 1e-9, None if newest_ns is None else newest_ns * 1e-9)
        if order is StampOrder.JUMP:
            while pending:
                yield heapq.heappop(pending)
            yield TIME_JUMP
            newest_ns = None
        newest_ns = event.due_ns if newest_ns is None else max(newest_ns, event.due_ns)
        heapq.heappush(pending, event)
        while pending and pending[0].due_ns < newest_ns - window_ns:
            yield heapq.heappop(pending)
    while pending:
        yield heapq.heappop(pending)


def relative_topic(topic: str, namespace: str = "") -> str | None:
    """A bag topic's name relative to a robot's namespace, leading slash removed ("/robot1/odom" is "odom"
    in namespace "robot1"); None for a topic outside the namespace."""
    name, prefix = topic.lstrip("/"), namespace.strip("/")
    if not prefix:
        return name
    return name[len(prefix) + 1 :] if name.startswith(prefix + "/") else None


def namespaced_topic(topic: str, namespace: str = "") -> str:
    """The fully qualified bag topic of a name relative to a robot's namespace (`relative_topic`'s
    inverse): "/robot1/odom", or "/odom" without a namespace."""
    prefix = namespace.strip("/")
    return fully_qualified(f"{prefix}/{topic}" if prefix else topic)


def bag_topics(path: pathlib.Path, namespace: str = "") -> set[str]:
    """The topics of a bag inside a robot's namespace, relative to it (`relative_topic`)."""
    with Reader(pathlib.Path(path)) as reader:
        return {name for c in reader.connections if (name := relative_topic(c.topic, namespace)) is not None}


def read_events(path: pathlib.Path, typestore: Any, counts: Counter, namespace: str = "") -> Iterator[Event]:
    """The input messages of a bag (of a robot's namespace) in bag order, topics relative to the namespace;
    undecodable ones are counted and skipped."""
    sequence = itertools.count()
    with Reader(path) as reader:
        connections = [c for c in reader.connections if relative_topic(c.topic, namespace) in _TOPIC_ORDER]
        wrong_type = [c for c in connections if c.msgtype != _TOPIC_TYPES[relative_topic(c.topic, namespace)]]
        if wrong_type:
            counts["messages_wrong_type"] += sum(c.msgcount for c in wrong_type)
        connections = [c for c in connections if c not in wrong_type]
        # rosbags reads every connection when given none
        for connection, bag_ns, raw in reader.messages(connections=connections) if connections else ():
            topic = relative_topic(connection.topic, namespace)
            try:
                message = typestore.deserialize_cdr(raw, connection.msgtype)
                due = due_ns(topic, message)
            except Exception:  # any corrupt message is bad input, never a crash
                counts["messages_undecodable"] += 1
                continue
            counts[f"messages_{topic}"] += 1
            yield Event(
                due,
                _TOPIC_ORDER[topic],
                next(sequence),
                topic,
                bag_ns,
                connection.msgtype,
                raw,
                message,
                tuple(getattr(connection.ext, "offered_qos_profiles", ())),
            )


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
        self.localiser.reset("time_jump_resets")

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
        if start is not None and outcome in ("reference", "predicted"):
            self.localiser.on_pose(stamp_s, start.pose, start.covariance, operator=True)
            self.live_start = None
        estimate = self.localiser.estimate()
        poses = self._total_poses(completed)  # after the odometry, as ekf_node receives them
        if outcome not in ("reference", "predicted") or estimate is None or estimate.stamp_s != stamp_s:
            return None, poses
        return estimate, poses

    def on_bearings(self, message: Any) -> list[RevolutionPose]:
        """One revolution to ToTal and every bearing to the EKF; the revolutions ToTal completed (this one,
        unless it waits for odometry, and the one that waited), their accepted poses offered to the EKF.

        A revolution older than the first odometry of a bag that has odometry is skipped: a bag starts in
        the middle of the streams, a case the nodes (started together) never meet.
        """
        first_odometry = self.first_odometry_s
        if self.expect_odometry and (
            first_odometry is None or stamp_to_seconds(message.header.stamp) < first_odometry
        ):
            self.counts["revolutions_before_odometry"] += 1
            return []
        self.counts["revolutions"] += 1
        self.counts["bearings"] += len(message.bearings)
        completed = self.triangulation.on_revolution(None, gating.message_bearings(message, stamp_to_seconds))
        self.localiser.on_revolution(ekf_inputs.message_bearings(message, stamp_to_seconds))
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
                self.localiser.offer_pose(
                    message_stamp_s,
                    (result.x, result.y, result.heading),
                    result.covariance,
                    self.settings.ekf.default_pose_covariance,
                    operator=False,
                )
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


# -- output messages ------------------------------------------------------------------------------------
class MessageBuilder:
    """rosbags message objects: the replay's outputs, and inputs made from the offline simulator."""

    def __init__(self, typestore: Any) -> None:
        self.types = typestore.types

    def header(self, stamp: int, frame_id: str) -> Any:
        time_type = self.types["builtin_interfaces/msg/Time"]
        return self.types["std_msgs/msg/Header"](
            stamp=time_type(sec=stamp // _NS, nanosec=stamp % _NS), frame_id=frame_id
        )

    def pose_with_covariance(self, pose: Pose2D, covariance_6x6: np.ndarray) -> Any:
        t = self.types
        geometry = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](
                x=0.0, y=0.0, z=math.sin(0.5 * pose[2]), w=math.cos(0.5 * pose[2])
            ),
        )
        return t["geometry_msgs/msg/PoseWithCovariance"](
            pose=geometry, covariance=covariance_6x6.ravel().astype(float)
        )

    def odometry(
        self, stamp: int, frame_id: str, pose: Pose2D, speed_mps: float, yaw_rate_radps: float
    ) -> Any:
        """nav_msgs/Odometry (to base_link) with a planar pose and twist, covariances zero."""
        t = self.types
        linear = t["geometry_msgs/msg/Vector3"](x=float(speed_mps), y=0.0, z=0.0)
        angular = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=float(yaw_rate_radps))
        twist = t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=linear, angular=angular), covariance=np.zeros(36)
        )
        return t[ODOMETRY_TYPE](
            header=self.header(stamp, frame_id),
            child_frame_id="base_link",
            pose=self.pose_with_covariance(pose, np.zeros((6, 6))),
            twist=twist,
        )

    def bearing_array(
        self,
        start: int,
        period_s: float,
        bearings: Iterable[tuple[int, int, float, float] | tuple[int, int, float, float, float]],
        revolution: int,
        frame_id: str = "beams_sensor",
    ) -> Any:
        """beams_msgs/BeaconBearingArray from (stamp ns, beacon id, bearing rad, variance rad^2) tuples,
        optionally followed by the angular window (rad; 0 without it)."""
        bearing_type = self.types["beams_msgs/msg/BeaconBearing"]
        items = [
            bearing_type(
                header=self.header(stamp, frame_id),
                beacon_id=int(beacon),
                bearing=float(angle),
                variance=float(variance),
                angular_window=float(window[0]) if window else 0.0,
                rising_angle=0.0,
                falling_angle=0.0,
                codes_seen=1,
            )
            for stamp, beacon, angle, variance, *window in bearings
        ]
        return self.types[BEARINGS_TYPE](
            header=self.header(start, frame_id),
            revolution=revolution % 2**32,
            period=float(period_s),
            bearings=items,
            rejected_windows=0,
        )

    def triangulated_pose(self, estimate: PoseEstimate, stamp: int, frame_id: str) -> Any:
        full = np.asarray(ros_covariance(estimate.covariance))
        return self.types[POSE_TYPE](
            header=self.header(stamp, frame_id),
            pose=self.pose_with_covariance((estimate.x, estimate.y, estimate.heading), full),
            inverse_abs_d=float(estimate.inverse_abs_d),
            beacon_ids=np.array(estimate.beacon_ids, dtype=np.uint16),
            accepted=bool(estimate.accepted),
            reason=estimate.reason,
        )

    def ekf_odometry(self, estimate: Estimate, stamp: int, odometry: Any, frame_id: str) -> Any:
        full = np.asarray(ros_covariance(estimate.covariance))
        return self.types[ODOMETRY_TYPE](
            header=self.header(stamp, frame_id),
            child_frame_id=odometry.child_frame_id or "base_link",
            pose=self.pose_with_covariance(estimate.pose, full),
            twist=odometry.twist,
        )

    def stamped(self, header: Any, pose: Any) -> Any:
        return self.types[POSE_COV_TYPE](header=header, pose=pose)


# -- bags from the offline simulator --------------------------------------------------------------------
# (when the live system would publish it (ns), topic, ROS type, rosbags message or raw CDR bytes)
BagMessage = tuple[int, str, str, Any]


def simulated_messages(match: Any, typestore: Any, epoch_ns: int = 0) -> list[BagMessage]:
    """The input topics of a `beams_sim.simulated_match.SimulatedMatch`, stamped epoch_ns + match time:
    truth and odometry at their stamps, each revolution when it ends (as driver_node publishes it).
    Topics are fully qualified ("/odom"), as `ros2 bag record` names them."""
    build = MessageBuilder(typestore)
    g, o = match.ground_truth, match.odometry
    messages: list[BagMessage] = []
    for k, t in enumerate(o.stamp_s):
        stamp = epoch_ns + round(t * 1e9)
        truth = (g.x_m[k], g.y_m[k], g.theta_rad[k])
        messages.append(
            (
                stamp,
                fully_qualified(TRUTH_TOPIC),
                ODOMETRY_TYPE,
                build.odometry(stamp, "map", truth, g.speed_mps[k], g.yaw_rate_radps[k]),
            )
        )
        messages.append(
            (
                stamp,
                fully_qualified(ODOMETRY_TOPIC),
                ODOMETRY_TYPE,
                build.odometry(stamp, "odom", o.pose(k), o.speed_mps[k], o.yaw_rate_radps[k]),
            )
        )
    for r in match.revolutions:
        start = epoch_ns + round(r.start_time_s * 1e9)
        bearings = [
            (epoch_ns + round(b.stamp_s * 1e9), b.beacon_id, b.bearing, b.variance, b.angular_window)
            for b in r.bearings
        ]
        messages.append(
            (
                start + round(r.period_s * 1e9),
                fully_qualified(BEARINGS_TOPIC),
                BEARINGS_TYPE,
                build.bearing_array(start, r.period_s, bearings, r.revolution),
            )
        )
    return messages


def write_bag(
    path: pathlib.Path,
    messages: Iterable[BagMessage],
    typestore: Any,
    *,
    storage: str = "mcap",
    passes: int = 1,
    pass_period_ns: int = 0,
    jitter_s: float = 0.0,
    seed: int = 0,
) -> pathlib.Path:
    """A bag of the messages, recorded when published plus a random delivery delay in [0, jitter_s) (so
    that bag order is not stamp order); passes > 1 records them again pass_period_ns later each time
    with the same stamps (a bag played in a loop). Topic names are written as given; each topic
    carries the nodes' offered QoS profile (NODES_QOS)."""
    rng = np.random.default_rng(seed)
    records = []
    for n in range(passes):
        for published, topic, msgtype, message in messages:
            raw = message if isinstance(message, bytes) else typestore.serialize_cdr(message, msgtype)
            arrival = published + n * pass_period_ns + round(jitter_s * rng.random() * 1e9)
            records.append((arrival, topic, msgtype, raw))
    records.sort(key=lambda record: record[0])
    with BagRecorder(pathlib.Path(path), typestore, storage) as recorder:
        for arrival, topic, msgtype, raw in records:
            recorder.write(topic, msgtype, arrival, raw, [NODES_QOS])
    return pathlib.Path(path)


# -- the replay -----------------------------------------------------------------------------------------
@dataclass
class _Run:
    """The state of one replay: pipelines, output bag and result."""

    pipelines: ReplayPipelines
    recorder: BagRecorder
    build: MessageBuilder
    typestore: Any
    map_frame: str
    # the robot's namespace: the output topics are in it, as the inputs were
    namespace: str = ""
    result: ReplayResult = field(default_factory=ReplayResult)
    segment: int = 0

    def write(self, topic: str, msgtype: str, stamp: int, message: Any) -> None:
        self.recorder.write(
            namespaced_topic(topic, self.namespace),
            msgtype,
            stamp,
            self.typestore.serialize_cdr(message, msgtype),
            [NODES_QOS],
        )
        self.result.messages_out += 1

    def handle(self, event: Event) -> None:
        topic = namespaced_topic(event.topic, self.namespace)
        # the inputs, unchanged, with their recorded QoS (the nodes' for an older bag without)
        self.recorder.write(topic, event.msgtype, event.bag_ns, event.raw, event.offered_qos or [NODES_QOS])
        self.result.messages_out += 1
        stamp, message = stamp_ns(event.message.header.stamp), event.message
        if event.topic == TRUTH_TOPIC:
            self.result.truth.add(self.segment, stamp, pose2d_of(message.pose.pose))
        elif event.topic == ODOMETRY_TOPIC:
            self.result.odometry.add(self.segment, stamp, pose2d_of(message.pose.pose))
            estimate, poses = self.pipelines.on_odometry(message)
            if estimate is not None:
                self._write_ekf(estimate, stamp, message)
            self.write_total(poses, event.due_ns)
        else:
            self.write_total(self.pipelines.on_bearings(message), event.due_ns)

    def write_total(self, poses: list[RevolutionPose], due: int) -> None:
        """ToTal's poses (those of a revolution that gave none are not published)."""
        for outcome in poses:
            if isinstance(outcome.result, PoseEstimate):
                self._write_total(outcome.result, outcome.stamp_s, due)

    def _write_ekf(self, estimate: Estimate, stamp: int, odometry: Any) -> None:
        self.result.ekf.add(self.segment, stamp, estimate.pose)
        message = self.build.ekf_odometry(estimate, stamp, odometry, self.map_frame)
        self.write(LIVE_EKF_TOPIC, ODOMETRY_TYPE, stamp, message)
        self.write("beams/ekf/pose", POSE_COV_TYPE, stamp, self.build.stamped(message.header, message.pose))

    def _write_total(self, estimate: PoseEstimate, stamp_s: float, due: int) -> None:
        stamp = round(stamp_s * 1e9)  # triangulation_node's time_message rounding
        message = self.build.triangulated_pose(estimate, stamp, self.map_frame)
        self.write(LIVE_POSE_TOPIC, POSE_TYPE, due, message)
        if estimate.accepted:
            self.result.total.add(self.segment, stamp, (estimate.x, estimate.y, estimate.heading))
            self.write("beams/pose_cov", POSE_COV_TYPE, due, self.build.stamped(message.header, message.pose))


def replay_bag(
    input_bag: pathlib.Path,
    output_bag: pathlib.Path,
    settings: ReplaySettings | None = None,
    *,
    typestore: Any = None,
    storage: str = "mcap",
    map_frame: str = "map",
    start_like_live: bool = False,
    namespace: str = "",
) -> ReplayResult:
    """Replay a bag through both pipelines and write the outputs (with the inputs) to a new bag.

    namespace: the robot whose topics are replayed (a bag of several robots: one replay each); its
    outputs are written in the same namespace.

    start_like_live: the EKF starts from the live EKF's first recorded estimate at an odometry stamp of
    the bag (`LiveStart`) instead of ToTal's first pose, to compare the replay with a live run whose start
    the bag did not record.
    """
    typestore = typestore if typestore is not None else beams_typestore()
    pipelines = ReplayPipelines(settings or ReplaySettings())
    use_odometry = pipelines.settings.triangulation.use_odometry
    pipelines.expect_odometry = use_odometry and ODOMETRY_TOPIC in bag_topics(input_bag, namespace)
    if start_like_live:
        pipelines.live_start = live_estimates(input_bag, typestore, namespace)
        if not pipelines.live_start:
            raise ValueError(f"{input_bag} has no {LIVE_EKF_TOPIC} message to start from")
    started = time.perf_counter()
    last_ns: int | None = None
    with BagRecorder(pathlib.Path(output_bag), typestore, storage) as recorder:
        run = _Run(pipelines, recorder, MessageBuilder(typestore), typestore, map_frame, namespace)
        events = read_events(pathlib.Path(input_bag), typestore, run.result.counts, namespace)
        for event in in_stamp_order(events):
            if event is TIME_JUMP:
                run.write_total(pipelines.flush(), last_ns)
                run.segment += 1
                pipelines.reset()
                continue
            run.result.messages_in += 1
            run.result.span_s += 0.0 if last_ns is None else max(0.0, (event.due_ns - last_ns) * 1e-9)
            last_ns = event.due_ns
            run.handle(event)
        run.write_total(pipelines.flush(), last_ns)
    result = run.result
    result.wall_s = time.perf_counter() - started
    result.counts.update(pipelines.counts)
    result.counts.update({f"ekf_{k}": v for k, v in pipelines.localiser.stats.counts.items()})
    return result


# -- figures --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Agreement:
    """Replayed against live poses at the same stamps (after `settle_s` from the first common stamp)."""

    matched: int
    max_position_m: float
    max_heading_rad: float
    rms_position_m: float


def agreement(replayed: Track, live: Track, settle_s: float = 0.0) -> Agreement:
    """Differences of two tracks at their common stamps (exact ns), from settle_s after the first one."""
    live_poses = live.by_stamp()
    pairs = sorted((t, pose, live_poses[t]) for t, pose in replayed.by_stamp().items() if t in live_poses)
    if pairs:
        start = pairs[0][0] + round(settle_s * _NS)
        pairs = [p for p in pairs if p[0] >= start]
    if not pairs:
        return Agreement(0, math.nan, math.nan, math.nan)
    position = np.array([math.hypot(a[0] - b[0], a[1] - b[1]) for _, a, b in pairs])
    heading = np.array([abs(wrap_to_pi(a[2] - b[2])) for _, a, b in pairs])
    return Agreement(len(pairs), float(position.max()), float(heading.max()), rms(position))


def live_tracks(input_bag: pathlib.Path, typestore: Any, namespace: str = "") -> tuple[Track, Track]:
    """(accepted ToTal poses, EKF estimates) the live nodes (of a robot's namespace) published, as recorded
    in the bag."""
    total, ekf = Track(), Track()
    live_topics = (LIVE_POSE_TOPIC, LIVE_EKF_TOPIC)
    with Reader(pathlib.Path(input_bag)) as reader:
        wanted = [c for c in reader.connections if relative_topic(c.topic, namespace) in live_topics]
        for connection, _, raw in reader.messages(connections=wanted) if wanted else ():
            message = typestore.deserialize_cdr(raw, connection.msgtype)
            stamp = stamp_ns(message.header.stamp)
            if relative_topic(connection.topic, namespace) == LIVE_EKF_TOPIC:
                ekf.add(0, stamp, pose2d_of(message.pose.pose))
            elif message.accepted:
                total.add(0, stamp, pose2d_of(message.pose.pose))
    return total, ekf


def summary(result: ReplayResult, live: tuple[Track, Track] | None = None) -> str:
    """The summary table: RMS errors against the truth, counts, speed, agreement with the live nodes."""
    tracks = result.in_map("ekf")  # dead reckoning from the EKF's first estimate
    truth = tracks["truth"]
    lines = []
    if len(truth):
        names = (
            ("odometry (from the first EKF pose)", "odometry"),
            ("ToTal (accepted)", "ToTal"),
            ("EKF", "EKF"),
        )
        lines += rms_table(((label, tracks[name]) for label, name in names), truth)
        lines.append("")
    lines.append(", ".join(f"{key} {value}" for key, value in sorted(result.counts.items())))
    lines.append(
        f"{result.messages_in} messages in {result.wall_s:.2f} s: {result.messages_per_s:.0f} "
        f"messages/s, {result.real_time_factor:.1f} x real time; {result.messages_out} written"
    )
    if live is not None:
        for name, replayed, recorded in (("ToTal", result.total, live[0]), ("EKF", result.ekf, live[1])):
            a = agreement(replayed, recorded)
            if a.matched:
                lines.append(
                    f"replayed {name} vs live at {a.matched} common stamps: max "
                    f"{1000 * a.max_position_m:.2f} mm, {math.degrees(a.max_heading_rad):.3f} deg "
                    f"(RMS {1000 * a.rms_position_m:.2f} mm)"
                )
    return "\n".join(lines)


def plot(result: ReplayResult, path: pathlib.Path) -> None:
    """Trajectories in the map frame: truth, odometry (dead reckoning), ToTal and the EKF."""
    plot_trajectories(result.in_map("ekf"), path, "BeAMS bag replay")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="replay_bag", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("input_bag", type=pathlib.Path, help="rosbag2 directory (sqlite3 or MCAP)")
    parser.add_argument("output_bag", type=pathlib.Path, help="new bag directory (must not exist)")
    parser.add_argument("--plot", type=pathlib.Path, help="trajectory plot (PNG)")
    parser.add_argument(
        "--start-like-live",
        action="store_true",
        help="start the EKF from the live EKF's first estimate recorded in the bag (to "
        "compare with the live run) instead of ToTal's first pose",
    )
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="output storage")
    parser.add_argument(
        "--namespace",
        default="",
        help="the robot whose topics to replay (e.g. robot1 for /robot1/odom, ...); "
        "default: the topics without a namespace",
    )
    parser.add_argument(
        "--params-file",
        type=pathlib.Path,
        default=installed_params_file(),
        help="ROS parameter file with triangulation_node and ekf_node sections, validated as "
        "the nodes validate it (default: beams_bringup's beams_params.yaml)",
    )
    options = parser.parse_args(argv)
    try:
        settings = settings_from_parameters(
            load_node_parameters(options.params_file, TRIANGULATION_PARAMETERS),
            load_node_parameters(options.params_file, EKF_PARAMETERS),
        )
        typestore = beams_typestore()
        result = replay_bag(
            options.input_bag,
            options.output_bag,
            settings,
            typestore=typestore,
            storage=options.storage,
            start_like_live=options.start_like_live,
            namespace=options.namespace,
        )
        live = live_tracks(options.input_bag, typestore, options.namespace)
    except (OSError, ValueError, ReaderError, WriterError) as error:
        print(f"replay_bag: {error}", file=sys.stderr)
        return 2
    if options.plot:
        plot(result, options.plot)
    print(summary(result, live))
    print(f"bag: {options.output_bag}" + (f"; plot: {options.plot}" if options.plot else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
