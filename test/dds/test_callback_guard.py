"""Nothing escapes a callback (issue 18): a fault injected into each kind of callback of a real node.

In-process (the fault is a monkeypatched method), in the test's own domain: the exception is counted
(`callback_exceptions`), /diagnostics turns ERROR with the site, the node's recovery hook runs (ekf_node's
filter re-initialises from the next fix, triangulation_node drops its waiting revolution), a service
caller gets success = False with the reason, a parameter change is refused with it, and the node answers
afterwards. The executor path is exercised too: a message over DDS into a failing subscription, with
the node spinning in the EventsExecutor run_node uses.
"""

import math

import pytest

pytestmark = pytest.mark.dds

ERROR = b"\x02"
WAIT_S = 15.0


class InjectedFaultError(RuntimeError):
    """The fault a test plants in a node's method."""


def fail(*_args, **_kwargs):
    raise InjectedFaultError("injected fault")


@pytest.fixture
def make_node(rclpy_context):
    nodes = []

    def make(node_class):
        node = node_class()
        nodes.append(node)
        # what the node would publish on /diagnostics, in order
        node.published_diagnostics = []
        node.diagnostics._publisher.publish = node.published_diagnostics.append
        return node

    yield make
    for node in nodes:
        node.destroy_node()


def last_status(node):
    node.diagnostics.publish()
    return node.published_diagnostics[-1].status[0]


def subscription(node, topic: str):
    return next(s for s in node.subscriptions if s.topic_name.endswith(topic))


def service(node, name: str):
    return next(s for s in node.services if s.srv_name.endswith(name))


def timer_of(node, method):
    return next(t for t in node.timers if getattr(t.callback, "__wrapped__", None) == method)


def operator_pose(x: float = 1.0, y: float = 1.0):
    from beams_msgs.srv import SetPose

    request = SetPose.Request()
    request.pose.header.frame_id = "map"
    request.pose.pose.pose.position.x, request.pose.pose.pose.position.y = x, y
    request.pose.pose.pose.orientation.w = 1.0
    for index in (0, 7, 35):
        request.pose.pose.covariance[index] = 0.01
    return request


def set_pose(node, request=None):
    from beams_msgs.srv import SetPose

    return service(node, "set_pose").callback(request or operator_pose(), SetPose.Response())


def revolution_message(node, revolution: int = 1):
    """A well-formed revolution stamped now on the node's clock (a stale stamp is refused earlier)."""
    from beams_msgs.msg import BeaconBearing, BeaconBearingArray

    now = node.get_clock().now().to_msg()
    msg = BeaconBearingArray(revolution=revolution, period=0.1)
    msg.header.stamp = now
    for beacon_id, bearing in ((1, 0.5), (2, 2.0), (3, -2.0)):
        b = BeaconBearing(beacon_id=beacon_id, bearing=bearing, variance=1e-6)
        b.header.stamp = now
        msg.bearings.append(b)
    return msg


def assert_fault_shown(node, site_part: str, count: int = 1) -> None:
    assert node.diagnostics.get("callback_exceptions") == count
    assert site_part in node.diagnostics.get("last_callback_exception", "")
    assert "InjectedFaultError: injected fault" in node.diagnostics.get("last_callback_exception", "")
    status = last_status(node)
    assert status.level == ERROR, status.message
    assert "a callback failed" in status.message and site_part in status.message


def test_ekf_subscription_fault_is_counted_shown_and_resets_the_filter(make_node, monkeypatch):
    from beams_ekf.ekf_node import EkfNode

    node = make_node(EkfNode)
    assert set_pose(node).success
    assert node.localiser.estimate() is not None
    monkeypatch.setattr(node.localiser, "on_bearings", fail)
    subscription(node, "beams/bearings").callback(revolution_message(node))  # no exception escapes
    assert_fault_shown(node, "subscription /beams/bearings")
    assert node.localiser.estimate() is None, "the filter re-initialises from the next fix"
    assert node.localiser.stats.counts["resets_after_callback_exception"] == 1
    monkeypatch.undo()
    answer = set_pose(node)  # the node answers afterwards, and takes the next fix
    assert answer.success and node.localiser.estimate() is not None


