"""Refusals at every severity in every order keep the node alive (issue 18: rclpy's "Logger severity
cannot be changed between calls" killed ekf_node after an ERROR refusal then a WARN one, or the reverse).

In-process: a real rclpy node with Diagnostics, in the test's own domain; and one DDS test that plays the
issue's reproduction against the installed ekf_node (reload with an empty calibration_file, then
set_pose with x = NaN: every call answered, the node keeps serving).
"""

import itertools
import math

import pytest

pytestmark = pytest.mark.dds

LEVELS = ("warn", "error")
WAIT_S = 20.0


@pytest.fixture
def diagnostics_node(ros_env):
    rclpy = pytest.importorskip("rclpy", reason="rclpy missing: run the tests through `make test`")
    from beams_common.ros.node_support import Diagnostics

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("refusal_probe", context=context)
    diagnostics = Diagnostics(node, "probe")
    published: list = []
    diagnostics._publisher.publish = published.append  # what /diagnostics would carry, in order
    try:
        yield diagnostics, published
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


@pytest.mark.parametrize("levels", list(itertools.product(LEVELS, repeat=3)), ids="-".join)
@pytest.mark.parametrize("same_key", [True, False], ids=["one key", "keys differ"])
def test_refusals_at_any_severity_in_any_order_are_counted_and_shown(diagnostics_node, levels, same_key):
    diagnostics, published = diagnostics_node
    keys = ["refused_x"] * 3 if same_key else ["refused_a", "refused_b", "refused_c"]
    for round_index in range(2):  # a second round: every site has logged before, at every severity
        for key, level in zip(keys, levels, strict=True):
            diagnostics.refuse(key, f"{level} refusal in round {round_index}", level=level)
        diagnostics.publish()
        status = published[-1].status[0]
        assert status.level == (b"\x02" if "error" in levels else b"\x01")
        assert "refusal" in status.message
    for key in set(keys):
        assert diagnostics.get(key) == 2 * keys.count(key)


def test_a_refusal_of_an_unknown_severity_is_a_programming_error(diagnostics_node):
    diagnostics, _ = diagnostics_node
    with pytest.raises(ValueError, match="'warn' or 'error'"):
        diagnostics.refuse("refused_x", "reason", level="fatal")


def test_a_condition_holds_the_status_until_cleared_whatever_the_node_sets(diagnostics_node):
    diagnostics, published = diagnostics_node
    diagnostics.set_condition("second_publisher", "error", "two publishers on /beams/bearings")
    diagnostics.set_level("ok", "tracking")
    diagnostics.publish()
    assert published[-1].status[0].level == b"\x02"
    assert published[-1].status[0].message.startswith("two publishers on /beams/bearings")
    diagnostics.clear_condition("second_publisher")
    diagnostics.publish()
    assert published[-1].status[0].level == b"\x00" and published[-1].status[0].message == "tracking"


@pytest.mark.parametrize(
    ("own", "condition", "cause_first"),
    [
        ("error", "error", True),  # a serial sensor without its zero reference: no revolution, rate 0 Hz
        ("warn", "warn", True),
        ("error", "warn", True),
        ("warn", "error", False),  # the worse one leads
        ("ok", "warn", False),
        ("ok", "error", False),
    ],
)
def test_the_node_s_own_state_leads_the_conditions_it_is_no_better_than(
    diagnostics_node, own, condition, cause_first
):
    """The cause first: `ros2 topic echo /diagnostics` cuts a long message, and a reader reads its start."""
    diagnostics, published = diagnostics_node
    diagnostics.set_condition("revolution rate", condition, "revolution rate 0.0 Hz, expected 10 Hz")
    diagnostics.set_level(own, "no zero reference for 2.0 s")
    diagnostics.publish()
    status = published[-1].status[0]
    worst = "error" if "error" in (own, condition) else "warn"
    assert status.level == {"warn": b"\x01", "error": b"\x02"}[worst]
    first, second = "no zero reference", "revolution rate"
    if not cause_first:
        first, second = second, first
    assert status.message.startswith(first) and second in status.message, status.message


def test_a_held_condition_ends_by_itself(diagnostics_node):
    diagnostics, published = diagnostics_node
    diagnostics.set_condition("brief", "warn", "for a moment", hold_s=0.0)
    diagnostics.publish()
    assert published[-1].status[0].level == b"\x00"


