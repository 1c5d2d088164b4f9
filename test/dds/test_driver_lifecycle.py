"""driver_node as a managed (lifecycle) node, driven over DDS through its lifecycle services
(lifecycle_msgs/srv/ChangeState and GetState: what `ros2 lifecycle set/get` call), issue 14.

With `autostart: false` the node waits unconfigured; configure opens nothing (the serial pty is not in
the process's open files), activate opens the port and publishes, deactivate stops the bearings,
cleanup releases the port, shutdown from any state releases everything and the process lives on until
stopped. A bad parameter makes configure fail with its reason and the node stays alive; a transition the
state does not offer is refused. The default (autostart) publishes as before and reports `active`.
"""

import contextlib
import os
import pathlib
import signal
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP

WAIT_S = 20.0
QUIET_S = 1.5  # no bearing may arrive for this long after a deactivation
SETTLE_S = 0.3  # bearings already in flight when the transition answered
STATIC_POSE = [1.0, 1.2, 0.4]
# A serial stamp maps the device's clock onto the host's (least-delay offset): a revolution begun after
# the activation may be stamped up to about a turret period before it.
SERIAL_STAMP_TOLERANCE_S = 0.3


class Managed:
    """The driver's lifecycle services, the bearings it publishes and its process."""

    def __init__(self, rclpy_node, node) -> None:
        from beams_msgs.msg import BeaconBearingArray

        self.graph = rclpy_node
        self.node = node
        self.bearings = rclpy_node.subscribe(BeaconBearingArray, "beams/bearings")

    def state(self) -> str:
        from lifecycle_msgs.srv import GetState

        return self.graph.call(
            GetState, "/driver_node/get_state", GetState.Request(), WAIT_S
        ).current_state.label

    def change(self, label: str) -> bool:
        """The transition by its label, as `ros2 lifecycle set /driver_node <label>` asks for it."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        request = ChangeState.Request(transition=Transition(label=label))
        return self.graph.call(ChangeState, "/driver_node/change_state", request, WAIT_S).success

    def change_by_id(self, transition_id: int) -> bool:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        request = ChangeState.Request(transition=Transition(id=transition_id))
        return self.graph.call(ChangeState, "/driver_node/change_state", request, WAIT_S).success

    def bearings_arrive(self, count: int = 3) -> bool:
        start = len(self.bearings)
        return self.graph.spin_until(lambda: len(self.bearings) >= start + count, WAIT_S)

    def quiet(self) -> bool:
        """No bearing for QUIET_S after those already sent settle."""
        self.graph.spin_for(SETTLE_S)
        start = len(self.bearings)
        self.graph.spin_for(QUIET_S)
        return len(self.bearings) == start

    def holds(self, path: str) -> bool:
        """Whether the node's process has path open (its /proc/<pid>/fd links)."""
        fd_dir = pathlib.Path(f"/proc/{self.node.process.pid}/fd")
        held = []
        for link in fd_dir.iterdir():
            try:
                held.append(os.readlink(link))
            except OSError:  # an fd closed while listing
                continue
        return path in held