def test_ekf_service_fault_answers_the_caller_with_the_reason(make_node, monkeypatch):
    from beams_ekf.ekf_node import EkfNode

    node = make_node(EkfNode)
    monkeypatch.setattr(node, "_operator_pose", fail)
    answer = set_pose(node)
    assert answer.success is False
    assert "internal error" in answer.message and "InjectedFaultError" in answer.message
    assert_fault_shown(node, "service /ekf_node/set_pose")
    monkeypatch.undo()
    assert set_pose(node).success


def test_ekf_timer_fault_is_counted_and_the_next_tick_runs(make_node, monkeypatch):
    from beams_ekf.ekf_node import EkfNode

    node = make_node(EkfNode)
    assert set_pose(node).success
    publish_tick = timer_of(node, node._publish)
    monkeypatch.setattr(node.localiser, "estimate", fail)
    publish_tick.callback()
    publish_tick.callback()
    assert_fault_shown(node, "timer", count=2)
    monkeypatch.undo()
    publish_tick.callback()  # runs again, without a fault
    assert node.diagnostics.get("callback_exceptions") == 2


def test_ekf_parameter_callback_fault_refuses_the_change_with_the_reason(make_node, monkeypatch):
    """A fault while the change is prepared (the on-set callback): refused with the reason."""
    from rclpy.parameter import Parameter

    import beams_ekf.ekf_node

    node = make_node(beams_ekf.ekf_node.EkfNode)
    monkeypatch.setattr(beams_ekf.ekf_node, "runtime_geometry", fail)
    [result] = node.set_parameters([Parameter("gate_probability", value=0.99)])
    assert not result.successful
    assert "internal error" in result.reason and "InjectedFaultError" in result.reason
    assert_fault_shown(node, "parameter change")
    monkeypatch.undo()
    [result] = node.set_parameters([Parameter("gate_probability", value=0.99)])
    assert result.successful, result.reason


def test_ekf_post_set_fault_is_counted_and_resets_the_filter(make_node, monkeypatch):
    """A fault while an accepted change is applied (the post-set callback, after rclpy set the value):
    counted, shown, the filter reset (its settings may be half-applied); the next change applies."""
    from rclpy.parameter import Parameter

    from beams_ekf.ekf_node import EkfNode

    node = make_node(EkfNode)
    assert set_pose(node).success
    monkeypatch.setattr(node.localiser, "configure", fail)
    node.set_parameters([Parameter("gate_probability", value=0.99)])
    assert_fault_shown(node, "parameter post-set")
    assert node.localiser.estimate() is None
    monkeypatch.undo()
    [result] = node.set_parameters([Parameter("gate_probability", value=0.995)])
    assert result.successful, result.reason
    assert node.diagnostics.get("callback_exceptions") == 1


def test_triangulation_fault_drops_the_waiting_revolution_and_keeps_publishing(make_node, monkeypatch):
    from beams_triangulation.triangulation_node import TriangulationNode

    node = make_node(TriangulationNode)
    before = node.pipeline
    monkeypatch.setattr(node.pipeline, "on_intake", fail)
    subscription(node, "beams/bearings").callback(revolution_message(node))
    assert_fault_shown(node, "subscription /beams/bearings")
    assert node.pipeline is not before, "a new pipeline: no waiting revolution, no odometry history"
    assert node.pipeline.settings == before.settings


def test_sim_world_and_driver_timer_faults_are_caught(make_node, monkeypatch):
    from beams_driver.driver_node import DriverNode
    from beams_sim.sim_world_node import SimWorldNode

    world = make_node(SimWorldNode)
    tick = timer_of(world, world._tick)
    monkeypatch.setattr(world, "_publish_truth", fail)
    tick.callback()
    assert_fault_shown(world, "timer")
    driver = make_node(DriverNode)
    poll = timer_of(driver, driver._poll)
    monkeypatch.setattr(driver.source, "poll", fail)
    poll.callback()
    assert_fault_shown(driver, "timer")


