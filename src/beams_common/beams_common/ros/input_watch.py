"""A second publisher on a node's input is said on /diagnostics at ERROR, naming the publishers.

Two driver_nodes (or two sim_world_nodes) in one namespace interleave their revolutions and odometry:
fused twice, lost detections, re-initialisations, every status OK. `WatchedInputs`, a mixin for rclpy's
Node and LifecycleNode (`class EkfNode(WatchedInputs, GuardedCallbacks, Node)`), watches every
subscription whose message type has one source by design (SINGLE_SOURCE_INPUTS: beams/bearings,
odometry, ground truth, ToTal poses; not /initialpose, where any operator may publish) two ways:

- the ROS graph, every GRAPH_CHECK_PERIOD_S on the steady clock: more than one publisher on the topic is
  an ERROR condition naming them (node names, and how many share a name), cleared once one is left;
- the messages: revolution counters or stamps that interleave (`stream_interleave.InterleaveDetector`),
  which also catches two sources behind one publisher (a relay) and says so the same way;
- with the same graph check, its own outputs of those types (ekf_node's beams/ekf/odometry, which no node
  of the suite reads) and its status topic: a second ekf_node in the namespace, or any other publisher
  of beams/ekf/status, is said by the EKF itself.

The conditions go through `Diagnostics.set_condition`: the node's status is ERROR with the reason first,
whatever else it says (a localisation node's: lost, on /diagnostics and its status topic). A node killed
with SIGKILL stays in the graph until its DDS lease ends (5 s in the package's Fast DDS profile): a node
respawned meanwhile is counted twice for those seconds.
"""

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType

from beams_common.intake.stream_interleave import InterleaveDetector
from beams_common.ros.messages import OdometrySample, odometry_sample

GRAPH_CHECK_PERIOD_S = 0.5
INTERLEAVE_HOLD_S = 1.0  # the message check's ERROR outlives the last switch by this long


@dataclass(frozen=True)
class StreamKey:
    """How to read a single-source stream's increasing value from its messages."""

    value: Callable[[Any], float]
    max_step: float  # the largest step one source makes between two messages
    modulus: float | None = None
    what: str = "stamps"


def _stamp_s(msg: Any) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


# message type (package/msg/Name) -> its stream key; 50 revolutions is 5 s of a 10 Hz turret
SINGLE_SOURCE_INPUTS = {
    "beams_msgs/msg/BeaconBearingArray": StreamKey(
        lambda msg: msg.revolution, max_step=50, modulus=2**32, what="revolution counters"
    ),
    "nav_msgs/msg/Odometry": StreamKey(_stamp_s, max_step=1.0),
    "beams_msgs/msg/TriangulatedPose": StreamKey(_stamp_s, max_step=1.0),
}
ODOMETRY_SAMPLES = StreamKey(lambda sample: sample.stamp_s, max_step=1.0)
# the outputs a second publisher makes untrustworthy: those types, and a localisation node's status
SINGLE_SOURCE_OUTPUTS = (*SINGLE_SOURCE_INPUTS, "beams_msgs/msg/LocalisationStatus")
# topics where several publishers are expected whatever their type
MANY_PUBLISHERS_ALLOWED = ("/initialpose",)


def type_name(msg_type: Any) -> str:
    """'package/msg/Name' of a generated message class."""
    return f"{msg_type.__module__.split('.')[0]}/msg/{msg_type.__name__}"


class WatchedInputs:
    """Mixin: see the module docstring. State is made on first use (rclpy's constructor creates
    subscriptions, /clock's, before ours runs)."""

    def create_subscription(self, msg_type, topic, callback, *args, **kwargs):
        key = SINGLE_SOURCE_INPUTS.get(type_name(msg_type))
        resolved = self.resolve_topic_name(topic)
        if key is not None and resolved not in MANY_PUBLISHERS_ALLOWED and not kwargs.get("raw", False):
            callback = self._watch_input(resolved, key, callback)
        return super().create_subscription(msg_type, topic, callback, *args, **kwargs)

    def create_odometry_subscription(self, topic: str, callback: Callable[[OdometrySample], None], qos: Any):
        """Odometry to `callback` as `messages.odometry_sample`s (rclpy's conversion skipped), watched."""
        watched = self._watch_input(self.resolve_topic_name(topic), ODOMETRY_SAMPLES, callback)
        return self.create_subscription(
            Odometry, topic, lambda raw: watched(odometry_sample(raw)), qos, raw=True
        )

    def _watch_input(self, topic: str, key: StreamKey, callback: Callable) -> Callable:
        watched = self.__dict__.setdefault("_watched_inputs", {})
        if topic not in watched:
            watched[topic] = InterleaveDetector(key.max_step, modulus=key.modulus)
        if "_input_graph_timer" not in self.__dict__:
            steady = Clock(clock_type=ClockType.STEADY_TIME)  # under use_sim_time too, before /clock
            self._input_graph_timer = self.create_timer(
                GRAPH_CHECK_PERIOD_S, self.check_input_publishers, clock=steady
            )
        detector = watched[topic]

        def observed(msg: Any) -> Any:
            now_s = time.monotonic()
            detector.observe(float(key.value(msg)), now_s)
            if detector.interleaved(now_s):
                self._show_input_condition(
                    f"interleaved {topic}",
                    f"two sources on {topic}: {key.what} interleave",
                    INTERLEAVE_HOLD_S,
                )
            return callback(msg)

        return observed

    def check_input_publishers(self) -> None:
        """The graph check: more than one publisher on a watched input is an ERROR condition (an input
        the node no longer subscribes to, a driver cleaned up, is not judged); then the same on the node's
        own single-source outputs and its status topic (a second ekf_node in the namespace, whose
        estimates interleave with this one's on beams/ekf/odometry, read by nothing in the suite; a
        spoofed status): said by the node itself, naming both."""
        watched = self.__dict__.get("_watched_inputs", {})
        subscribed = {subscription.topic_name for subscription in self.subscriptions}
        outputs = [
            p.topic_name
            for p in self.publishers
            if p.topic_name not in watched and type_name(p.msg_type) in SINGLE_SOURCE_OUTPUTS
        ]
        for topic in [*watched, *outputs]:
            # the count first: the endpoints' descriptions cost rclpy a QoS profile each, every check
            crowded = topic in (*subscribed, *outputs) and self.count_publishers(topic) > 1
            publishers = self.get_publishers_info_by_topic(topic) if crowded else []
            if len(publishers) <= 1:
                self._clear_input_condition(f"publishers {topic}")
                continue
            names = sorted(_qualified(info.node_namespace, info.node_name) for info in publishers)
            listed = ", ".join(
                f"{n} (x{names.count(n)})" if names.count(n) > 1 else n for n in sorted(set(names))
            )
            own = " (this node's output)" if topic in outputs else ""
            reason = f"{len(publishers)} publishers on {topic}{own}: {listed}"
            self._show_input_condition(f"publishers {topic}", reason, None)

    def _clear_input_condition(self, name: str) -> None:
        diagnostics = getattr(self, "diagnostics", None)
        if diagnostics is not None:
            diagnostics.clear_condition(name)

    def _show_input_condition(self, name: str, reason: str, hold_s: float | None) -> None:
        diagnostics = getattr(self, "diagnostics", None)
        if diagnostics is None:
            return
        if name not in diagnostics.active_conditions():
            diagnostics.increment("input_source_problems")  # each time one starts
        diagnostics.set("last_input_publishers_problem", reason)
        diagnostics.set_condition(name, "error", reason, hold_s=hold_s)


def _qualified(namespace: str, name: str) -> str:
    return f"{namespace.rstrip('/')}/{name}"
