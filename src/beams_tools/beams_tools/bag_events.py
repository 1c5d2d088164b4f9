"""The replay's input: the topics it reads, message time (a revolution is due when it ends), and the
events of a bag put back in stamp order, with time jumps (a bag played in a loop) marked."""

from __future__ import annotations

import heapq
import itertools
import math
import pathlib
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from rosbags.rosbag2 import Reader

from beams_common.intake.time_jumps import StampOrder, TimeJumpDetector
from beams_common.interfaces import topics
from beams_tools.bag_io import fully_qualified, offered_qos
from beams_triangulation.motion_compensation import ODOMETRY_TIME_JUMP_S

BEARINGS_TOPIC = topics.BEARINGS
ODOMETRY_TOPIC = topics.ODOMETRY
TRUTH_TOPIC = topics.GROUND_TRUTH
# Outputs of the live nodes, when the bag recorded them: what the replay is compared with.
LIVE_POSE_TOPIC = topics.POSE
LIVE_EKF_TOPIC = topics.EKF_ODOMETRY
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
NS_PER_S = 1_000_000_000


# -- message time ---------------------------------------------------------------------------------------
def stamp_ns(stamp: Any) -> int:
    """builtin_interfaces/Time in integer nanoseconds (exact, for ordering and matching)."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


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
    window_ns: int = round(REORDER_WINDOW_S * NS_PER_S),
    jump_ns: int = round(TIME_JUMP_S * NS_PER_S),
) -> Iterator[Event | None]:
    """Events by due instant within a reorder window (a later message is passed on late, the pipelines drop or
    absorb it as the nodes do); TIME_JUMP where a topic's own stamps go back by > jump_ns in two consecutive
    messages of it (a bag loop; one stray message is not: `beams_common.intake.time_jumps`). A topic is
    judged against itself, as each node judges its input: a recorder that fell behind on one topic (its
    odometry received more than a second late on a loaded machine) writes it late among the others, and
    that is no loop."""
    pending: list[Event] = []
    newest_ns: int | None = None
    newest_of_topic: dict[str, float] = {}
    time_jumps: dict[str, TimeJumpDetector] = {}
    for event in events:
        detector = time_jumps.get(event.topic)
        if detector is None:  # made at the topic's first message, not at every one
            detector = time_jumps[event.topic] = TimeJumpDetector(jump_ns * 1e-9)
        if detector.classify(event.due_ns * 1e-9, newest_of_topic.get(event.topic)) is StampOrder.JUMP:
            while pending:
                yield heapq.heappop(pending)
            yield TIME_JUMP
            newest_ns = None
            newest_of_topic.clear()
            time_jumps = {event.topic: detector}
        newest_of_topic[event.topic] = max(newest_of_topic.get(event.topic, -math.inf), event.due_ns * 1e-9)
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
            qos = tuple(getattr(connection.ext, "offered_qos_profiles", ()))
            order = (due, _TOPIC_ORDER[topic], next(sequence))
            yield Event(*order, topic, bag_ns, connection.msgtype, raw, message, qos)
