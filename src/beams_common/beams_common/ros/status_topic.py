"""A localisation node's status on a topic of its own, beside its estimates (docs/status.md).

The estimates' messages (nav_msgs/Odometry, geometry_msgs/PoseWithCovarianceStamped) have no field for
a status, and /diagnostics is one array for every node at 1 Hz: a consumer that must not use an
untrusted pose (a planner, `ros2 topic echo`, a bag) reads beams_msgs/LocalisationStatus instead. It is
latched (transient local, depth 1): a late subscriber gets the current status at once. It says the
node's verdict under the node's conditions (`Diagnostics.verdict`: what /diagnostics says), who says it,
until when it holds (STATUS_VALIDITY_S), the estimate it judges, its protection level
(docs/protection_level.md) and the alert limits.
"""

import math
import os
import socket
import time

from builtin_interfaces.msg import Time
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from beams_common.ros.node_support import Diagnostics
from beams_common.status.health import STATUS_VALIDITY_S, Status, Verdict
from beams_common.status.protection_level import Integrity, ProtectionLevel
from beams_msgs.msg import LocalisationStatus

STATUS_QOS = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
# a status unchanged this long (s) is said again, so that a node judging it once a second (its 1 Hz
# timer, whose ticks jitter) says it every second: a silent status topic is a node that died
STATUS_HEARTBEAT_S = 0.9

STATUS_CODES = {
    Status.WAITING: LocalisationStatus.WAITING,
    Status.TRACKING: LocalisationStatus.TRACKING,
    Status.DEGRADED: LocalisationStatus.DEGRADED,
    Status.LOST: LocalisationStatus.LOST,
}


class StatusTopic:
    """Publishes the node's verdict under its conditions at once when its status or message changes (a
    condition set or cleared included: `Diagnostics.on_publish`), and again when STATUS_HEARTBEAT_S has
    passed since it last said it; the protection level also goes to the node's `diagnostics`."""

    def __init__(self, node: Node, topic: str, diagnostics: Diagnostics) -> None:
        self.node, self.diagnostics = node, diagnostics
        self.publisher = node.create_publisher(LocalisationStatus, topic, STATUS_QOS)
        self.identity = {
            "node": node.get_fully_qualified_name(),
            "instance": f"{socket.gethostname()} pid {os.getpid()} started {time.time():.6f}",
        }
        self._said: tuple[Status, str] | None = None
        self._said_ns = 0
        self._estimate: tuple[Integrity, ProtectionLevel | None, Time] | None = None
        diagnostics.on_publish = self._say

    def say(
        self, verdict: Verdict, integrity: Integrity, level: ProtectionLevel | None, stamp: Time | None
    ) -> None:
        """The node's verdict with the newest estimate's protection level and header stamp (None: no
        estimate), said on /diagnostics and here."""
        if level is not None:
            self.diagnostics.set("horizontal_protection_level_m", level.horizontal_m)
            self.diagnostics.set("heading_protection_level_rad", level.heading_rad)
        self._estimate = (integrity, level, Time() if stamp is None else stamp)
        self._say(self.diagnostics.set_verdict(verdict))

    def _say(self, verdict: Verdict | None = None) -> None:  # the verdict under the conditions, or judged now
        verdict = self.diagnostics.verdict() if verdict is None else verdict
        if verdict is None or self._estimate is None:
            return
        integrity, level, stamp = self._estimate
        now = self.node.get_clock().now()
        said = (verdict.status, verdict.message)
        if said == self._said and now.nanoseconds - self._said_ns < STATUS_HEARTBEAT_S * 1e9:
            return
        message = LocalisationStatus(
            valid_until=(now + Duration(seconds=STATUS_VALIDITY_S)).to_msg(),
            estimate_stamp=stamp,
            status=STATUS_CODES[verdict.status],
            message=verdict.message,
            horizontal_protection_level_m=math.nan if level is None else level.horizontal_m,
            heading_protection_level_rad=math.nan if level is None else level.heading_rad,
            single_fault_covered=level is not None and level.faults_covered,
            horizontal_alert_limit_m=integrity.horizontal_limit_m,
            heading_alert_limit_rad=integrity.heading_limit_rad,
            integrity_risk=integrity.risk,
            within_alert_limits=level is not None and integrity.within(level),
            **self.identity,
        )
        message.header.stamp = now.to_msg()
        self.publisher.publish(message)
        self._said, self._said_ns = said, now.nanoseconds
