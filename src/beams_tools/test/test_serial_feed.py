"""The campaign's simulated serial sensor: real-time revolutions on a pty behind a fixed path, and its
line faults (noise, silence, unplugging), read back with the driver's own frame parser."""

import contextlib
import os
import time

import pytest

from beams_driver.serial_protocol import EventKind, FrameParser
from beams_tools.serial_feed import SerialFeed

POSE = (1.2, 0.8, 0.3)
READ_S = 1.0  # ten turret periods


def _read(link, duration_s: float) -> bytes:
    """What the sensor sends during duration_s, read through the link as the driver opens it."""
    fd = os.open(link, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
    data = bytearray()
    deadline = time.monotonic() + duration_s
    try:
        while time.monotonic() < deadline:
            with contextlib.suppress(BlockingIOError):
                data += os.read(fd, 65536)
            time.sleep(0.01)
    finally:
        os.close(fd)
    return bytes(data)


def _zero_references(data: bytes) -> int:
    return sum(event.kind == EventKind.ZERO_REFERENCE for event in FrameParser().feed(data))


@pytest.fixture
def feed(tmp_path):
    feed = SerialFeed(tmp_path / "beams_sensor", lambda _host_s: POSE, seed=3)
    yield feed
    feed.close()


def test_the_feed_sends_a_revolution_per_turret_period(feed):
    revolutions = _zero_references(_read(feed.link, READ_S))
    assert 7 <= revolutions <= 11, revolutions


def test_silence_sends_nothing_and_noise_garbles_frames(feed):
    clean = _read(feed.link, READ_S)
    feed.set_fault("silence")
    _read(feed.link, 0.2)  # what was written before, still in the pty
    assert _read(feed.link, READ_S) == b""
    feed.set_fault("noise")
    noisy = _read(feed.link, READ_S)
    # five random bytes per revolution: bytes skipped and frames broken, where the clean stream has fewer
    assert _garbled(noisy) >= 5 + _garbled(clean), (_garbled(noisy), _garbled(clean))


def _garbled(data: bytes) -> int:
    """Bytes skipped and frames refused by the driver's parser."""
    parser = FrameParser()
    parser.feed(data)
    return sum(parser.drops[key] for key in ("garbage_bytes", "bad_crc", "truncated", "unknown_kind"))


def test_unplugging_removes_the_path_and_plugging_back_restores_it(feed):
    feed.set_fault("unplug")
    assert not feed.link.exists()
    feed.set_fault(None)
    assert feed.link.exists()
    assert _zero_references(_read(feed.link, READ_S)) >= 7
