"""driver_node and the turret's protocol version (issue 20), over DDS with a pseudo-terminal as the device:
the old firmware's v1 stream is an ERROR naming the fix, frames the firmware lost are counted and warned
on /diagnostics, and the bearings keep coming from the revolutions they spared."""

import numpy as np

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_driver.serial_protocol import (
    TICKS_PER_REVOLUTION,
    TIMER_HZ,
    V1_STREAM_PROBLEM,
    EventKind,
    FrameEncoder,
    encode_v1_frame,
)
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator

WAIT_S = 20.0
POSE = (1.2, 0.8, 0.3)


def driver_statuses(diagnostics, level: int, text: str) -> list:
    return [
        status
        for message in diagnostics
        for status in message.status
        if "driver_node" in status.name and status.level == level and text in status.message
    ]


def test_old_firmware_stream_is_an_error_naming_the_protocol(rclpy_node, start_node, streaming_pty):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    from beams_msgs.msg import BeaconBearingArray

    rng = np.random.default_rng(40)

    def v1_revolution(k: int) -> bytes:  # what the v1 firmware sent: 8-byte frames, a 16-bit timer
        ticks = np.sort(rng.integers(k * TICKS_PER_REVOLUTION, (k + 1) * TICKS_PER_REVOLUTION, 60))
        return b"".join(encode_v1_frame(1 + i % 2, i, int(t)) for i, t in enumerate(ticks))

    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    bearings = rclpy_node.subscribe(BeaconBearingArray, "beams/bearings")
    with streaming_pty(v1_revolution(k) for k in range(1000)) as device:
        node = start_node("beams_driver", "driver_node", params={"source": "serial", "device": device})
        reported = rclpy_node.spin_until(
            lambda: driver_statuses(diagnostics, DiagnosticStatus.ERROR, "protocol v1"), WAIT_S
        )
        assert reported, node.log()
        rclpy_node.spin_for(1.0)
        assert node.process.poll() is None
    (status, *_) = driver_statuses(diagnostics, DiagnosticStatus.ERROR, "protocol v1")
    assert status.message.endswith(V1_STREAM_PROBLEM)
    assert bearings == []
    assert V1_STREAM_PROBLEM in node.log()


def test_frames_the_firmware_lost_are_warned_and_counted(rclpy_node, start_node, streaming_pty):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    from beams_msgs.msg import BeaconBearingArray

    config = SensorSimConfig()
    simulator = SensorSimulator(config, EUROBOT_BEACON_MAP, np.random.default_rng(41))
    encoder = FrameEncoder()

    def revolution(k: int) -> bytes:  # every tenth revolution loses 5 edges in the firmware's queue
        edges = simulator.revolution(lambda _t: POSE, k * config.period_s)
        out = encoder.event(EventKind.ZERO_REFERENCE, round(edges.start_time_s * TIMER_HZ))
        for index, (time_s, rising) in enumerate(zip(edges.edge_times_s, edges.edge_rising, strict=True)):
            kind = EventKind.RISING if rising else EventKind.FALLING
            out += encoder.event(kind, round(time_s * TIMER_HZ), lost=k % 10 == 5 and index < 5)
        return out

    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    bearings = rclpy_node.subscribe(BeaconBearingArray, "beams/bearings")
    with streaming_pty(revolution(k) for k in range(1000)) as device:
        params = {"source": "serial", "device": device, "lost_frames_cost": "revolution"}  # whole ones
        node = start_node("beams_driver", "driver_node", params=params)
        warned = rclpy_node.spin_until(
            lambda: driver_statuses(diagnostics, DiagnosticStatus.WARN, "lost") and len(bearings) >= 20,
            WAIT_S,
        )
        assert warned, node.log()
    values = rclpy_node.diagnostic_values("driver")
    assert int(values["serial_drops_lost_frames"]) >= 5
    assert int(values["serial_drops_lost_frames"]) % 5 == 0
    assert int(values["serial_device_timer_hz"]) == TIMER_HZ
    assert int(values["serial_drops_revolution_with_gap"]) >= 1
    # the revolutions that lost edges (one in ten) are not published; the others are
    published = {message.revolution for message in bearings}
    missing = set(range(min(published), max(published) + 1)) - published
    assert missing and all((k - min(missing)) % 10 == 0 for k in missing), sorted(missing)
    assert len(bearings) >= 20