def stamp_s(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


@pytest.fixture
def sensor_pty() -> Iterator[tuple[str, threading.Event]]:
    """A pty streaming the simulated sensor's frames at 10 revolutions per second, as the sensor's
    microcontroller does; bytes nobody reads are dropped when the pty's buffer is full."""
    from beams_driver.serial_protocol import FrameEncoder
    from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator

    master, slave = os.openpty()
    os.set_blocking(master, False)
    config = SensorSimConfig()
    simulator = SensorSimulator(config, EUROBOT_BEACON_MAP, np.random.default_rng(5))
    encoder = FrameEncoder()
    stop = threading.Event()
    pose = tuple(STATIC_POSE)

    def device() -> None:
        k = 0
        start = time.monotonic()
        while not stop.is_set():
            chunk = encoder.revolution(simulator.revolution(lambda _t: pose, k * config.period_s))
            # nobody reads (the driver is not active): the sensor's bytes are lost
            with contextlib.suppress(BlockingIOError):
                os.write(master, chunk)
            k += 1
            stop.wait(max(0.0, start + k * config.period_s - time.monotonic()))

    writer = threading.Thread(target=device, daemon=True)
    writer.start()
    try:
        yield os.ttyname(slave), stop
    finally:
        stop.set()
        writer.join(timeout=10)
        os.close(master)
        os.close(slave)


def test_serial_driver_walks_the_lifecycle_and_opens_the_port_only_while_configured_and_active(
    rclpy_node, start_node, sensor_pty
):
    device, _ = sensor_pty
    node = start_node(
        "beams_driver", "driver_node", params={"autostart": False, "source": "serial", "device": device}
    )
    driver = Managed(rclpy_node, node)
    assert driver.state() == "unconfigured"
    assert not driver.holds(device) and driver.quiet()

    # configure: validated, the decoder built, the port still closed
    assert driver.change("configure")
    assert driver.state() == "inactive"
    assert not driver.holds(device), "configure opened the serial device"
    assert driver.quiet()

    # activate: the port opened, the bearings arrive
    assert driver.change("activate")
    assert driver.state() == "active"
    assert driver.bearings_arrive(5), node.log()
    assert driver.holds(device)
    assert all(len(msg.bearings) == 3 for msg in driver.bearings[-3:])

    # deactivate: no more bearings; the port stays open for the next activation
    assert driver.change("deactivate")
    assert driver.state() == "inactive"
    assert driver.quiet(), f"{len(driver.bearings)} bearings after the deactivation"
    assert driver.holds(device)

    # activate again: what the sensor sent while inactive is not published as if it were new
    count = len(driver.bearings)
    activated_s = time.time()
    assert driver.change("activate")
    assert driver.bearings_arrive(5), node.log()
    earliest = min(stamp_s(msg) for msg in driver.bearings[count:])
    assert earliest > activated_s - SERIAL_STAMP_TOLERANCE_S, (earliest, activated_s)

    # cleanup: the port released, nothing published
    assert driver.change("deactivate") and driver.change("cleanup")
    assert driver.state() == "unconfigured"
    assert not driver.holds(device), "cleanup left the serial device open"
    assert f"serial device {device} released" in node.log()
    assert driver.quiet()

    # configured and active once more (the port reopened), then shut down from active
    assert driver.change("configure") and driver.change("activate")
    assert driver.bearings_arrive(3), node.log()
    assert driver.change("shutdown")
    assert driver.state() == "finalized"
    assert not driver.holds(device) and driver.quiet()
    assert node.process.poll() is None, "the node process ended at shutdown"
    assert node.log().count(f"serial device {device} released") == 2
    assert "Traceback" not in node.log()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_signal_while_inactive_releases_the_port_and_exits_0(rclpy_node, start_node, sensor_pty, sig):
    device, _ = sensor_pty
    node = start_node(
        "beams_driver", "driver_node", params={"autostart": False, "source": "serial", "device": device}
    )
    driver = Managed(rclpy_node, node)
    assert driver.change("configure") and driver.change("activate") and driver.change("deactivate")
    assert driver.holds(device)
    node.assert_clean_exit(sig)
    assert f"serial device {device} released" in node.log()


def test_simulated_driver_drops_the_revolutions_of_its_inactive_time_and_releases_its_subscription(
    rclpy_node, start_node
):
    """The simulation catches up on the revolutions it missed (under 1 s); after a re-activation none of
    them is published. The ground-truth subscription exists only while the source does."""
    node = start_node("beams_driver", "driver_node", params={"autostart": False})
    driver = Managed(rclpy_node, node)
    truth_topic = "/beams/sim/ground_truth"

    def truth_subscribers() -> int:
        return rclpy_node.node.count_subscribers(truth_topic)

    assert driver.change("configure")
    rclpy_node.spin_for(1.0)
    assert truth_subscribers() == 0, "configure started the simulation"
    assert driver.change("activate")
    assert rclpy_node.spin_until(lambda: truth_subscribers() == 1, WAIT_S)

    # a static pose would publish; following the (absent) ground truth, nothing is published
    assert driver.quiet()
    assert driver.change("deactivate") and driver.change("cleanup")
    assert rclpy_node.spin_until(lambda: truth_subscribers() == 0, WAIT_S), "the pose subscription stayed"
    assert driver.change("shutdown") and driver.state() == "finalized"


def test_simulated_driver_reactivated_publishes_only_new_revolutions(rclpy_node, start_node):
    node = start_node(
        "beams_driver", "driver_node", params={"autostart": False, "sim_static_pose": STATIC_POSE}
    )
    driver = Managed(rclpy_node, node)
    assert driver.change("configure") and driver.change("activate")
    assert driver.bearings_arrive(5), node.log()
    assert driver.change("deactivate")
    rclpy_node.spin_for(0.6)  # under the simulation's 1 s catch-up: it would fill the gap
    count = len(driver.bearings)
    activated_s = time.time()
    assert driver.change("activate")
    assert driver.bearings_arrive(5), node.log()
    stamps = [stamp_s(msg) for msg in driver.bearings[count:]]
    assert min(stamps) >= activated_s, (
        f"a revolution begun {activated_s - min(stamps):.3f} s before activation"
    )
    # the revolution counter shows no missing revolution after the first new one
    revolutions = [msg.revolution for msg in driver.bearings[count:]]
    assert revolutions == list(range(revolutions[0], revolutions[0] + len(revolutions)))


def test_a_bad_parameter_makes_configure_fail_and_the_node_stays_unconfigured(rclpy_node, start_node):
    node = start_node("beams_driver", "driver_node", params={"autostart": False, "min_complete_codes": 0})
    driver = Managed(rclpy_node, node)
    assert driver.state() == "unconfigured"
    assert not driver.change("configure")
    assert driver.state() == "unconfigured"
    assert rclpy_node.spin_until(
        lambda: "configure failed: min_complete_codes = 0 is below its minimum 1" in node.log(), WAIT_S
    ), node.log()
    # a transition the state does not offer is refused, not fatal (2: cleanup, 3: activate)
    assert not driver.change_by_id(3) and not driver.change_by_id(2)
    assert driver.state() == "unconfigured" and node.process.poll() is None
    assert driver.change("shutdown") and driver.state() == "finalized"
    assert "Traceback" not in node.log()


def test_a_source_that_cannot_start_makes_activate_fail_and_the_node_stays_inactive(
    rclpy_node, start_node, tmp_path
):
    device = str(tmp_path / "ttyBEAMS")  # not there yet: plugged in later
    node = start_node(
        "beams_driver", "driver_node", params={"autostart": False, "source": "serial", "device": device}
    )
    driver = Managed(rclpy_node, node)
    assert driver.change("configure"), "configure must not open the device"
    assert not driver.change("activate")
    assert driver.state() == "inactive"
    assert rclpy_node.spin_until(lambda: "activate failed: source serial" in node.log(), WAIT_S), node.log()
    master, slave = os.openpty()
    try:
        os.symlink(os.ttyname(slave), device)  # the sensor plugged in: a udev-style link
        assert driver.change("activate"), node.log()
        assert driver.state() == "active"
        assert driver.change("shutdown") and driver.state() == "finalized"
        assert f"serial device {device} released" in node.log()
    finally:
        os.close(master)
        os.close(slave)
    assert "Traceback" not in node.log()


def test_autostart_by_default_publishes_at_once_and_is_read_only(rclpy_node, start_node):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    node = start_node("beams_driver", "driver_node", params={"sim_static_pose": STATIC_POSE})
    driver = Managed(rclpy_node, node)
    assert driver.bearings_arrive(5), node.log()
    assert driver.state() == "active"
    value = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=False)
    request = SetParameters.Request(parameters=[Parameter(name="autostart", value=value)])
    (result,) = rclpy_node.call(SetParameters, "/driver_node/set_parameters", request, WAIT_S).results
    assert not result.successful and "read-only" in result.reason


def test_a_destroyed_driver_node_leaves_the_graph(rclpy_context):
    """In one process (the one-process robot, in-process tests): rclpy's LifecycleNode keeps its node while
    its state machine lives; driver_node's destroy_node releases both, so the node leaves the graph."""
    from beams_driver.driver_node import DriverNode

    driver = DriverNode()
    observer = rclpy_context.create_node("observer")

    def in_graph() -> bool:
        rclpy_context.spin_once(observer, timeout_sec=0.05)
        return "driver_node" in observer.get_node_names()

    end = time.monotonic() + WAIT_S
    while not in_graph() and time.monotonic() < end:
        pass
    assert in_graph(), "driver_node never appeared in the graph"
    driver.destroy_node()
    end = time.monotonic() + 5.0
    while in_graph() and time.monotonic() < end:
        pass
    assert not in_graph(), "driver_node still in the graph 5 s after destroy_node"
    observer.destroy_node()