def test_ekf_node_answers_a_refused_reload_then_a_nan_set_pose_and_keeps_serving(start_node, rclpy_node):
    """The issue's reproduction: an ERROR refusal (reload with no calibration_file) then a WARN one
    (set_pose x = NaN) killed ekf_node before the second answer; now both are answered, then a good
    set_pose is taken and the EKF publishes."""
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from std_srvs.srv import Trigger

    from beams_msgs.srv import SetPose

    node = start_node("beams_ekf", "ekf_node")
    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    outputs = rclpy_node.subscribe(Odometry, "/beams/ekf/odometry")
    for attempt in range(2):  # both orders of the two severities, and again after each
        reload = rclpy_node.call(Trigger, "/ekf_node/reload_calibration", Trigger.Request(), WAIT_S)
        assert not reload.success and "calibration_file parameter is empty" in reload.message
        request = SetPose.Request()
        request.pose.header.frame_id = "map"
        request.pose.pose.pose.position.x = math.nan
        request.pose.pose.pose.orientation.w = 1.0
        answer = rclpy_node.call(SetPose, "/ekf_node/set_pose", request, WAIT_S)
        assert not answer.success and "refused" in answer.message, attempt
        assert node.process.poll() is None, node.log()
    good = SetPose.Request()
    good.pose.header.frame_id = "map"
    good.pose.header.stamp = rclpy_node.node.get_clock().now().to_msg()
    good.pose.pose.pose.position.x, good.pose.pose.pose.position.y = 1.0, 1.0
    good.pose.pose.pose.orientation.w = 1.0
    for index in (0, 7, 35):
        good.pose.pose.covariance[index] = 0.01
    answer = rclpy_node.call(SetPose, "/ekf_node/set_pose", good, WAIT_S)
    assert answer.success, answer.message
    assert rclpy_node.spin_until(lambda: len(outputs) > 0, WAIT_S), node.log()
    assert rclpy_node.spin_until(
        lambda: int(rclpy_node.diagnostic_values("ekf_node").get("calibration_reloads_refused", 0)) == 2,
        WAIT_S,
    ), rclpy_node.diagnostic_values("ekf_node")
    assert "Traceback" not in node.log()
    assert diagnostics


def test_conditions_are_listed_worst_first_and_lasting_before_held(diagnostics_node):
    diagnostics, published = diagnostics_node
    diagnostics.set_condition("slow", "warn", "input slow")
    diagnostics.set_condition("interleaved", "error", "sources interleave", hold_s=60.0)
    diagnostics.set_condition("graph", "error", "2 publishers: /a, /b")
    diagnostics.set_level("ok", "tracking")
    diagnostics.publish()
    status = published[-1].status[0]
    assert status.level == b"\x02"
    assert status.message == "2 publishers: /a, /b; sources interleave; input slow; tracking"


def test_an_error_conditions_end_is_said_at_once_after_the_old_status_again(diagnostics_node):
    """An ERROR condition is said at once when set and, as soon as it ends (cleared, or its hold over),
    the old status is repeated (it closes its span) and the new one follows, not up to a second later."""
    import time

    diagnostics, published = diagnostics_node
    diagnostics.set_level("ok", "tracking")
    diagnostics.set_condition("second_publisher", "error", "2 publishers on /odom")
    assert [s.status[0].level for s in published] == [b"\x02"]  # said at once
    diagnostics.publish_if_conditions_changed()
    assert len(published) == 1  # nothing changed: nothing said
    diagnostics.clear_condition("second_publisher")
    assert [s.status[0].level for s in published[1:]] == [b"\x02", b"\x00"]
    assert published[1].status[0].message == published[0].status[0].message
    assert published[2].status[0].message == "tracking"
    # a held ERROR: its end is found by the next check (the nodes check at every estimate or pose)
    diagnostics.set_condition("interleave", "error", "two sources on /beams/bearings", hold_s=0.05)
    count = len(published)
    diagnostics.publish_if_conditions_changed()
    assert len(published) == count
    time.sleep(0.1)
    diagnostics.publish_if_conditions_changed()
    assert [s.status[0].level for s in published[count:]] == [b"\x02", b"\x00"]
    # a WARN condition's start and end wait for the next tick, as set_condition says only an ERROR at once
    diagnostics.set_condition("slow", "warn", "bearings at 5 Hz")
    count = len(published)
    diagnostics.clear_condition("slow")
    assert len(published) == count
