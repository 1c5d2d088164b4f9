"""The protection level on the status topics (docs/protection_level.md): when a node's protection level
crosses its alert limit (5 cm, 3 deg by default) its status is degraded ("unavailable for navigation")
with `within_alert_limits` false, and tracking again once it is back within.

- ekf_node, a robot standing still: initialised by a ToTal fix of 2 cm and 1 deg (level 96 mm, 4.4 deg),
  revolutions of two bearings (beacon 3 hidden) leave the pose unobserved along one direction, so the
  level stays above the limit; beacon 3 back, it stays above (134 mm: the solution without beacon 3 is
  the two beacons' alone); an operator's pose, then three bearings from the start bring it to 13 mm.
- triangulation_node: bearings of 0.5 deg accepted by the gates (position std 2 cm) give a level of
  91 mm; bearings of 0.1 deg, 18 mm.
"""

import math
import time

import pytest

pytestmark = pytest.mark.dds

BEACONS = {1: (-0.062, -0.062), 2: (-0.062, 2.062), 3: (3.062, 1.0)}
POSE = (1.3, 0.7, 2.4)
T0_S = 1000.0  # synthetic stamps: the stamp plausibility check off
PARAMS = {"max_stamp_age_s": 0.0, "max_stamp_lead_s": 0.0}
STATUS_TIMEOUT_S = 15.0


def _bearings(ids, end_s: float, sigma_deg: float):
    """A revolution of the standing robot's exact bearings to `ids`, stamped 0.03 s apart up to end_s."""
    from beams_common.interfaces.bearing_messages import BearingFields, nanoseconds
    from beams_common.ros.messages import bearing_array

    x, y, theta = POSE
    fields = [
        BearingFields(
            nanoseconds(T0_S + end_s - 0.03 * (len(ids) - k)),
            i,
            math.remainder(math.atan2(BEACONS[i][1] - y, BEACONS[i][0] - x) - theta, math.tau),
            math.radians(sigma_deg) ** 2,
        )
        for k, i in enumerate(ids)
    ]
    return bearing_array(nanoseconds(T0_S + end_s - 0.1), fields, period_s=0.1)


class _Status:
    """The newest message of a status topic."""

    def __init__(self, rclpy_node, topic: str) -> None:
        from beams_common.ros.status_topic import STATUS_QOS
        from beams_msgs.msg import LocalisationStatus

        self.said = rclpy_node.subscribe(LocalisationStatus, topic, STATUS_QOS)

    def says(self, status: int, within: bool):
        def check() -> bool:
            return bool(self.said) and (self.said[-1].status, self.said[-1].within_alert_limits) == (
                status,
                within,
            )

        return check

    def __repr__(self) -> str:
        return str([(m.status, m.message, m.horizontal_protection_level_m) for m in self.said[-8:]])


