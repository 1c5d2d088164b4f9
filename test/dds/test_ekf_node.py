"""ekf_node over DDS: it initialises from ToTal's pose, tracks a synthetic match from odometry and bearing
messages (message stamps only, faster than real time), publishes map -> base_link odometry with a
covariance, resets on its service, takes an operator's pose, and refuses bad parameters (exit 2)."""

import math

import pytest

OFFSET = (0.02, -0.01)
# synthetic instants are shifted so that stamps look like a real clock's
T0_S = 1000.0


@pytest.fixture(scope="module")
def match():
    from beams_thesis.synthetic import synthetic_match

    return synthetic_match(4.0, seed=11, sensor_offset_m=OFFSET)


def _time(seconds: float):
    from builtin_interfaces.msg import Time

    whole = math.floor(seconds)
    return Time(sec=int(whole), nanosec=round((seconds - whole) * 1e9) % 1_000_000_000)


def _odometry(t: float, pose):
    from nav_msgs.msg import Odometry

    msg = Odometry()
    msg.header.stamp = _time(T0_S + t)
    msg.header.frame_id = "odom"
    msg.child_frame_id = "base_link"
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(pose[0]), float(pose[1])
    msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(pose[2] / 2), math.cos(pose[2] / 2)
    return msg


def _revolution(bearings):
    from beams_common.interfaces.bearing_messages import BearingFields, nanoseconds
    from beams_common.ros.messages import bearing_array

    fields = [
        BearingFields(nanoseconds(T0_S + b.stamp_s), b.beacon_id, b.bearing_rad, b.variance_rad2)
        for b in bearings
    ]
    return bearing_array(nanoseconds(T0_S + bearings[0].arrival_s - 0.1), fields, period_s=0.1)


class _Feeder:
    """Publishers of the node's inputs, connected before use."""

    def __init__(self, graph):
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import Odometry

        from beams_msgs.msg import BeaconBearingArray, TriangulatedPose

        node = graph.node
        self.graph = graph
        self.odom = node.create_publisher(Odometry, "odom", 50)
        self.bearings = node.create_publisher(BeaconBearingArray, "beams/bearings", 20)
        self.total = node.create_publisher(TriangulatedPose, "beams/pose", 10)
        self.initial_pose = node.create_publisher(PoseWithCovarianceStamped, "/initialpose", 10)
        publishers = (self.odom, self.bearings, self.total, self.initial_pose)
        assert graph.spin_until(lambda: all(p.get_subscription_count() > 0 for p in publishers), 20.0), (
            "ekf_node did not subscribe to its inputs within 20 s"
        )

    def play(
        self,
        match,
        until_s: float,
        start_s: float = 0.0,
        speed: float = 2.0,
        odometry: bool = True,
        revolutions: bool = True,
    ) -> None:
        """Odometry (50 Hz) and revolutions in arrival order, `speed` times faster than real time; either
        left out on request."""
        from itertools import groupby

        turns = (
            [list(g) for _, g in groupby(match.bearings, key=lambda b: b.arrival_s)] if revolutions else []
        )
        r = 0
        for k, t in enumerate(match.times_s):
            if not start_s <= t < until_s:
                continue
            if odometry:
                self.odom.publish(_odometry(float(t), match.odometry[k]))
            while r < len(turns) and turns[r][0].arrival_s <= t:
                if turns[r][0].arrival_s >= start_s:
                    self.bearings.publish(_revolution(turns[r]))
                r += 1
            self.graph.spin_for(0.02 / speed)


def _params():
    # synthetic stamps (T0_S), not on the node's clock: the stamp plausibility check off
    return {
        "turret_offset_m": list(OFFSET),
        "publish_rate_hz": 50.0,
        "max_stamp_age_s": 0.0,
        "max_stamp_lead_s": 0.0,
    }


def _error_m(msg, match) -> float:
    t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec - T0_S
    x, y, _ = match.truth_at(t)
    return math.hypot(msg.pose.pose.position.x - x, msg.pose.pose.position.y - y)


def _assert_map_to_odom_places_the_odometry_on_the_estimate(transforms, outputs, match) -> None:
    """REP-105: map -> odom composed with the odometry pose of the same stamp is the EKF's map pose."""
    import numpy as np

    from beams_common.geometry.pose2d import compose
    from beams_common.ros.messages import stamp_to_seconds

    # one stamp may carry two estimates (after the odometry, then after a revolution's bearings at that
    # same odometry instant): a transform must match one of the estimates published with its stamp,
    # and each stamp goes to /tf once (tf2 ignores a repeated stamp, logging TF_REPEATED_DATA)
    estimates: dict[tuple[int, int], list] = {}
    for output in outputs:
        estimates.setdefault((output.header.stamp.sec, output.header.stamp.nanosec), []).append(output)
    stamps = [(m.transforms[0].header.stamp.sec, m.transforms[0].header.stamp.nanosec) for m in transforms]
    assert len(set(stamps)) == len(stamps), f"{len(stamps) - len(set(stamps))} transforms at a repeated stamp"
    assert any(len(same) > 1 for same in estimates.values()), "no estimate refined at a published instant"
    checked = 0
    for message in transforms:
        (transform,) = message.transforms
        assert (transform.header.frame_id, transform.child_frame_id) == ("map", "odom")
        candidates = estimates.get((transform.header.stamp.sec, transform.header.stamp.nanosec))
        if not candidates:
            continue
        q = transform.transform.rotation
        map_to_odom = (
            transform.transform.translation.x,
            transform.transform.translation.y,
            2.0 * math.atan2(q.z, q.w),
        )
        # the odometry message of that stamp (the feeder's stamps are the match's instants + T0_S)
        k = int(np.argmin(np.abs(match.times_s + T0_S - stamp_to_seconds(transform.header.stamp))))
        x, y, yaw = compose(map_to_odom, tuple(match.odometry[k]))
        position_m, heading_rad = min(
            (
                math.hypot(x - e.pose.pose.position.x, y - e.pose.pose.position.y),
                abs(
                    math.remainder(
                        yaw - 2.0 * math.atan2(e.pose.pose.orientation.z, e.pose.pose.orientation.w),
                        math.tau,
                    )
                ),
            )
            for e in candidates
        )
        assert position_m < 1e-6 and heading_rad < 1e-6, (position_m, heading_rad)
        checked += 1
    assert checked > 20, f"only {checked} of {len(transforms)} transforms matched an estimate"


