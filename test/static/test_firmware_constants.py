"""The protocol's timings have one source: the turret firmware's configuration (firmware/turret/config.h)
and its frame definitions (turret.c); the host's constants (beams_driver.serial_protocol) must equal them."""

import pathlib
import re

import pytest

from beams_driver import serial_protocol
from beams_driver.serial_protocol import EventKind

TURRET = pathlib.Path(__file__).resolve().parents[2] / "firmware" / "turret"


def firmware_defines() -> dict[str, int]:
    """Every integer #define of config.h and turret.c, evaluated in order as the C preprocessor would
    (integer suffixes dropped, `/` the integer division)."""
    values: dict[str, int] = {}
    for source in ("config.h", "turret.c"):
        text = re.sub(r"/\*.*?\*/", "", (TURRET / source).read_text(), flags=re.S)
        for name, expression in re.findall(r"^#define\s+(\w+)\s+(.+?)\s*$", text, flags=re.M):
            if name in values:
                continue  # the first definition wins (#ifndef guards)
            python = re.sub(r"\b(0x[0-9A-Fa-f]+|\d+)[UL]+\b", r"\1", expression).replace("/", "//")
            try:
                values[name] = int(eval(python, {}, dict(values)))  # the project's own header
            except (NameError, SyntaxError):
                continue  # not an integer (F_CPU's guard, a function-like macro)
    return values


def firmware_kinds() -> dict[str, int]:
    """turret.c's event kinds: KIND_RISING = 0x01, ..."""
    text = (TURRET / "turret.c").read_text()
    return {name: int(value, 0) for name, value in re.findall(r"KIND_(\w+) = (0x[0-9A-Fa-f]+)", text)}


@pytest.fixture(scope="module")
def firmware() -> dict[str, int]:
    return firmware_defines()


def test_the_link_and_the_clock_are_the_firmwares(firmware: dict[str, int]) -> None:
    assert firmware["BAUD_RATE"] == serial_protocol.DEFAULT_BAUDRATE
    assert firmware["TIMER_HZ"] == serial_protocol.FIRMWARE_TIMER_HZ
    assert firmware["TICKS_PER_REVOLUTION"] == serial_protocol.FIRMWARE_TICKS_PER_REVOLUTION
    assert firmware["PROTOCOL_VERSION"] == serial_protocol.PROTOCOL_VERSION


def test_the_heartbeat_and_the_hello_periods_are_the_firmwares(firmware: dict[str, int]) -> None:
    """A heartbeat once per wrap of Timer1, which runs in normal mode (no WGM1 bit set: it counts the
    full 16 bits), every HELLO_EVERY_HEARTBEATS-th one a hello."""
    turret_c = (TURRET / "turret.c").read_text()
    assert "WGM1" not in turret_c and "TCCR1A" not in turret_c and "OCR1A" not in turret_c
    assert 0 < firmware["HEARTBEAT_COMPARE"] < serial_protocol.HEARTBEAT_TICKS == 1 << 16
    assert firmware["HELLO_EVERY_HEARTBEATS"] == serial_protocol.HEARTBEATS_PER_HELLO
    heartbeat_s, hello_s = serial_protocol.HEARTBEAT_PERIOD_S, serial_protocol.HELLO_PERIOD_S
    assert (heartbeat_s, hello_s) == pytest.approx((0.032768, 0.262144), abs=1e-12)


def test_the_frames_are_the_firmwares(firmware: dict[str, int]) -> None:
    assert bytes([firmware["SYNC_1"], firmware["SYNC_2"]]) == serial_protocol.SYNC
    assert firmware["EVENT_FRAME_SIZE"] == serial_protocol.FRAME_SIZE
    assert firmware["HELLO_FRAME_SIZE"] == serial_protocol.HELLO_SIZE
    assert firmware_kinds() == {kind.name: int(kind) for kind in EventKind}


def test_the_simulated_device_keeps_the_firmwares_periods() -> None:
    """FrameEncoder (the simulated device, any clock): a heartbeat every 32.768 ms, every eighth a hello."""
    encoder = serial_protocol.FrameEncoder(timer_hz=2_000_000, ticks_per_revolution=200_000)
    data = encoder.event(EventKind.RISING, 0) + encoder.event(EventKind.FALLING, 8 * (1 << 16))
    events = serial_protocol.FrameParser().feed(data)
    periodic = [e for e in events if e.kind in (EventKind.HEARTBEAT, EventKind.HELLO)]
    assert [e.ticks for e in periodic] == [k * (1 << 16) for k in range(9)]
    assert [e.kind for e in periodic] == [EventKind.HELLO] + [EventKind.HEARTBEAT] * 7 + [EventKind.HELLO]
