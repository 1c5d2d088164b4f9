"""The localisation nodes' status beside their estimates (issue 18: "the pose messages and /diagnostics say
tracking only while their consistency checks pass"): beams/ekf/status and beams/triangulation/status
(beams_msgs/LocalisationStatus) say what /diagnostics says, at once on a change and at least every
second, latched for a late subscriber.

The whole robot runs on its defaults; an operator's pose 0.5 m off the truth (a well-formed but wrong
input) makes the EKF's status degraded at once on the topic, with /diagnostics' reason; the bearings
bring it back to tracking.
"""

import itertools
import math
import time

import pytest

pytestmark = pytest.mark.dds

UP_TIMEOUT_S = 60.0
HEARTBEAT_BOUND_S = 1.3  # STATUS_HEARTBEAT_S (0.9) after a 1 Hz judgement, with a loaded machine's jitter
SAID_AT_ONCE_S = 0.5
BACK_TIMEOUT_S = 30.0
WORDS = {0: "waiting", 1: "tracking", 2: "degraded", 3: "lost"}


def test_the_status_topics_say_what_diagnostics_says_at_once_and_latched(start_node, rclpy_node):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry

    from beams_common.interfaces import topics
    from beams_common.ros.status_topic import STATUS_QOS
    from beams_msgs.msg import LocalisationStatus
    from beams_msgs.srv import SetPose

    node = rclpy_node.node
    said: dict[str, list[tuple[float, LocalisationStatus]]] = {"ekf": [], "triangulation": []}
    diagnostics: list[tuple[float, str]] = []  # the EKF's /diagnostics messages
    truth: list[Odometry] = []

    def on_status(kind: str):
        return lambda msg: said[kind].append((time.monotonic(), msg))

    def on_diagnostics(msg) -> None:
        diagnostics.extend((time.monotonic(), s.message) for s in msg.status if s.name == "/ekf_node: ekf")

    node.create_subscription(LocalisationStatus, "/" + topics.EKF_STATUS, on_status("ekf"), STATUS_QOS)
    node.create_subscription(
        LocalisationStatus, "/" + topics.TRIANGULATION_STATUS, on_status("triangulation"), STATUS_QOS
    )
    node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_diagnostics, 50)
    node.create_subscription(Odometry, "/" + topics.GROUND_TRUTH, truth.append, 10)
    # the EKF alone first: with no input it says waiting, and the probe hears it before any bearing could
    # change it (latched at depth 1, a status superseded before discovery completes is never delivered)
    nodes = [start_node("beams_ekf", "ekf_node")]
    assert rclpy_node.spin_until(lambda: bool(said["ekf"]), UP_TIMEOUT_S), nodes[0].log()
    assert said["ekf"][0][1].status == LocalisationStatus.WAITING, said["ekf"][0][1].message
    nodes += [
        start_node("beams_sim", "sim_world_node"),
        start_node("beams_driver", "driver_node"),
        start_node("beams_triangulation", "triangulation_node"),
    ]

    def newest(kind: str) -> LocalisationStatus | None:
        return said[kind][-1][1] if said[kind] else None

    def tracking(kind: str) -> bool:
        latest = newest(kind)
        return latest is not None and latest.status == LocalisationStatus.TRACKING

    assert rclpy_node.spin_until(lambda: tracking("ekf") and tracking("triangulation"), UP_TIMEOUT_S), (
        [(m.status, m.message) for _, m in said["ekf"][-3:]],
        [(m.status, m.message) for _, m in said["triangulation"][-3:]],
        [n.log() for n in nodes],
    )
    # every message's code and text agree
    for kind in said:
        for _, msg in said[kind]:
            assert msg.message.split(":")[0] == WORDS[msg.status], (kind, msg.status, msg.message)

    # at least once a second while nothing changes
    start = time.monotonic()
    rclpy_node.spin_until(lambda: False, 3.5)
    for kind in said:
        stamps = [t for t, _ in said[kind] if t >= start - HEARTBEAT_BOUND_S]
        gaps = [b - a for a, b in itertools.pairwise(stamps)]
        assert len(stamps) >= 3 and max(gaps) <= HEARTBEAT_BOUND_S, (kind, gaps)

    # latched: a subscriber that comes now gets the current status at once (tracking, or degraded for a
    # while on a loaded machine: two ToTal poses in a row delayed past the 0.25 s stamp tolerance)
    late: list[LocalisationStatus] = []
    node.create_subscription(LocalisationStatus, "/" + topics.EKF_STATUS, late.append, STATUS_QOS)
    assert rclpy_node.spin_until(lambda: bool(late), SAID_AT_ONCE_S + 0.5)
    assert late[0].header.stamp in [m.header.stamp for _, m in said["ekf"][-3:]], late[0].message

    # an operator's pose 0.5 m off the truth: degraded at once, the reason as /diagnostics gives it (from
    # tracking: a change of status is said on both at once, a new reason within one at the 1 Hz tick)
    assert rclpy_node.spin_until(lambda: tracking("ekf"), BACK_TIMEOUT_S), said["ekf"][-1][1].message
    assert truth, "no ground truth received"
    true_pose = truth[-1].pose.pose
    pose = PoseWithCovarianceStamped()
    pose.header.frame_id = "map"
    pose.header.stamp = node.get_clock().now().to_msg()
    pose.pose.pose.position.x = true_pose.position.x + 0.5
    pose.pose.pose.position.y = true_pose.position.y
    pose.pose.pose.orientation = true_pose.orientation
    pose.pose.covariance[0] = pose.pose.covariance[7] = 0.01**2
    pose.pose.covariance[35] = math.radians(1.0) ** 2
    sent = time.monotonic()
    reply = rclpy_node.call(SetPose, "/ekf_node/set_pose", SetPose.Request(pose=pose), 10.0)
    assert reply.success, reply.message
    answered = time.monotonic()

    unconfirmed = "pose not yet confirmed by the bearings since"

    def degraded_after(t0: float) -> list[tuple[float, LocalisationStatus]]:
        return [
            (t, m)
            for t, m in said["ekf"]
            if t >= t0 and m.status == LocalisationStatus.DEGRADED and unconfirmed in m.message
        ]

    assert rclpy_node.spin_until(lambda: bool(degraded_after(sent)), SAID_AT_ONCE_S + 1.0), said["ekf"][-1]
    at, degraded = degraded_after(sent)[0]
    assert at - answered <= SAID_AT_ONCE_S, at - answered
    rclpy_node.spin_until(lambda: any(t >= at and unconfirmed in m for t, m in diagnostics), 2.0)
    diagnosed = [m for t, m in diagnostics if t >= sent and m.startswith("degraded") and unconfirmed in m]
    assert diagnosed and diagnosed[0].split("(")[0] == degraded.message.split("(")[0], (diagnosed, degraded)
    # the bearings find the pose wrong and re-initialise it from ToTal: tracking again
    assert rclpy_node.spin_until(lambda: tracking("ekf"), BACK_TIMEOUT_S), [
        (m.status, m.message) for _, m in said["ekf"][-5:]
    ]
    assert all(n.process.poll() is None for n in nodes)
