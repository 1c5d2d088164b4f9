"""One status: /diagnostics and the status topic say the node's verdict under the same conditions.

Diagnostics and StatusTopic on a stand-in node (no DDS: its publishers keep what they are given, its
clock is the test's): an ERROR condition appearing and clearing, a held one ending, a WARN one, the
heartbeat and the validity every message carries, and the node's identity.
"""

import os
import socket
from types import SimpleNamespace

import pytest
from rclpy.time import Time

from beams_common.ros import node_support
from beams_common.ros.node_support import Diagnostics
from beams_common.ros.status_topic import STATUS_HEARTBEAT_S, StatusTopic
from beams_common.status.health import STATUS_VALIDITY_S, judge
from beams_common.status.protection_level import INTEGRITY_SPECS, Integrity, ProtectionLevel
from beams_msgs.msg import LocalisationStatus

INTEGRITY = Integrity({spec.name: spec.default for spec in INTEGRITY_SPECS})
LEVEL = ProtectionLevel(0.003, 0.001, True)
SECOND = "2 publishers on /beams/ekf/status (this node's output): /ekf_node, /spoof"
NS = 1_000_000_000


class StandInNode:
    """What Diagnostics and StatusTopic use of an rclpy Node."""

    def __init__(self) -> None:
        self.now_ns = 1_795_000_000 * NS
        self.published: dict[str, list] = {}

    def get_fully_qualified_name(self) -> str:
        return "/robot/ekf_node"

    def get_logger(self):
        return SimpleNamespace(info=print, warning=print, error=print)

    def create_publisher(self, _type, topic: str, _qos):
        return SimpleNamespace(publish=self.published.setdefault(topic, []).append)

    def create_timer(self, *_args, **_kwargs) -> None:
        return None

    def get_parameter(self, _name: str):
        return SimpleNamespace(value=False)

    def get_clock(self):
        return SimpleNamespace(now=lambda: Time(nanoseconds=self.now_ns))


@pytest.fixture
def node() -> StandInNode:
    return StandInNode()


def said(node: StandInNode) -> tuple[list[LocalisationStatus], list]:
    """(status messages, /diagnostics statuses) published so far."""
    arrays = node.published.get("/diagnostics", [])
    return node.published.get("status", []), [array.status[0] for array in arrays]


def value(diagnostic, key: str) -> str:
    return {pair.key: pair.value for pair in diagnostic.values}[key]


def test_an_error_condition_is_said_at_once_by_both_and_its_end_too(node):
    diagnostics = Diagnostics(node, "ekf")
    topic = StatusTopic(node, "status", diagnostics)
    topic.say(judge(), INTEGRITY, LEVEL, Time(nanoseconds=node.now_ns - 30_000_000).to_msg())
    statuses, diagnosed = said(node)
    assert [s.status for s in statuses] == [LocalisationStatus.TRACKING]
    assert (diagnosed[-1].level, diagnosed[-1].message, value(diagnosed[-1], "status")) == (
        b"\x00",
        "tracking",
        "tracking",
    )
    # a second publisher on the status topic: both say it at once, with one message, at ERROR / lost
    node.now_ns += 200_000_000
    diagnostics.set_condition("publishers /beams/ekf/status", "error", SECOND)
    statuses, diagnosed = said(node)
    assert len(statuses) == 2 and statuses[-1].status == LocalisationStatus.LOST
    assert statuses[-1].message == f"lost: {SECOND}" == diagnosed[-1].message
    assert (diagnosed[-1].level, value(diagnosed[-1], "status")) == (b"\x02", "lost")
    # the node's own verdict stays tracking meanwhile: the condition still rules
    node.now_ns += 100_000_000
    topic.say(judge(), INTEGRITY, LEVEL, None)
    assert said(node)[0][-1].status == LocalisationStatus.LOST and len(said(node)[0]) == 2
    # cleared: tracking again at once, on /diagnostics after the ERROR report repeated (closing its span)
    node.now_ns += 100_000_000
    before = len(said(node)[1])
    diagnostics.clear_condition("publishers /beams/ekf/status")
    statuses, diagnosed = said(node)
    assert [d.message for d in diagnosed[before:]] == [f"lost: {SECOND}", "tracking"]
    assert [s.status for s in statuses] == [1, 3, 1]
    assert statuses[-1].header.stamp.nanosec == 400_000_000