def test_ekf_node_tracks_and_resets(start_node, rclpy_node, match, total_pose_message):
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from std_srvs.srv import Trigger
    from tf2_msgs.msg import TFMessage

    start_node("beams_ekf", "ekf_node", _params())
    outputs = rclpy_node.subscribe(Odometry, "beams/ekf/odometry")
    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    transforms = rclpy_node.subscribe(TFMessage, "/tf", 100)
    feeder = _Feeder(rclpy_node)

    feeder.play(match, until_s=0.3)
    assert outputs == [], "published before any pose initialised the filter"
    # stamped at its revolution, as ToTal's: the odometry since then brings it to the present
    x, y, yaw = match.truth_at(0.25)
    feeder.total.publish(total_pose_message(T0_S + 0.25, (x + 0.01, y - 0.01, yaw)))
    rclpy_node.spin_for(0.3)
    feeder.play(match, start_s=0.3, until_s=3.0)
    assert rclpy_node.spin_until(lambda: len(outputs) > 20, 10.0), "no estimate published"

    last = outputs[-1]
    assert (last.header.frame_id, last.child_frame_id) == ("map", "base_link")
    assert _error_m(last, match) < 0.01
    variances = [last.pose.covariance[0], last.pose.covariance[7], last.pose.covariance[35]]
    assert all(0.0 < v < 1e-3 for v in variances)
    assert rclpy_node.spin_until(
        lambda: any(
            kv.key == "bearings_accepted" and int(kv.value) > 30
            for d in diagnostics
            for s in d.status
            if "ekf" in s.name
            for kv in s.values
        ),
        5.0,
    )
    # a revolution after the timer published its odometry's instant: the estimate refined at that stamp
    feeder.play(match, start_s=3.0, until_s=3.25, revolutions=False)
    rclpy_node.spin_for(0.2)
    count = len(outputs)
    feeder.play(match, start_s=3.1, until_s=3.25, odometry=False)
    assert rclpy_node.spin_until(lambda: len(outputs) > count, 5.0), "no estimate after the revolutions"
    _assert_map_to_odom_places_the_odometry_on_the_estimate(transforms, outputs, match)

    answer = rclpy_node.call(Trigger, "/ekf_node/reset", Trigger.Request(), 10.0)
    assert answer.success
    rclpy_node.spin_for(0.3)
    count = len(outputs)
    feeder.play(match, start_s=3.25, until_s=3.75)
    rclpy_node.spin_for(0.3)
    assert len(outputs) == count, "published after a reset without a new pose"


def test_ekf_node_takes_an_operator_pose(start_node, rclpy_node, match):
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry

    from beams_msgs.srv import SetPose

    start_node("beams_ekf", "ekf_node", _params())
    outputs = rclpy_node.subscribe(Odometry, "beams/ekf/odometry")
    feeder = _Feeder(rclpy_node)
    feeder.play(match, until_s=0.2)
    pose = PoseWithCovarianceStamped()
    pose.header.frame_id = "map"  # stamp 0: "now" (RViz's /initialpose style)
    x, y, theta = match.truth_at(0.18)
    pose.pose.pose.position.x, pose.pose.pose.position.y = x, y
    pose.pose.pose.orientation.z, pose.pose.pose.orientation.w = math.sin(theta / 2), math.cos(theta / 2)
    reply = rclpy_node.call(SetPose, "/ekf_node/set_pose", SetPose.Request(pose=pose), 10.0)
    assert reply.success, reply.message
    feeder.play(match, start_s=0.2, until_s=2.0)
    assert rclpy_node.spin_until(lambda: len(outputs) > 10, 10.0), "no estimate after set_pose"
    assert _error_m(outputs[-1], match) < 0.01

    wrong_frame = SetPose.Request(pose=pose)
    wrong_frame.pose.header.frame_id = "odom"
    refused = rclpy_node.call(SetPose, "/ekf_node/set_pose", wrong_frame, 10.0)
    assert not refused.success and "odom" in refused.message


@pytest.mark.parametrize(
    ("params", "named"),
    [
        ({"beacon_ids": [1, 2, 3], "beacon_x": [0.0, 1.0], "beacon_y": [0.0, 1.0, 2.0]}, "beacon_x"),
        # each in range, but more gated bearings than the window holds: the filter could never be "lost"
        ({"kidnap_gated_bearings": 13, "kidnap_window_bearings": 12}, "kidnap_gated_bearings"),
    ],
)
def test_ekf_node_refuses_bad_parameters(start_node, params, named):
    node = start_node("beams_ekf", "ekf_node", params)
    assert node.wait_exit(20) == 2
    assert "invalid parameters" in node.log() and named in node.log()
    assert "Traceback" not in node.log()
