"""Replay conditions over DDS (issue 7): triangulation_node and ekf_node with use_sim_time follow /clock and
message stamps from a recorded match, and a bag played in a loop (time going back) resets them cleanly."""

import math

import pytest

# Simulated time starts here: far from the wall clock, as in a bag replayed with --clock.
T0_S = 100.0
MATCH_S = 6.0
WAIT_S = 20.0


@pytest.fixture(scope="module")
def match():
    from beams_sim.simulated_match import simulate_match

    return simulate_match(duration_s=MATCH_S, seed=5)


def _stamp(seconds: float):
    from beams_common.ros.messages import seconds_to_stamp

    return seconds_to_stamp(T0_S + seconds)


def _odometry(match, index: int):
    from nav_msgs.msg import Odometry

    from beams_common.ros.messages import set_pose2d

    msg = Odometry()
    msg.header.stamp = _stamp(float(match.odometry.stamp_s[index]))
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    set_pose2d(msg.pose.pose, match.odometry.pose(index))
    msg.twist.twist.linear.x = float(match.odometry.speed_mps[index])
    msg.twist.twist.angular.z = float(match.odometry.yaw_rate_radps[index])
    return msg


def _revolution(decoded):
    from beams_common.interfaces.bearing_messages import BearingFields, nanoseconds
    from beams_common.ros.messages import bearing_array

    fields = [
        BearingFields(
            nanoseconds(T0_S + b.stamp_s),
            b.beacon_id,
            b.bearing,
            b.variance,
            angular_window_rad=b.angular_window,
            codes_seen=b.codes_seen,
        )
        for b in decoded.bearings
    ]
    start_ns = nanoseconds(T0_S + decoded.start_time_s)
    return bearing_array(start_ns, fields, period_s=decoded.period_s, revolution=decoded.revolution)


def _play(graph, publishers, match, speed: float = 2.0) -> None:
    """Odometry at 50 Hz and each revolution when it ends, with /clock, `speed` times real time."""
    from rosgraph_msgs.msg import Clock

    clock, odom, bearings = publishers
    revolutions = iter(match.revolutions)
    pending = next(revolutions, None)
    for index, t in enumerate(match.odometry.stamp_s):
        clock.publish(Clock(clock=_stamp(float(t))))
        odom.publish(_odometry(match, index))
        while pending is not None and pending.start_time_s + pending.period_s <= t:
            bearings.publish(_revolution(pending))
            pending = next(revolutions, None)
        graph.spin_for(0.02 / speed)


def _position_error_m(msg, match) -> float:
    from beams_common.ros.messages import stamp_to_seconds

    x, y, _ = match.truth_at(stamp_to_seconds(msg.header.stamp) - T0_S)
    return math.hypot(msg.pose.pose.position.x - x, msg.pose.pose.position.y - y)


def test_nodes_follow_sim_time_and_reset_when_the_bag_loops(rclpy_node, start_node, match):
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock

    from beams_msgs.msg import BeaconBearingArray, TriangulatedPose

    for package, executable in (("beams_triangulation", "triangulation_node"), ("beams_ekf", "ekf_node")):
        start_node(package, executable, params={"use_sim_time": True})
    node = rclpy_node.node
    publishers = (
        node.create_publisher(Clock, "/clock", 10),
        node.create_publisher(Odometry, "odom", 50),
        node.create_publisher(BeaconBearingArray, "beams/bearings", 10),
    )
    poses = rclpy_node.subscribe(TriangulatedPose, "beams/pose")
    estimates = rclpy_node.subscribe(Odometry, "beams/ekf/odometry")
    rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    assert rclpy_node.spin_until(
        lambda: all(p.get_subscription_count() >= 2 for p in publishers[1:]), WAIT_S
    ), "the nodes did not subscribe to odom and beams/bearings"

    _play(rclpy_node, publishers, match)
    assert rclpy_node.spin_until(lambda: len(estimates) > 50, WAIT_S), "no EKF estimate"
    first_pass = list(estimates)
    for msg in first_pass:  # stamps from the data, never the wall clock
        assert T0_S <= msg.header.stamp.sec <= T0_S + MATCH_S + 1
    assert _position_error_m(first_pass[-1], match) < 0.02
    assert any(p.accepted for p in poses)

    estimates.clear()
    _play(rclpy_node, publishers, match)  # the bag loops: time goes back to T0_S

    def reset_reported() -> bool:
        return int(rclpy_node.diagnostic_values("ekf").get("time_jump_resets", 0)) >= 1

    assert rclpy_node.spin_until(reset_reported, WAIT_S), "the EKF did not report its reset"
    assert rclpy_node.spin_until(lambda: len(estimates) > 50, WAIT_S), "no estimate after the loop"
    assert _position_error_m(estimates[-1], match) < 0.02
