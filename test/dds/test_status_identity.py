"""One status (docs/status.md): beams/ekf/status says what /diagnostics says, its ERROR conditions
included, names the node and its process, and expires.

- Two ekf_nodes of one name in one namespace both publish beams/ekf/status: each says lost, naming the
  two publishers, in two distinct `instance`s; /diagnostics says the same at ERROR. Stopping one clears it.
- One ekf_node: without odometry it says it waits for odometry while it refuses every ToTal fix for want
  of it; a spoofed "tracking" on its status topic makes its own status lost, naming the spoofer; stopped
  with SIGSTOP (hung), it says nothing more and its last status expires (`valid_until`).
"""

import os
import signal
import time

import pytest

pytestmark = pytest.mark.dds

UP_TIMEOUT_S = 60.0
# the graph check runs every 0.5 s; the status is said at once on a change
DETECTION_BOUND_S = 3.0
CLEAR_BOUND_S = 8.0
TOPIC = "/beams/ekf/status"
SECOND_PUBLISHER = "2 publishers on /beams/ekf/status (this node's output)"


def _status_subscription(rclpy_node) -> list:
    """Every beams/ekf/status message, with the probe's arrival time: (time, message)."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from beams_msgs.msg import LocalisationStatus

    said: list = []
    qos = QoSProfile(
        depth=50, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
    )
    rclpy_node.node.create_subscription(
        LocalisationStatus, TOPIC, lambda m: said.append((time.monotonic(), m)), qos
    )
    return said


def _ekf_diagnostics(rclpy_node) -> list:
    from diagnostic_msgs.msg import DiagnosticArray

    diagnosed: list = []

    def on_diagnostics(msg) -> None:
        diagnosed.extend(s for s in msg.status if s.name == "/ekf_node: ekf")

    rclpy_node.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
    return diagnosed


def _seconds(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


def test_two_ekf_nodes_on_one_status_topic_each_say_lost_naming_both(start_node, rclpy_node):
    from diagnostic_msgs.msg import DiagnosticStatus

    from beams_msgs.msg import LocalisationStatus

    said = _status_subscription(rclpy_node)
    diagnosed = _ekf_diagnostics(rclpy_node)
    first, second = start_node("beams_ekf", "ekf_node"), start_node("beams_ekf", "ekf_node")

    def newest() -> dict[str, LocalisationStatus]:
        return {m.instance: m for _, m in said}

    # DDS discovers the other node's publisher before its name (rmw's _NODE_NAME_UNKNOWN_ placeholder
    # meanwhile): the first lost status may name an unknown node, the next graph check names it
    def both_lost() -> bool:
        latest = newest()
        return len(latest) == 2 and all(
            m.status == LocalisationStatus.LOST and f"{SECOND_PUBLISHER}: /ekf_node (x2)" in m.message
            for m in latest.values()
        )

    assert rclpy_node.spin_until(both_lost, UP_TIMEOUT_S), (
        [(m.instance, m.status, m.message) for m in newest().values()],
        first.log(),
        second.log(),
    )
    latest = newest()
    assert {m.node for m in latest.values()} == {"/ekf_node"}
    pids = {int(instance.split(" pid ")[1].split()[0]) for instance in latest}
    assert pids == {first.process.pid, second.process.pid}
    for message in latest.values():
        assert message.message.startswith("lost: 2 publishers on /beams/ekf/"), message.message

    # /diagnostics says the very same, at ERROR, its `status` value lost
    def diagnosed_alike() -> list:
        messages = {m.message for _, m in said}
        return [d for d in diagnosed if d.level == DiagnosticStatus.ERROR and d.message in messages]

    assert rclpy_node.spin_until(lambda: bool(diagnosed_alike()), 3.0), [d.message for d in diagnosed[-3:]]
    assert all({p.key: p.value for p in d.values}["status"] == "lost" for d in diagnosed_alike())

    # one stops: the other says its own status again (waiting for odometry)
    first.assert_clean_exit()
    stopped = time.monotonic()

    remaining = next(i for i in latest if f" pid {second.process.pid} " in i)

    def remaining_waiting() -> bool:
        own = [m for t, m in said if t > stopped and m.instance == remaining]
        return bool(own) and own[-1].status == LocalisationStatus.WAITING

    assert rclpy_node.spin_until(remaining_waiting, CLEAR_BOUND_S), [m.message for _, m in said[-3:]]
    assert said[-1][1].message.startswith("waiting: waiting for odometry"), said[-1][1].message


def test_the_ekf_says_what_it_waits_for_a_spoof_and_when_it_hangs(start_node, rclpy_node, total_pose_message):
    from nav_msgs.msg import Odometry

    from beams_common.ros.messages import seconds_to_stamp
    from beams_common.ros.status_topic import STATUS_QOS
    from beams_common.status.health import STATUS_VALIDITY_S, Status, status_in_force
    from beams_msgs.msg import LocalisationStatus, TriangulatedPose

    said = _status_subscription(rclpy_node)
    diagnosed = _ekf_diagnostics(rclpy_node)
    ekf = start_node("beams_ekf", "ekf_node")
    assert rclpy_node.spin_until(lambda: bool(said), UP_TIMEOUT_S), ekf.log()
    instance = said[0][1].instance
    assert f" pid {ekf.process.pid} " in instance and said[0][1].node == "/ekf_node"

    def own() -> list:
        return [m for _, m in said if m.instance == instance]

    # ToTal's fixes without odometry: every one refused (outside the odometry history), and the status
    # says odometry is what it waits for
    node = rclpy_node.node
    poses = node.create_publisher(TriangulatedPose, "/beams/pose", 10)
    odometry = node.create_publisher(Odometry, "/odom", 10)

    def now_s() -> float:
        return node.get_clock().now().nanoseconds * 1e-9

    def refused() -> int:
        values = {pair.key: pair.value for status in diagnosed for pair in status.values}
        return int(values.get("poses_outside_history", 0))

    def fix() -> None:
        poses.publish(total_pose_message(now_s() - 0.05, (1.0, 1.0, 0.0)))

    deadline = time.monotonic() + 15.0
    while refused() < 5 and time.monotonic() < deadline:
        fix()
        rclpy_node.spin_for(0.2)
    assert refused() >= 5, (refused(), ekf.log())
    waiting = own()[-1]
    assert waiting.status == LocalisationStatus.WAITING, waiting.message
    assert waiting.message.startswith("waiting: waiting for odometry (odom)"), waiting.message
    assert (waiting.estimate_stamp.sec, waiting.estimate_stamp.nanosec) == (0, 0)
    # odometry comes: the next fix is taken, and the status no longer waits
    start = now_s()
    for k in range(60):
        message = Odometry()
        message.header.stamp = seconds_to_stamp(now_s())
        message.header.frame_id = "odom"
        message.pose.pose.orientation.w = 1.0
        odometry.publish(message)
        if k >= 20 and k % 10 == 0:
            poses.publish(total_pose_message(now_s() - 0.1, (1.0, 1.0, 0.0)))
        rclpy_node.spin_for(0.02)
    assert own()[-1].status != LocalisationStatus.WAITING, own()[-1].message
    assert _seconds(own()[-1].estimate_stamp) >= start

    # a spoofed "tracking" on its status topic: its own status says lost, naming the spoofer
    spoof = node.create_publisher(LocalisationStatus, TOPIC, STATUS_QOS)
    fake = LocalisationStatus(status=LocalisationStatus.TRACKING, message="tracking", node="/ekf_node")
    before = len(own())

    def own_lost() -> bool:  # the spoofer named once discovered (both_lost above)
        return any(
            m.status == LocalisationStatus.LOST
            and f"{SECOND_PUBLISHER}: /beams_test_probe, /ekf_node" in m.message
            for m in own()[before:]
        )

    assert rclpy_node.publish_until(spoof, fake, own_lost, DETECTION_BOUND_S + 2.0), own()[-1].message
    node.destroy_publisher(spoof)
    assert rclpy_node.spin_until(lambda: SECOND_PUBLISHER not in own()[-1].message, CLEAR_BOUND_S)

    # hung: nothing more is said, and the last status expires STATUS_VALIDITY_S after its stamp
    os.kill(ekf.process.pid, signal.SIGSTOP)
    try:
        rclpy_node.spin_for(0.5)  # what was under way arrives
        stopped = len(own())
        rclpy_node.spin_for(STATUS_VALIDITY_S + 0.5)
        assert len(own()) == stopped
        last = own()[-1]
        assert _seconds(last.valid_until) - _seconds(last.header.stamp) == pytest.approx(STATUS_VALIDITY_S)
        assert status_in_force(Status.TRACKING, _seconds(last.valid_until), now_s()) is Status.LOST
    finally:
        os.kill(ekf.process.pid, signal.SIGCONT)
    resumed = len(own())
    assert rclpy_node.spin_until(lambda: len(own()) > resumed, 3.0), ekf.log()
    assert _seconds(own()[-1].valid_until) > now_s()
