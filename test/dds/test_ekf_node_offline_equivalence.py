"""ekf_node's own intake and the offline driver of the benches and the thesis's figures
(`beams_thesis.replay.replay`, bench_ekf's) give the same estimates from the same messages: both go
through the Localiser's three doors, with the same intakes, so the offline figures are the node's.

In-process, in the test's own domain: the node's callbacks are called directly with the messages (its
receiving clock set to each message's arrival), the offline driver gets the same messages decoded as
the node decodes them.
"""

from itertools import groupby

import numpy as np
import pytest

pytestmark = pytest.mark.dds

START_COVARIANCE = np.diag([1e-4, 1e-4, 1e-3])
FIX_COVARIANCE = np.diag([1e-4, 1e-4, 1e-4])
FIX_DELAY_S = 0.01  # a ToTal fix arrives this long after its revolution's bearings


def _messages(match):
    """The match as the node's topics carry it: odometry, one beams/bearings per revolution, ToTal's
    accepted fix of each revolution (the truth at its middle, off by a few mm), an operator's start."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry

    from beams_common.interfaces.bearing_messages import BearingFields, nanoseconds
    from beams_common.ros.messages import (
        bearing_array,
        ros_covariance,
        seconds_to_stamp,
        set_pose2d,
        stamp_to_seconds,
    )
    from beams_msgs.msg import TriangulatedPose

    def pose_message(message, stamp_s, pose, covariance):
        message.header.stamp, message.header.frame_id = seconds_to_stamp(stamp_s), "map"
        set_pose2d(message.pose.pose, pose)
        message.pose.covariance = ros_covariance(covariance)
        return message

    odometry = []
    for t, pose in zip(match.times_s, match.odometry, strict=True):
        message = Odometry()
        message.header.stamp = seconds_to_stamp(float(t))
        set_pose2d(message.pose.pose, tuple(pose))
        odometry.append((stamp_to_seconds(message.header.stamp), message))  # as both decode it
    rng = np.random.default_rng(4)
    revolutions, fixes = [], []
    for arrival_s, group in groupby(match.bearings, key=lambda b: b.arrival_s):
        fields = [
            BearingFields(nanoseconds(b.stamp_s), b.beacon_id, b.bearing_rad, b.variance_rad2) for b in group
        ]
        revolutions.append((arrival_s, bearing_array(nanoseconds(arrival_s - 0.1), fields, period_s=0.1)))
        stamp_s = arrival_s - 0.05
        fix = tuple(np.add(match.truth_at(stamp_s), rng.normal(0.0, 0.003, 3)))
        message = pose_message(TriangulatedPose(), stamp_s, fix, FIX_COVARIANCE)
        message.accepted = True
        fixes.append((arrival_s + FIX_DELAY_S, message))
    start = (np.add(match.truth[0], (0.01, -0.01, 0.01)), START_COVARIANCE)
    initial = pose_message(PoseWithCovarianceStamped(), float(match.times_s[0]), *start)
    return odometry, revolutions, fixes, initial


def _node_estimates(node, odometry, revolutions, fixes, initial):
    """The messages through the node's callbacks in arrival order (replay's: at one instant the odometry
    up to it, then the bearings, then the fixes); the estimate after each instant."""
    from beams_common.ros.messages import odometry_sample

    clock = {"now_s": 0.0}
    node._now_s = lambda: clock["now_s"]
    node._operator_pose(initial)
    arrivals = sorted(
        [(a, 0, m) for a, m in revolutions] + [(a, 1, m) for a, m in fixes], key=lambda e: e[:2]
    )
    estimates, k = [], 0
    for arrival_s, group in groupby(arrivals, key=lambda e: e[0]):
        while k < len(odometry) and odometry[k][0] <= arrival_s:
            clock["now_s"] = odometry[k][0]
            node._on_odometry(odometry_sample(odometry[k][1]))  # as the raw subscription reads it
            k += 1
        clock["now_s"] = arrival_s
        for _, kind, message in group:
            (node._on_bearings if kind == 0 else node._on_total_pose)(message)
        estimate = node.localiser.estimate()
        estimates.append((estimate.stamp_s, *estimate.pose, *estimate.covariance.ravel()))
    return np.array(estimates)


def _offline_result(node, match, odometry, revolutions, fixes, initial):
    """The same messages, decoded as the node decodes them, through beams_thesis.replay (the benches')."""
    from beams_common.geometry.bearing import bearings_of_message
    from beams_common.intake.pose_intake import PoseSource, pose_message_intake
    from beams_common.ros.messages import pose2d_of, stamp_to_seconds
    from beams_ekf.localiser import build_localiser
    from beams_thesis.replay import PoseEvent, replay
    from beams_thesis.synthetic import BearingEvent

    def kept(source, message):
        return pose_message_intake(source, "map", "map", stamp_to_seconds(message.header.stamp), message.pose)

    times = np.array([stamp_to_seconds(m.header.stamp) for _, m in odometry])
    poses = np.array([pose2d_of(m.pose.pose) for _, m in odometry])
    bearings = [
        BearingEvent(arrival_s, b.stamp_s, b.beacon_id, b.bearing_rad, b.variance_rad2, b.angular_window_rad)
        for arrival_s, message in revolutions
        for b in bearings_of_message(message, stamp_to_seconds)
    ]
    pose_events = [
        PoseEvent(a, (fix := kept(PoseSource.TOTAL, m)).stamp_s, fix.pose, fix.covariance) for a, m in fixes
    ]
    start = kept(PoseSource.OPERATOR, initial)
    geometry = node.geometry
    localiser = build_localiser(geometry.beacon_map.as_dict(), geometry.turret_offset_m, node.settings)
    return replay(
        localiser, times, poses, bearings, match.truth_at, start.pose, start.covariance, pose_events
    )


def test_the_node_s_intake_and_the_offline_replay_give_the_same_estimates(rclpy_context):
    from beams_ekf.ekf_node import EkfNode
    from beams_thesis.synthetic import synthetic_match

    match = synthetic_match(6.0, seed=3)
    messages = _messages(match)
    node = EkfNode()
    try:
        live = _node_estimates(node, *messages)
        offline = _offline_result(node, match, *messages)
        counts = dict(node.localiser.stats.counts)
    finally:
        node.destroy_node()
    assert len(live) == len(offline.times_s) == len(messages[1]) + len(messages[2])
    np.testing.assert_allclose(live[:, 0], offline.times_s, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(live[:, 1:4], offline.estimates, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(live[:, 4:], offline.covariances.reshape(len(live), 9), rtol=0.0, atol=1e-12)
    assert counts == offline.counts
    # the fixes reached the pose door (kept, ignored while the filter tracks) and the bearings were used
    assert counts["bearings_accepted"] > 0.95 * len(match.bearings)
    assert counts["initialisations"] == 1
