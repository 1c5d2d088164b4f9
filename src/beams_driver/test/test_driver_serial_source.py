"""SerialEdgeSource through a real pseudo-terminal pair, with the sensor simulator as the device."""

import contextlib
import grp
import math
import os
import pathlib
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_driver import serial_source
from beams_driver.decoder import BearingDecoder
from beams_driver.edges import RevolutionEdges
from beams_driver.serial_protocol import (
    FRAME_SIZE,
    HELLO_SIZE,
    TICKS_PER_REVOLUTION,
    TIMER_HZ,
    V1_STREAM_PROBLEM,
    EventKind,
    FrameEncoder,
    FrameParser,
    encode_frame,
    encode_v1_frame,
)
from beams_driver.serial_source import (
    UNREADABLE_STREAM_BYTES,
    DeviceNotFoundError,
    DeviceOpenError,
    SerialEdgeSource,
    SerialSource,
)
from beams_driver.variance import VarianceModel
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator

HALF_TICK_RAD = math.pi / TICKS_PER_REVOLUTION
WAIT_S = 10.0


class FakeDevice:
    """The sensor's end of the link: a pty master, reached by the source through a stable symlink."""

    def __init__(self, link: pathlib.Path) -> None:
        self.master, slave = os.openpty()
        self.slave_path = os.ttyname(slave)
        self._slave = slave  # keep the pty alive until the source has opened its end
        self.link = link
        self.unplugged = threading.Event()  # writers stop: the closed fd numbers may be reused
        if link.is_symlink():
            link.unlink()
        link.symlink_to(self.slave_path)

    def write_in_background(self, data: bytes, chunk: int = 997, pause_s: float = 0.0) -> threading.Thread:
        """Write from a thread (the pty buffer is small and blocks until the source reads), pausing
        pause_s between chunks."""

        def run() -> None:
            for offset in range(0, len(data), chunk):
                if self.unplugged.is_set():
                    return
                try:
                    os.write(self.master, data[offset : offset + chunk])
                except OSError:
                    return  # the test unplugged the device mid-write
                time.sleep(pause_s)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        return thread

    def stream_in_background(self, revolutions: list[RevolutionEdges]) -> threading.Thread:
        """Send one revolution per turret period, as the sensor does (opening the port flushes what
        arrived before)."""
        encoder = FrameEncoder()

        def run() -> None:
            for edges in revolutions:
                if self.unplugged.is_set():
                    return
                try:
                    os.write(self.master, encoder.revolution(edges))
                except OSError:
                    return
                time.sleep(edges.period_s)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        return thread

    def unplug(self) -> None:
        self.unplugged.set()
        for fd in (self.master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        self.link.unlink(missing_ok=True)


@pytest.fixture
def link(tmp_path: pathlib.Path) -> pathlib.Path:
    return tmp_path / "beams_sensor"


@pytest.fixture
def device(link: pathlib.Path) -> Iterator[FakeDevice]:
    fake = FakeDevice(link)
    yield fake
    fake.unplug()


def simulated_revolutions(count: int, seed: int, first: int = 0) -> list[RevolutionEdges]:
    """Edges of a robot standing still in the middle of the table, from driver-sensor's simulator."""
    config = SensorSimConfig()
    simulator = SensorSimulator(config, EUROBOT_BEACON_MAP, np.random.default_rng(seed))
    pose = (1.2, 0.8, 0.3)
    return [simulator.revolution(lambda t: pose, k * config.period_s) for k in range(first, first + count)]


def frame_offset(data: bytes, index: int) -> int:
    """Byte offset of the index-th frame of an encoder's stream (hellos are longer than events)."""
    offset = 0
    for _ in range(index):
        offset += HELLO_SIZE if data[offset + 2] == EventKind.HELLO else FRAME_SIZE
    return offset


def read_until(source: SerialEdgeSource, count: int, timeout_s: float = WAIT_S) -> list[RevolutionEdges]:
    received: list[RevolutionEdges] = []
    deadline = time.monotonic() + timeout_s
    while len(received) < count and time.monotonic() < deadline:
        received += source.read()
    return received


def assert_same_edges(sent: list[RevolutionEdges], received: list[RevolutionEdges]) -> None:
    assert len(received) == len(sent)
    for original, decoded in zip(sent, received, strict=True):
        assert decoded.n_edges == original.n_edges > 0
        np.testing.assert_array_equal(decoded.edge_rising, original.edge_rising)
        assert np.max(np.abs(decoded.edge_angles_rad - original.edge_angles_rad)) <= HALF_TICK_RAD * 1.0001
        assert decoded.period_s == pytest.approx(original.period_s, rel=1e-9)


def test_missing_device_at_start_is_a_clear_error(tmp_path: pathlib.Path) -> None:
    source = SerialEdgeSource(str(tmp_path / "ttyUSB9"))
    with pytest.raises(DeviceNotFoundError, match=r"does not exist.*plugged in.*`device` parameter"):
        source.open()


def test_a_path_that_is_not_a_tty_is_a_clear_error(tmp_path: pathlib.Path) -> None:
    directory = tmp_path / "not_a_device"
    directory.mkdir()
    with pytest.raises(DeviceOpenError, match="cannot open serial device"):
        SerialEdgeSource(str(directory)).open()


def test_simulated_sensor_edges_cross_the_pty_intact(device: FakeDevice, link: pathlib.Path) -> None:
    sent = simulated_revolutions(20, seed=11)
    data = FrameEncoder().revolutions(sent)
    with SerialEdgeSource(str(link), clock=lambda: 1000.0) as source:
        writer = device.write_in_background(data)
        received = read_until(source, len(sent))
        writer.join(WAIT_S)
    assert_same_edges(sent, received)
    assert [r.revolution for r in received] == list(range(20))
    assert sum(source.drops.values()) == 0
    # The host clock read 1000 s at every arrival: device time is mapped so the last capture lands on it.
    assert received[-1].start_time_s + received[-1].period_s == pytest.approx(1000.0, abs=1e-6)


def test_bearings_decoded_from_the_pty_equal_the_simulator_s(device: FakeDevice, link: pathlib.Path) -> None:
    sent = simulated_revolutions(10, seed=15)
    decoder = BearingDecoder(SensorSimConfig().codes, VarianceModel(SensorSimConfig().codes))
    with SerialEdgeSource(str(link)) as source:
        device.write_in_background(FrameEncoder().revolutions(sent))
        received = read_until(source, len(sent))
    assert len(received) == len(sent)
    for original, decoded in zip(sent, received, strict=True):
        direct, serial = decoder.decode(original), decoder.decode(decoded)
        assert [b.beacon_id for b in serial.bearings] == [b.beacon_id for b in direct.bearings]
        assert sorted(b.beacon_id for b in serial.bearings) == [1, 2, 3]
        for a, b in zip(direct.bearings, serial.bearings, strict=True):
            assert b.bearing == pytest.approx(a.bearing, abs=1e-9)
            assert b.angular_window == pytest.approx(a.angular_window, abs=1e-9)
            assert b.variance == pytest.approx(a.variance, rel=1e-6)


def test_corrupted_stream_on_the_pty_drops_only_damaged_revolutions(
    device: FakeDevice, link: pathlib.Path
) -> None:
    sent = simulated_revolutions(10, seed=12)
    data = bytearray(FrameEncoder().revolutions(sent))
    # revolution 4 starts 0.4 s in: a checksum byte of the fourth frame after its zero reference
    rev4 = (
        FrameParser()
        .feed(bytes(data))
        .index(
            next(
                e
                for e in FrameParser().feed(bytes(data))
                if e.kind == EventKind.ZERO_REFERENCE and e.ticks >= 4 * 62400
            )
        )
    )
    data[frame_offset(bytes(data), rev4 + 3) + FRAME_SIZE - 1] ^= 0xFF
    data[len(data) // 2 : len(data) // 2] = b"\x00\xa5\x13garbage"
    logs: list[str] = []
    with SerialEdgeSource(str(link), log=logs.append) as source:
        device.write_in_background(bytes(data))
        received = read_until(source, 8)
    assert source.drops["bad_crc"] >= 1
    assert logs and "dropped" in logs[0] and "bad_crc" in logs[0]  # logged as soon as it happens
    assert 4 not in [r.revolution for r in received]
    kept = {r.revolution: r for r in received}
    survivors = [s for s in sent if s.revolution in kept]
    assert_same_edges(survivors, [kept[s.revolution] for s in survivors])
    assert len(kept) >= 8


def test_device_that_disappears_is_reopened_with_back_off(link: pathlib.Path) -> None:
    logs: list[str] = []
    first = FakeDevice(link)
    source = SerialEdgeSource(str(link), reconnect_initial_s=0.05, reconnect_max_s=0.2, log=logs.append)
    source.open()
    try:
        sent_before = simulated_revolutions(3, seed=13)
        first.write_in_background(FrameEncoder().revolutions(sent_before)).join(WAIT_S)
        assert_same_edges(sent_before, read_until(source, 3))
        first.unplug()  # USB cable pulled: the pty closes and the /dev link vanishes
        deadline = time.monotonic() + WAIT_S
        while source.connected and time.monotonic() < deadline:
            assert source.read() == []
        assert not source.connected and source.disconnections == 1
        while source.failed_reconnections < 3 and time.monotonic() < deadline:
            assert source.read() == []  # absent device: attempts fail quietly, with growing delays
        assert source.reconnect_delay_s == pytest.approx(0.2)  # 0.05 doubled, capped at reconnect_max_s
        second = FakeDevice(link)  # plugged back: a new tty behind the same link
        try:
            sent_after = simulated_revolutions(4, seed=14, first=50)
            while not source.connected and time.monotonic() < deadline:
                source.read()
            assert source.reconnections == 1
            # A new stream: unrelated sequence numbers and timer epoch, yet every revolution is assembled.
            second.write_in_background(FrameEncoder(first_sequence=77).revolutions(sent_after))
            assert_same_edges(sent_after, read_until(source, 4))
        finally:
            second.unplug()
    finally:
        source.close()
    assert any("lost" in line for line in logs) and any("reconnected" in line for line in logs)
    assert source.read() == []  # closed sources stay quiet


def test_device_back_at_its_path_is_read_again_within_a_second(link: pathlib.Path) -> None:
    """Unplugged long enough for the back-off to grow past a second, the sensor is read again within
    a second of its return: a reappearing path is tried at once (issue 14)."""
    first = FakeDevice(link)
    source = SerialEdgeSource(str(link), reconnect_initial_s=0.1, reconnect_max_s=5.0)
    source.open()
    try:
        first.write_in_background(FrameEncoder().revolutions(simulated_revolutions(2, seed=21))).join(WAIT_S)
        assert len(read_until(source, 2)) == 2
        first.unplug()
        deadline = time.monotonic() + WAIT_S
        while source.failed_reconnections < 5 and time.monotonic() < deadline:
            assert source.read() == []
        # 0.1 s doubled at each failed attempt: the next one is 3.2 s away when the sensor returns.
        assert source.reconnect_delay_s == pytest.approx(3.2)
        second = FakeDevice(link)
        try:
            returned_s = time.monotonic()
            second.stream_in_background(simulated_revolutions(20, seed=22))
            received = read_until(source, 1, timeout_s=WAIT_S)
            assert received and time.monotonic() - returned_s < 1.0
        finally:
            second.unplug()
    finally:
        source.close()
    assert source.disconnections == 1 and source.reconnections == 1


def test_permission_denied_is_one_line_that_says_what_to_do(device: FakeDevice, link: pathlib.Path) -> None:
    """A device the user may not open (not in its group): one line naming the group to join."""
    os.chmod(device.slave_path, 0o000)  # nobody's, not even its owner's
    opener = [
        sys.executable,
        "-c",
        f"""
from beams_driver.serial_source import DeviceOpenError, SerialEdgeSource
try:
    SerialEdgeSource({str(link)!r}).open()
except DeviceOpenError as error:
    print(error)
""",
    ]
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root and setpriv is missing: cannot take away root's permission bypass")
        opener = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search", *opener]
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    result = subprocess.run(opener, capture_output=True, text=True, timeout=60, env=environment)
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1 and not result.stderr, result.stdout + result.stderr
    group = grp.getgrgid(os.stat(device.slave_path).st_gid).gr_name
    assert lines[0] == (
        f"cannot open serial device {str(link)!r}: permission denied: add the user to its group "
        f"(sudo usermod -aG {group} $USER, then log in again) or give it a udev rule"
    )


def test_baud_rate_the_port_refuses_is_one_clear_line(device: FakeDevice, link: pathlib.Path) -> None:
    with pytest.raises(DeviceOpenError) as raised:
        SerialEdgeSource(str(link), baudrate=-9600).open()
    message = str(raised.value)
    assert message.startswith(f"cannot open serial device {str(link)!r} at baud_rate -9600: ")
    assert "\n" not in message


def test_stream_at_another_baud_rate_is_named_once(device: FakeDevice, link: pathlib.Path) -> None:
    """Bytes that never form a frame (what a sensor at another baud rate sends, without pause) are
    reported once, in one line naming the baud rate; the first valid frame clears the report."""
    logs: list[str] = []
    garbage = np.random.default_rng(5).integers(0, 256, UNREADABLE_STREAM_BYTES * 8, dtype=np.uint8)
    with SerialEdgeSource(str(link), log=logs.append) as source:
        writer = device.write_in_background(garbage.tobytes(), chunk=64, pause_s=0.01)
        deadline = time.monotonic() + WAIT_S
        while not source.stream_problem and time.monotonic() < deadline:
            assert source.read() == []
        assert source.stream_problem.endswith(
            "no valid frame: is baud_rate 500000 the sensor's (its default is 500000)?"
        )
        assert [line for line in logs if "no valid frame" in line] == [source.stream_problem]
        writer.join(WAIT_S)
        device.write_in_background(FrameEncoder().revolutions(simulated_revolutions(3, seed=23)))
        assert read_until(source, 2) and source.stream_problem == ""


class FakeHost:
    """What SerialSource asks of driver_node: a clock, a log and a wake (from the source's thread)."""

    def __init__(self) -> None:
        self.warnings: list[str] = []
        self.woken = threading.Event()
        self.wakes = 0

    def wake(self) -> None:
        self.wakes += 1
        self.woken.set()

    def now_s(self) -> float:
        return time.time()

    def log_warning(self, message: str) -> None:
        self.warnings.append(message)

    def log_info(self, message: str) -> None:
        pass


def poll_until(source: SerialSource, predicate, timeout_s: float = WAIT_S) -> list[RevolutionEdges]:
    """Poll every 10 ms until predicate(revolutions received so far) holds, or timeout_s."""
    received: list[RevolutionEdges] = []
    deadline = time.monotonic() + timeout_s
    while not predicate(received) and time.monotonic() < deadline:
        received += source.poll(time.time()).revolutions
        time.sleep(0.01)
    return received


def test_old_firmware_is_an_error_that_names_the_protocol(device: FakeDevice, link: pathlib.Path) -> None:
    """A v1 stream (the old firmware's frames) on a v2 host: no bearing, one ERROR naming the fix."""
    ticks = np.sort(np.random.default_rng(30).integers(0, 20 * TICKS_PER_REVOLUTION, 2000))
    data = b"".join(encode_v1_frame(1 + i % 3, i, int(t)) for i, t in enumerate(ticks))
    host = FakeHost()
    source = SerialSource({"device": str(link), "baud_rate": 500_000}, (), host)
    try:
        device.write_in_background(data)
        received = poll_until(source, lambda _: source.health().level == "error")
        health = source.health()
    finally:
        source.close()
    assert received == []
    assert health.message.endswith(V1_STREAM_PROBLEM)
    assert "protocol v1" in health.message and "flash firmware/turret" in health.message
    assert health.values["serial_drops_protocol_v1_frames"] > 0
    assert [w for w in host.warnings if "protocol v1" in w] == [health.message]


def edge_stream(
    encoder: FrameEncoder,
    sent: list[RevolutionEdges],
    edge: Callable[[int, int, EventKind], tuple[EventKind, bool]],
) -> bytearray:
    """The revolutions as `FrameEncoder.revolutions` sends them, each edge's frame as edge(revolution,
    index, kind) says: its kind, and whether the device numbered it but lost it."""
    data = bytearray()
    for revolution in sent:
        data += encoder.event(EventKind.ZERO_REFERENCE, round(revolution.start_time_s * TIMER_HZ))
        for index, (time_s, rising) in enumerate(
            zip(revolution.edge_times_s, revolution.edge_rising, strict=True)
        ):
            kind, lost = edge(revolution.revolution, index, EventKind.RISING if rising else EventKind.FALLING)
            data += encoder.event(kind, round(time_s * TIMER_HZ), lost=lost)
    closing_s = sent[-1].start_time_s + sent[-1].period_s
    return data + encoder.event(EventKind.ZERO_REFERENCE, round(closing_s * TIMER_HZ))


@pytest.mark.parametrize("cost", ["revolution", "window"])
def test_frames_the_turret_lost_are_counted_and_warned(
    device: FakeDevice, link: pathlib.Path, cost: str
) -> None:
    """Its queue overflowed (events numbered, not sent): /diagnostics shows the count and a warning, and
    the revolution they fall in is dropped (cost "revolution") or published with where they were lost
    (cost "window", the default: the decoder drops the windows near it), the others kept."""
    sent = simulated_revolutions(6, seed=31)
    encoder = FrameEncoder()
    data = edge_stream(encoder, sent, lambda revolution, index, kind: (kind, revolution == 2 and index < 7))
    data += encoder.event(EventKind.HEARTBEAT, round((sent[-1].start_time_s + 1.5) * TIMER_HZ))  # a hello
    values = {"device": str(link), "baud_rate": 500_000, "lost_frames_cost": cost}
    source = SerialSource(values, (), FakeHost())
    expected = [0, 1, 3, 4, 5] if cost == "revolution" else [0, 1, 2, 3, 4, 5]
    try:
        device.write_in_background(bytes(data))
        received = poll_until(
            source,
            lambda got: (
                len(got) >= len(expected) and getattr(source.serial.parser.device, "dropped_events", 0) > 0
            ),
        )
        health = source.health()
    finally:
        source.close()
    assert [r.revolution for r in received] == expected
    assert health.level == "warn" and "lost 7 frames" in health.message
    assert f"the {cost}s they touched were dropped" in health.message
    if cost == "window":  # the 7 lost edges lie between the event before the first and the 8th edge
        (lost,) = received[2].lost_angles_rad
        assert 0.0 <= lost[0] <= sent[2].edge_angles_rad[0]
        assert lost[1] == pytest.approx(sent[2].edge_angles_rad[7], abs=HALF_TICK_RAD * 1.0001)
        assert received[2].n_edges == sent[2].n_edges - 7
    assert health.values["serial_drops_lost_frames"] == 7
    assert health.values["serial_device_dropped_events"] == 7
    assert health.values["serial_device_timer_hz"] == TIMER_HZ


def test_edges_the_turret_missed_are_counted_and_warned(device: FakeDevice, link: pathlib.Path) -> None:
    """The firmware's capture missed an edge (a pulse of a few us) and said so: /diagnostics counts it
    (serial_missed_edges) and warns, and the revolution is published with where it was missed."""
    sent = simulated_revolutions(4, seed=32)

    def missed(revolution: int, index: int, kind: EventKind) -> tuple[EventKind, bool]:
        return (EventKind.MISSED_EDGE if revolution == 2 and index == 3 else kind), False

    data = edge_stream(FrameEncoder(), sent, missed)
    source = SerialSource({"device": str(link), "baud_rate": 500_000}, (), FakeHost())
    try:
        device.write_in_background(bytes(data))
        received = poll_until(source, lambda got: len(got) >= len(sent))
        health = source.health()
    finally:
        source.close()
    assert [r.revolution for r in received] == [0, 1, 2, 3]
    (lost,) = received[2].lost_angles_rad
    assert lost == pytest.approx(sent[2].edge_angles_rad[2:4], abs=HALF_TICK_RAD * 1.0001)
    assert received[2].n_edges == sent[2].n_edges - 1
    assert health.values["serial_missed_edges"] == 1 and "serial_drops_lost_frames" not in health.values
    assert health.level == "warn" and "the turret missed 1 receiver edges" in health.message


def test_frames_without_a_hello_are_an_error(
    device: FakeDevice, link: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A device that never says its clock (a firmware that skips the hello): no edge is used, and after
    HELLO_WAIT_S an error says why."""
    monkeypatch.setattr(serial_source, "HELLO_WAIT_S", 0.3)
    data = b"".join(encode_frame(EventKind.RISING, i, 1000 * i) for i in range(20000))
    source = SerialSource({"device": str(link), "baud_rate": 500_000}, (), FakeHost())
    try:
        device.write_in_background(data, chunk=200, pause_s=0.002)
        received = poll_until(source, lambda _: source.health().level == "error")
        health = source.health()
    finally:
        source.close()
    assert received == []
    assert "no hello" in health.message and "flash firmware/turret" in health.message
    assert health.values["serial_drops_before_hello"] > 0


def paced_revolutions(
    device: FakeDevice, revolutions: list[RevolutionEdges], silent: range
) -> threading.Thread:
    """One revolution per turret period, as the sensor sends them; during `silent` (revolution numbers)
    the optical switch is unplugged: its edges and heartbeats still come, no zero reference."""
    encoder = FrameEncoder()

    def run() -> None:
        for edges in revolutions:
            if device.unplugged.is_set():
                return
            if edges.revolution in silent:
                data = b"".join(
                    encoder.event(EventKind.RISING if rising else EventKind.FALLING, round(t * TIMER_HZ))
                    for t, rising in zip(edges.edge_times_s, edges.edge_rising, strict=True)
                )
            else:
                data = encoder.revolution(edges)
            with contextlib.suppress(OSError):
                os.write(device.master, data)
            time.sleep(edges.period_s)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_no_zero_reference_is_an_error_until_it_returns(device: FakeDevice, link: pathlib.Path) -> None:
    """The switch unplugged for 1.5 s while edges and heartbeats still come: nothing is published,
    /diagnostics says ERROR with the reason within the timeout, and both recover when it is back."""
    sent = simulated_revolutions(45, seed=32)
    host = FakeHost()
    source = SerialSource(
        {"device": str(link), "baud_rate": 500_000, "zero_reference_timeout_s": 0.5}, (), host
    )
    try:
        paced_revolutions(device, sent, silent=range(10, 25))
        before = poll_until(source, lambda got: len(got) >= 8)
        assert source.health().level == "ok"
        during = poll_until(source, lambda _: source.health().level == "error", timeout_s=5.0)
        health = source.health()
        assert health.message.startswith("no zero reference for "), health.message
        assert health.message.endswith(
            "s: turret stopped or switch unplugged (the turret's frames still arrive)"
        )
        silence_s = float(health.message.split()[4])
        assert 0.5 <= silence_s < 1.0
        after = poll_until(source, lambda got: len(got) >= 10)
        health = source.health()
    finally:
        source.close()
    assert {r.revolution for r in during} <= set(range(10))
    assert health.level != "error" and "no zero reference" not in (health.message or ""), health.message
    assert after and min(r.revolution for r in after) >= 25
    assert_same_edges([sent[r.revolution] for r in before + during + after], before + during + after)


def test_line_noise_is_not_called_a_baud_rate_problem(device: FakeDevice, link: pathlib.Path) -> None:
    """1 % of the bytes replaced by random ones: frames still form, so no baud-rate diagnosis; the
    revolutions the noise spared are published (the assembler's tests count them exactly)."""
    sent = simulated_revolutions(40, seed=33)
    clean = FrameEncoder().revolutions(sent)
    rng = np.random.default_rng(34)
    damaged = np.frombuffer(clean, dtype=np.uint8).copy()
    hit = rng.random(len(damaged)) < 0.01
    damaged[hit] = rng.integers(0, 256, int(hit.sum()))
    logs: list[str] = []
    source = SerialSource({"device": str(link), "baud_rate": 500_000}, (), FakeHost())
    source.serial._log = logs.append
    try:
        device.write_in_background(
            damaged.tobytes() + FrameEncoder(first_sequence=9).revolutions(sent[:3]), 500, 0.005
        )
        received = poll_until(
            source, lambda _: source.serial.parser.bytes_fed >= len(damaged) + len(clean) // 20
        )
        health = source.health()
    finally:
        source.close()
    assert source.serial.parser.drops["lost_frames"] > 50
    assert not [line for line in logs if "no valid frame" in line]
    assert health.level == "warn" and "lost" in health.message, health.message
    assert received


def test_a_forged_frame_out_of_time_order_refuses_its_revolution() -> None:
    """Noise that passed the checksum (1 in 65536 bad frames) may put an edge back in time: the revolution
    is refused and counted, never built."""
    from beams_driver.serial_protocol import FrameEvent, RevolutionAssembler

    assembler = RevolutionAssembler(TIMER_HZ, TICKS_PER_REVOLUTION)
    events = [
        FrameEvent(EventKind.ZERO_REFERENCE, 0, 0, False),
        FrameEvent(EventKind.RISING, 1000, 1, False),
        FrameEvent(EventKind.FALLING, 500, 2, False),
        FrameEvent(EventKind.ZERO_REFERENCE, TICKS_PER_REVOLUTION, 3, False),
        FrameEvent(EventKind.RISING, TICKS_PER_REVOLUTION + 1000, 4, False),
        FrameEvent(EventKind.ZERO_REFERENCE, 2 * TICKS_PER_REVOLUTION, 5, False),
    ]
    assert [r.revolution for r in assembler.feed(events)] == [1]
    assert assembler.drops["edges_out_of_order"] == 1


def test_the_source_hears_of_each_drop_and_its_recent_drops_clear_themselves():
    """The parser and the assembler report every drop as it happens (no totals compared): the log line and
    /diagnostics' recent drops (RECENT_DROPS_WARN_S) come from those reports."""
    now = [100.0]
    logged: list[str] = []
    source = SerialEdgeSource("/dev/beams-none", monotonic=lambda: now[0], log=logged.append)
    source.parser.drops.add("lost_frames", 3)
    source.assembler.drops.add("bad_revolution_period")
    assert source.recent_drops() == {"lost_frames": 3, "bad_revolution_period": 1}
    source._log_new_drops()
    assert logged == ["serial device /dev/beams-none: dropped bad_revolution_period 1, lost_frames 3"]
    now[0] += serial_source.RECENT_DROPS_WARN_S + 0.1
    source.parser.drops.add("lost_frames")
    assert source.recent_drops() == {"lost_frames": 1}
    assert source.drops == {"lost_frames": 4, "bad_revolution_period": 1}


def serial_readers() -> list[threading.Thread]:
    return [thread for thread in threading.enumerate() if thread.name == "serial_source"]


def test_the_reader_thread_wakes_the_driver_at_each_revolution_and_stops_on_close(
    device: FakeDevice, link: pathlib.Path
) -> None:
    """No poll loop: the source's thread reads the port as bytes come and wakes its host once per
    revolution assembled (a revolution ends with the next one's zero reference), which the first poll
    after the wake hands over; close() stops the thread at once and releases the port."""
    sent = simulated_revolutions(5, seed=35)
    host = FakeHost()
    source = SerialSource({"device": str(link), "baud_rate": 500_000}, (), host)
    encoder, received = FrameEncoder(), []
    try:
        assert len(serial_readers()) == 1
        for edges in sent:
            os.write(device.master, encoder.revolution(edges))
            if edges.revolution == 0:
                continue  # open until the next zero reference
            written_s = time.monotonic()
            assert host.woken.wait(WAIT_S), f"no wake for revolution {edges.revolution - 1}"
            assert time.monotonic() - written_s < 1.0
            host.woken.clear()
            poll = source.poll(time.time())
            assert [r.revolution for r in poll.revolutions] == [edges.revolution - 1]
            assert not poll.continuity_broken
            received += poll.revolutions
        assert host.wakes == len(sent) - 1
        assert source.poll(time.time()).revolutions == []
    finally:
        closing_s = time.monotonic()
        source.close()
    assert time.monotonic() - closing_s < 2 * serial_source.READ_WAIT_S + 0.2
    assert serial_readers() == [] and not source.serial.connected
    assert_same_edges(sent[:-1], received)


def test_revolutions_nobody_polls_are_bounded_and_break_the_continuity(
    device: FakeDevice, link: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A driver that does not poll (inactive) leaves at most MAX_PENDING_REVOLUTIONS (and a read's worth)
    waiting: the older ones go, and the next poll says the first one does not follow the last polled."""
    monkeypatch.setattr(serial_source, "MAX_PENDING_REVOLUTIONS", 2)
    sent = simulated_revolutions(8, seed=36)
    data = FrameEncoder().revolutions(sent)
    source = SerialSource({"device": str(link), "baud_rate": 500_000}, (), FakeHost())
    try:
        device.write_in_background(data, chunk=len(data) // 8 + 1, pause_s=0.05).join(WAIT_S)
        deadline = time.monotonic() + WAIT_S
        while source.serial.parser.bytes_fed < len(data) and time.monotonic() < deadline:
            time.sleep(0.01)
        poll = source.poll(time.time())
    finally:
        source.close()
    numbers = [r.revolution for r in poll.revolutions]
    assert poll.continuity_broken and numbers == list(range(8 - len(numbers), 8)) and len(numbers) < 8
