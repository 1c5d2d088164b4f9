"""The campaign's simulated serial sensor: real-time revolutions on a pty behind a fixed path, and its
line faults (noise, spurious zero references, silence, unplugging), read back with the driver's own frame
parser."""

import contextlib
import os
import time

import numpy as np
import pytest

from beams_driver.serial_protocol import TIMER_HZ, EventKind, FrameParser
from beams_tools.serial_feed import SPURIOUS_ZERO_EARLY_S, SerialFeed

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


def test_a_spurious_zero_reference_comes_just_before_each_real_one(feed):
    feed.set_fault("spurious_zero")
    _read(feed.link, 0.2)  # what was written before the fault, still in the pty
    events = [e for e in FrameParser().feed(_read(feed.link, READ_S)) if e.kind == EventKind.ZERO_REFERENCE]
    gaps_s = np.diff([e.ticks for e in events]) / TIMER_HZ
    # pairs 1.2 ms apart
    spurious = np.isclose(gaps_s, SPURIOUS_ZERO_EARLY_S, atol=2e-5)
    assert spurious.sum() >= 6, gaps_s
    assert np.all(spurious | (gaps_s > 0.09)), gaps_s  # otherwise the rest of the 0.1 s turn
