"""A simulated BeAMS sensor on a pseudo-terminal, for driver_node's serial source under the fault campaign:
one revolution per turret period in real time, written at its end behind a fixed symlink (as udev's by-id
links are), with the line's faults: line noise, a spurious zero reference SPURIOUS_ZERO_EARLY_S before every
real one (a bouncing optical switch), silence, and unplugging until `clear`/`plug`."""

import contextlib
import os
import pathlib
import threading
import time
import tty
from collections.abc import Callable

import numpy as np

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_driver.serial_protocol import EventKind, FrameEncoder, seconds_to_ticks
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator
from beams_tools.fault_schedule import DRAWS, SERIAL_CLASS

# the case seen: a spurious zero reference this long (s) before each real one, 1.2 % of a 0.1 s turn
SPURIOUS_ZERO_EARLY_S = 1.2e-3
# (x, y, theta) of the robot at a host time (s), or None while unknown
PoseAtHost = Callable[[float], tuple[float, float, float] | None]


class SerialFeed:
    """The simulated sensor behind `link`; `pose_at_host` gives the robot's pose at a host time."""

    def __init__(
        self, link: pathlib.Path, pose_at_host: PoseAtHost, seed: int, noise_bytes_per_revolution: int = 5
    ) -> None:
        self.link = link
        self._pose_at_host = pose_at_host
        self._rng = np.random.default_rng(seed)
        self._seed = seed
        self.noise_bytes_per_revolution = noise_bytes_per_revolution
        self.fault: str | None = None
        self.revolutions_written = 0
        self._lock = threading.Lock()
        self._master: int | None = None
        self._slave: int | None = None
        self._stop = threading.Event()
        self.plug()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def plug(self) -> None:
        """A new pty behind the link (the sensor plugged in)."""
        with self._lock:
            self._master, self._slave = os.openpty()
            os.set_blocking(self._master, False)  # a full pty buffer (no reader) must not stall the feed
            tty.setraw(self._slave)  # bytes as they come, as a serial port gives them (no line discipline)
            self.link.unlink(missing_ok=True)
            self.link.symlink_to(os.ttyname(self._slave))

    def unplug(self) -> None:
        """The pty closed and the link removed (the cable pulled)."""
        with self._lock:
            for fd in (self._master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None
            self.link.unlink(missing_ok=True)

    def set_fault(self, fault: str | None) -> None:
        """Start a line fault ("noise", "spurious_zero", "silence", "unplug") or end it (None)."""
        if fault is not None and fault not in DRAWS[SERIAL_CLASS][0]:
            raise ValueError(f"line fault must be one of {DRAWS[SERIAL_CLASS][0]}, got {fault!r}")
        if fault == "unplug":
            self.unplug()
        elif self.fault == "unplug":
            self.plug()
        self.fault = fault

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.unplug()

    def _run(self) -> None:
        config = SensorSimConfig()
        simulator = SensorSimulator(config, EUROBOT_BEACON_MAP, np.random.default_rng(self._seed))
        encoder = FrameEncoder(first_sequence=self._seed)
        period_s = config.period_s
        start_s = time.time()
        revolution = 0
        while not self._stop.is_set():
            end_s = start_s + (revolution + 1) * period_s
            self._stop.wait(max(0.0, end_s - time.time()))
            if self._pose_at_host(end_s) is None or self.fault in ("silence", "unplug"):
                revolution += 1
                continue

            def pose_at(device_s: float) -> tuple[float, float, float]:
                return self._pose_at_host(start_s + device_s) or (0.0, 0.0, 0.0)

            edges = simulator.revolution(pose_at, revolution * period_s)
            frames = (
                spurious_zero_then(encoder, edges.start_time_s) if self.fault == "spurious_zero" else b""
            ) + encoder.revolution(edges)
            if self.fault == "noise":
                frames = with_line_noise(frames, self.noise_bytes_per_revolution, self._rng)
            with self._lock:
                if self._master is not None:
                    with contextlib.suppress(BlockingIOError, OSError):
                        os.write(self._master, frames)
                        self.revolutions_written += 1
            revolution += 1


def with_line_noise(frames: bytes, count: int, rng: np.random.Generator) -> bytes:
    """The frames with `count` random bytes inserted at random places (line noise)."""
    data = bytearray(frames)
    for _ in range(count):
        position = int(rng.integers(len(data) + 1))
        data[position:position] = bytes([int(rng.integers(256))])
    return bytes(data)


def spurious_zero_then(encoder: FrameEncoder, opening_s: float) -> bytes:
    """The frame of a spurious zero reference SPURIOUS_ZERO_EARLY_S before a revolution's opening one
    (nothing when the previous revolution's last edge came later: the frames stay in time order)."""
    try:
        return encoder.event(EventKind.ZERO_REFERENCE, seconds_to_ticks(opening_s - SPURIOUS_ZERO_EARLY_S))
    except ValueError:
        return b""