def test_a_fault_in_a_dds_delivered_message_leaves_the_spinning_node_serving(make_node, monkeypatch):
    """Through the executor run_node uses: a message over DDS into a failing subscription, then a
    service call over DDS, answered."""
    import rclpy
    from rclpy.experimental import EventsExecutor

    from beams_ekf.ekf_node import EkfNode
    from beams_msgs.msg import BeaconBearingArray
    from beams_msgs.srv import SetPose

    node = make_node(EkfNode)
    monkeypatch.setattr(node.localiser, "on_bearings", fail)
    probe = rclpy.create_node("guard_probe")
    executor = EventsExecutor()
    executor.add_node(node)
    executor.add_node(probe)
    try:
        publisher = probe.create_publisher(BeaconBearingArray, "beams/bearings", 10)
        client = probe.create_client(SetPose, "ekf_node/set_pose")
        deadline = _deadline()
        while node.diagnostics.get("callback_exceptions") == 0 and not _past(deadline):
            publisher.publish(revolution_message(node))
            executor.spin_once(timeout_sec=0.1)
        assert node.diagnostics.get("callback_exceptions") >= 1
        monkeypatch.undo()
        assert client.wait_for_service(timeout_sec=WAIT_S)
        future = client.call_async(operator_pose())
        deadline = _deadline()
        while not future.done() and not _past(deadline):
            executor.spin_once(timeout_sec=0.1)
        assert future.done() and future.result().success, "the node answers after the fault"
    finally:
        executor.shutdown()
        probe.destroy_node()


def test_an_async_service_fault_is_answered_too(make_node):
    """calibration_node's services are coroutines: the guard awaits them inside itself."""
    import asyncio

    from std_srvs.srv import Trigger

    from beams_calibration.calibration_node import CalibrationNode

    node = make_node(CalibrationNode)

    async def failing(_request, _response):
        raise InjectedFaultError("injected fault")

    guarded = node.guard_callback("service probe", failing, on_failure=lambda reason, *_: reason)
    assert "InjectedFaultError" in asyncio.run(guarded(Trigger.Request(), Trigger.Response()))
    assert_fault_shown(node, "service probe")


def test_the_repeated_fault_is_logged_with_its_traceback_once(make_node, monkeypatch, capfd):
    from beams_ekf.ekf_node import EkfNode

    node = make_node(EkfNode)
    monkeypatch.setattr(node, "_operator_pose", fail)
    for _ in range(5):
        assert not set_pose(node).success
    err = capfd.readouterr().err
    assert err.count("Traceback") == 1, err
    assert node.diagnostics.get("callback_exceptions") == 5
    assert math.isfinite(node.diagnostics.CALLBACK_FAULT_HOLD_S)


def _deadline() -> float:
    import time

    return time.monotonic() + WAIT_S


def _past(deadline: float) -> bool:
    import time

    return time.monotonic() > deadline


def test_a_failing_diagnostics_publication_does_not_escape_either(make_node, monkeypatch):
    """The guard shows a failure on /diagnostics, at once: when that publication fails too (the fault
    is in Diagnostics itself), the second exception stays inside the guard."""
    from beams_ekf.ekf_node import EkfNode

    node = make_node(EkfNode)
    monkeypatch.setattr(node.diagnostics._publisher, "publish", fail)
    monkeypatch.setattr(node, "_operator_pose", fail)
    answer = set_pose(node)  # the fault, then its ERROR published at once: that fails too
    assert answer.success is False and "InjectedFaultError" in answer.message
    assert node.diagnostics.get("callback_exceptions") >= 1
    monkeypatch.undo()
    node.diagnostics._publisher.publish = node.published_diagnostics.append
    assert set_pose(node).success