def test_ekf_status_degraded_while_two_bearings_leave_the_level_above_the_limit(
    start_node, rclpy_node, total_pose_message
):
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry

    from beams_msgs.msg import BeaconBearingArray, LocalisationStatus, TriangulatedPose

    node = start_node("beams_ekf", "ekf_node", PARAMS)
    status = _Status(rclpy_node, "/beams/ekf/status")
    odometry = rclpy_node.node.create_publisher(Odometry, "odom", 50)
    bearings = rclpy_node.node.create_publisher(BeaconBearingArray, "beams/bearings", 20)
    fixes = rclpy_node.node.create_publisher(TriangulatedPose, "beams/pose", 10)
    initial_pose = rclpy_node.node.create_publisher(PoseWithCovarianceStamped, "/initialpose", 10)
    publishers = (odometry, bearings, fixes, initial_pose)
    assert rclpy_node.spin_until(lambda: all(p.get_subscription_count() for p in publishers), 20.0)
    start = time.monotonic()

    def drive(until, ids=(), fix: bool = False, timeout_s: float = STATUS_TIMEOUT_S) -> bool:
        """Odometry of the standing robot at ~50 Hz and a revolution of `ids` each 0.1 s (stamps: the
        time since the start), until `until()` or the timeout; `fix`: first a ToTal fix of 2 cm, 1 deg."""
        from beams_common.ros.messages import seconds_to_stamp

        end, next_revolution = time.monotonic() + timeout_s, 0.0
        while time.monotonic() < end:
            now_s = time.monotonic() - start
            message = Odometry()
            message.header.stamp = seconds_to_stamp(T0_S + now_s)
            message.header.frame_id, message.child_frame_id = "odom", "base_link"
            message.pose.pose.orientation.w = 1.0
            odometry.publish(message)
            if fix:
                pose = total_pose_message(T0_S + now_s - 0.05, POSE)
                pose.pose.covariance[0] = pose.pose.covariance[7] = 0.02**2
                fixes.publish(pose)
                fix = False
            if ids and now_s >= next_revolution:
                bearings.publish(_bearings(ids, now_s - 0.01, 0.1))
                next_revolution = now_s + 0.1
            rclpy_node.spin_for(0.02)
            if until():
                return True
        return False

    assert drive(lambda: False, timeout_s=1.0) is False  # the odometry history fills
    degraded = status.says(LocalisationStatus.DEGRADED, False)
    assert drive(degraded, ids=(1, 2), fix=True), (status, node.log())
    drive(lambda: False, ids=(1, 2), timeout_s=3.0)  # the rates judged, the level still above
    said = status.said[-1]
    assert (said.status, said.within_alert_limits) == (LocalisationStatus.DEGRADED, False), status
    assert "unavailable for navigation" in said.message and said.horizontal_protection_level_m > 0.05
    assert said.single_fault_covered and said.horizontal_alert_limit_m == pytest.approx(0.05)
    assert said.integrity_risk == pytest.approx(1e-5)

    # beacon 3 back: the solution without it is the two beacons' alone, still unobserved along one
    # direction for a robot standing still: a fault of beacon 3 could go unseen, the level stays above
    drive(lambda: False, ids=(1, 2, 3), timeout_s=2.0)
    said = status.said[-1]
    assert said.status == LocalisationStatus.DEGRADED and said.horizontal_protection_level_m > 0.05, status

    # an operator's pose of 2 cm: the solutions start again after the first revolution of three beacons
    pose = PoseWithCovarianceStamped()
    pose.header.frame_id = "map"  # stamp 0: "now"
    (pose.pose.pose.position.x, pose.pose.pose.position.y), theta = POSE[:2], POSE[2]
    pose.pose.pose.orientation.z, pose.pose.pose.orientation.w = math.sin(theta / 2), math.cos(theta / 2)
    pose.pose.covariance[0] = pose.pose.covariance[7] = 0.02**2
    pose.pose.covariance[35] = math.radians(1.0) ** 2
    initial_pose.publish(pose)
    assert drive(status.says(LocalisationStatus.TRACKING, True), ids=(1, 2, 3)), (status, node.log())
    said = status.said[-1]
    assert said.message == "tracking" and 0.0 < said.horizontal_protection_level_m < 0.025
    assert 0.0 < said.heading_protection_level_rad < said.heading_alert_limit_rad
    assert node.process.poll() is None and "Traceback" not in node.log()


def test_triangulation_status_degraded_while_the_level_is_above_the_limit(start_node, rclpy_node):
    from beams_msgs.msg import BeaconBearingArray, LocalisationStatus

    node = start_node("beams_triangulation", "triangulation_node", {**PARAMS, "use_odometry": False})
    status = _Status(rclpy_node, "/beams/triangulation/status")
    bearings = rclpy_node.node.create_publisher(BeaconBearingArray, "beams/bearings", 20)
    assert rclpy_node.spin_until(lambda: bearings.get_subscription_count() > 0, 20.0)
    start = time.monotonic()

    def drive(until, sigma_deg: float) -> bool:
        """A revolution each 0.1 s of bearings of sigma_deg, until `until()` or the timeout."""
        end = time.monotonic() + STATUS_TIMEOUT_S
        while time.monotonic() < end:
            bearings.publish(_bearings((1, 2, 3), time.monotonic() - start, sigma_deg))
            rclpy_node.spin_for(0.1)
            if until():
                return True
        return False

    for sigma_deg, expected, within in (
        (0.1, LocalisationStatus.TRACKING, True),
        (0.5, LocalisationStatus.DEGRADED, False),
        (0.1, LocalisationStatus.TRACKING, True),
    ):
        assert drive(status.says(expected, within), sigma_deg), (sigma_deg, status, node.log())
        said = status.said[-1]
        assert not said.single_fault_covered  # three bearings: no redundancy
        if within:
            assert said.message == "tracking" and said.horizontal_protection_level_m == pytest.approx(
                0.0183, rel=0.05
            )
        else:
            assert "unavailable for navigation" in said.message
            assert said.horizontal_protection_level_m == pytest.approx(0.0915, rel=0.05)
    assert node.process.poll() is None and "Traceback" not in node.log()
