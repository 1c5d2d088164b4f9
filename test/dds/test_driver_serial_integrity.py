"""driver_node's serial source under faults of the link (issue 18), over DDS with a pseudo-terminal as the
device: the optical switch unplugged (edges and heartbeats arrive, no zero reference) is an ERROR on
/diagnostics with the reason, and bearings come back with it; line noise (0.1 % of the bytes) costs
only the revolutions it touches (or only the beacon windows, lost_frames_cost "window"), is no baud-rate
problem, and never a wrong bearing."""

import threading
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_driver.serial_protocol import TIMER_HZ, EventKind, FrameEncoder
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator

pytestmark = pytest.mark.dds

WAIT_S = 20.0
POSE = (1.2, 0.8, 0.3)


def driver_statuses(diagnostics) -> list:
    return [status for message in diagnostics for status in message.status if "driver_node" in status.name]


def sensor_stream(
    seed: int, zero_reference: Callable[[int], bool], byte_error_rate: float = 0.0
) -> Iterator[bytes]:
    """The simulated sensor's frames, one revolution per chunk; the zero reference of revolution k is
    sent when zero_reference(k); a fraction byte_error_rate of the bytes replaced by random ones."""
    config = SensorSimConfig()
    simulator = SensorSimulator(config, EUROBOT_BEACON_MAP, np.random.default_rng(seed))
    rng = np.random.default_rng(seed + 1)
    encoder = FrameEncoder()
    for k in range(100_000):
        edges = simulator.revolution(lambda _t: POSE, k * config.period_s)
        if zero_reference(k):
            data = encoder.revolution(edges)
        else:
            data = b"".join(
                encoder.event(EventKind.RISING if rising else EventKind.FALLING, round(t * TIMER_HZ))
                for t, rising in zip(edges.edge_times_s, edges.edge_rising, strict=True)
            )
        if byte_error_rate:
            damaged = np.frombuffer(data, dtype=np.uint8).copy()
            hit = rng.random(len(damaged)) < byte_error_rate
            damaged[hit] = rng.integers(0, 256, int(hit.sum()))
            data = damaged.tobytes()
        yield data


def test_no_zero_reference_is_an_error_and_bearings_return_with_it(rclpy_node, start_node, streaming_pty):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    from beams_msgs.msg import BeaconBearingArray

    switch_on = threading.Event()
    switch_on.set()
    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    bearings = rclpy_node.subscribe(BeaconBearingArray, "beams/bearings")
    with streaming_pty(sensor_stream(50, lambda _k: switch_on.is_set())) as device:
        node = start_node(
            "beams_driver",
            "driver_node",
            params={"source": "serial", "device": device, "zero_reference_timeout_s": 0.5},
        )
        assert rclpy_node.spin_until(lambda: len(bearings) >= 5, WAIT_S), node.log()
        switch_on.clear()  # the optical switch unplugged: edges and heartbeats still arrive
        rclpy_node.spin_for(0.3)
        published_before = len(bearings)
        before = len(diagnostics)

        # the cause leads the message once it is said, the revolution rate's condition after it (the order:
        # test_diagnostics_refusals.py); a starved node's first ERROR may be the rate's alone (make test's
        # DDS tier on 3 workers, once)
        def cause_reported() -> list:
            return [
                s
                for s in driver_statuses(diagnostics[before:])
                if s.level == DiagnosticStatus.ERROR and "no zero reference for " in s.message
            ]

        assert rclpy_node.spin_until(cause_reported, WAIT_S), node.log()
        rclpy_node.spin_for(1.0)
        assert len(bearings) == published_before, "bearings published without a zero reference"
        for status in cause_reported():
            assert status.message.startswith("no zero reference for "), status.message
            assert "turret stopped or switch unplugged (the turret's frames still arrive)" in status.message
        switch_on.set()
        back = len(diagnostics)
        assert rclpy_node.spin_until(lambda: len(bearings) >= published_before + 5, WAIT_S), node.log()
        assert rclpy_node.spin_until(
            lambda: (
                driver_statuses(diagnostics[back:])
                and driver_statuses(diagnostics[back:])[-1].level != DiagnosticStatus.ERROR
            ),
            WAIT_S,
        ), driver_statuses(diagnostics)[-1].message
        assert node.process.poll() is None
    values = rclpy_node.diagnostic_values("driver_node")
    assert int(values["serial_drops_bad_revolution_period"]) >= 1  # the one the silence spanned
    assert all(len(message.bearings) == 3 for message in bearings[published_before + 1 :])


@pytest.mark.parametrize("cost", ["revolution", "window"])
def test_line_noise_costs_only_the_revolutions_or_windows_it_touches(
    rclpy_node, start_node, cost, streaming_pty
):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    from beams_msgs.msg import BeaconBearingArray

    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    bearings = rclpy_node.subscribe(BeaconBearingArray, "beams/bearings")
    with streaming_pty(sensor_stream(51, lambda _k: True, byte_error_rate=0.001)) as device:
        params = {"source": "serial", "device": device, "lost_frames_cost": cost}
        node = start_node("beams_driver", "driver_node", params=params)
        assert rclpy_node.spin_until(lambda: len(bearings) >= 25, WAIT_S), node.log()
        assert node.process.poll() is None
    statuses = driver_statuses(diagnostics)
    assert not [s.message for s in statuses if s.level == DiagnosticStatus.ERROR]
    assert any(s.level == DiagnosticStatus.WARN and "lost" in s.message for s in statuses)
    values = rclpy_node.diagnostic_values("driver_node")
    assert int(values["serial_drops_lost_frames"]) >= 1
    if cost == "window":  # revolutions with lost frames published, some with fewer than 3 bearings
        assert int(values["serial_drops_revolution_with_lost_frames"]) >= 1
        assert any(len(message.bearings) < 3 for message in bearings)
    else:
        assert "serial_drops_revolution_with_lost_frames" not in values
        assert int(values["serial_drops_revolution_with_gap"]) >= 1
    # the published revolutions are whole: every bearing of the fixed robot within 5 sigma of the others
    # of its beacon (a wrong revolution would be 0.01-0.07 rad off)
    by_beacon: dict[int, list[tuple[float, float]]] = {}
    for message in bearings:
        for bearing in message.bearings:
            by_beacon.setdefault(bearing.beacon_id, []).append((bearing.bearing, bearing.variance))
    assert sorted(by_beacon) == [1, 2, 3]
    for values_of_beacon in by_beacon.values():
        angles = np.array([angle for angle, _ in values_of_beacon])
        sigmas = np.sqrt([variance for _, variance in values_of_beacon])
        assert np.all(np.abs(angles - np.median(angles)) <= 5.0 * sigmas), angles