def test_a_held_error_ends_at_the_next_judgement_and_a_warn_condition_degrades(node, monkeypatch):
    steady = [50.0]
    monkeypatch.setattr(node_support.time, "monotonic", lambda: steady[0])
    diagnostics = Diagnostics(node, "ekf")
    topic = StatusTopic(node, "status", diagnostics)
    topic.say(judge("", [], ["bearings at 3.0 Hz over 2 s, below 5 Hz"]), INTEGRITY, None, None)
    diagnostics.callback_failed("odometry", "ValueError: boom")
    statuses, diagnosed = said(node)
    assert statuses[-1].status == LocalisationStatus.LOST
    assert statuses[-1].message.startswith("lost: a callback failed (odometry: ValueError: boom); bearings")
    assert diagnosed[-1].message == statuses[-1].message
    steady[0] += Diagnostics.CALLBACK_FAULT_HOLD_S - 0.01
    topic.say(judge(), INTEGRITY, None, None)
    assert said(node)[0][-1].status == LocalisationStatus.LOST
    steady[0] += 0.02  # the hold is over: the next judgement says the node's own verdict
    topic.say(judge(), INTEGRITY, None, None)
    assert said(node)[0][-1].status == LocalisationStatus.TRACKING
    assert said(node)[1][-1].message == "tracking"
    diagnostics.set_condition("odometry rate", "warn", "odometry at 2.0 Hz")
    topic.say(judge(), INTEGRITY, None, None)
    assert said(node)[0][-1].message == "degraded: odometry at 2.0 Hz"
    assert said(node)[0][-1].status == LocalisationStatus.DEGRADED


def test_every_message_says_who_and_until_when_and_is_said_again_each_heartbeat(node):
    diagnostics = Diagnostics(node, "ekf")
    topic = StatusTopic(node, "status", diagnostics)
    estimate = Time(nanoseconds=node.now_ns - 7).to_msg()
    topic.say(judge("waiting for odometry"), INTEGRITY, None, None)
    topic.say(judge(), INTEGRITY, LEVEL, estimate)
    node.now_ns += int((STATUS_HEARTBEAT_S - 0.01) * NS)
    topic.say(judge(), INTEGRITY, LEVEL, estimate)  # unchanged, within the heartbeat: not said again
    node.now_ns += int(0.02 * NS)
    diagnostics.publish()  # the 1 Hz report says it again: past the heartbeat
    statuses, _ = said(node)
    assert [s.status for s in statuses] == [0, 1, 1]
    for message in statuses:
        stamp_ns = message.header.stamp.sec * NS + message.header.stamp.nanosec
        until_ns = message.valid_until.sec * NS + message.valid_until.nanosec
        assert until_ns - stamp_ns == STATUS_VALIDITY_S * NS
        assert message.node == "/robot/ekf_node"
        assert message.instance.startswith(f"{socket.gethostname()} pid {os.getpid()} started ")
    assert (statuses[0].estimate_stamp.sec, statuses[0].estimate_stamp.nanosec) == (0, 0)
    assert (statuses[-1].estimate_stamp.sec, statuses[-1].estimate_stamp.nanosec) == (
        estimate.sec,
        estimate.nanosec,
    )
    assert statuses[-1].horizontal_protection_level_m == 0.003


def test_the_timed_publication_reads_before_publish_first(node):
    """What a node reads once a second for /diagnostics (driver_node: its source's health) is read by the
    timer's publication, into it; an ERROR published at once does not wait for it."""
    timers = []
    node.create_timer = lambda _period, callback, **_: timers.append(callback)
    diagnostics = Diagnostics(node, "driver")
    diagnostics.before_publish = lambda: diagnostics.set("source", "read")
    diagnostics.set_condition("link", "error", "gone")
    assert "source" not in [pair.key for pair in said(node)[1][-1].values]
    timers[0]()
    assert value(said(node)[1][-1], "source") == "read"
