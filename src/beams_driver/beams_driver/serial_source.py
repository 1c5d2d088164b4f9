"""The real-hardware edge source: the BeAMS sensor's serial stream (`serial_protocol`) read with pyserial.
Only `open()` raises (one line saying what to fix); `read()` reopens a lost device with a back-off and
counts bad bytes as drops (docs/serial_integrity.md)."""

import contextlib
import errno
import grp
import os
import select
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import serial

from beams_common.config.parameters import ParameterSpec
from beams_driver.edge_source import EdgeSourceKind, SourceHealth, SourceHost, SourcePoll
from beams_driver.edges import RevolutionEdges
from beams_driver.serial_protocol import (
    DEFAULT_BAUDRATE,
    FRAME_SIZE,
    HELLO_PERIOD_S,
    LOST_FRAMES_COSTS,
    MIN_SPAN_TOLERANCE_S,
    EventKind,
    FrameEvent,
    FrameParser,
    RevolutionAssembler,
)

# Bytes and seconds without a valid frame that call a stream unreadable (a wrong baud rate), beyond what
# line noise or a burst of it on plugging in leaves.
UNREADABLE_STREAM_BYTES = 64 * FRAME_SIZE
UNREADABLE_STREAM_S = 0.5
# Frames without a hello for this long (the firmware sends one every 262 ms): the device hides its clock.
HELLO_WAIT_S = 3.0 * HELLO_PERIOD_S
# /diagnostics warns this long after lost frames, a refused zero reference or revolution length.
RECENT_DROPS_WARN_S = 5.0


class DeviceNotFoundError(FileNotFoundError):
    """The serial device path does not exist."""


class DeviceOpenError(OSError):
    """The serial device exists but cannot be opened (permissions, busy, not a tty)."""


class SerialEdgeSource:
    """Edges from the BeAMS sensor on a serial port: open(), read() in a loop, close()."""

    def __init__(
        self,
        device: str,
        baudrate: int = DEFAULT_BAUDRATE,
        *,
        read_timeout_s: float = 0.05,
        reconnect_initial_s: float = 0.1,
        reconnect_max_s: float = 5.0,
        max_clock_drift: float = 1e-4,
        drop_log_period_s: float = 5.0,
        assembler: RevolutionAssembler | None = None,
        monotonic: Callable[[], float] = time.monotonic,
        clock: Callable[[], float] = time.time,
        sleep: Callable[[float], None] = time.sleep,
        log: Callable[[str], None] | None = None,
        serial_factory: Callable[..., Any] = serial.Serial,
    ) -> None:
        if not read_timeout_s > 0 or not 0 < reconnect_initial_s <= reconnect_max_s:
            raise ValueError(
                f"read_timeout_s ({read_timeout_s}) must be > 0 and 0 < reconnect_initial_s "
                f"({reconnect_initial_s}) <= reconnect_max_s ({reconnect_max_s})"
            )
        self.device = device
        self.baudrate = int(baudrate)
        self.read_timeout_s = float(read_timeout_s)
        self.reconnect_initial_s = float(reconnect_initial_s)
        self.reconnect_max_s = float(reconnect_max_s)
        self.max_clock_drift = float(max_clock_drift)
        self.drop_log_period_s = float(drop_log_period_s)
        self.parser = FrameParser()
        self.assembler = assembler or RevolutionAssembler()
        self.parser.drops.listeners.append(self._dropped)
        self.assembler.drops.listeners.append(self._dropped)
        self.disconnections = 0
        self.reconnections = 0
        self.failed_reconnections = 0
        self._clock = clock
        self._monotonic = monotonic
        self._sleep = sleep
        self._log = log or (lambda message: None)
        self._serial_factory = serial_factory
        self.port: Any = None  # the open pyserial port, None while the device is lost
        self._opened = False
        # the back-off between reconnection attempts (doubles per failure up to reconnect_max_s)
        self.reconnect_delay_s = self.reconnect_initial_s
        self._next_attempt_s = 0.0
        self._offset_s: float | None = None
        self._last_arrival_s = 0.0
        self._unlogged_drops: Counter[str] = Counter()  # since the last line about drops
        self._recent_drops: deque[tuple[float, str, int]] = deque()  # (monotonic s, reason, count)
        self._next_drop_log_s = 0.0
        self._device_missing = False
        self._bytes_since_frame = 0
        self._frames_seen = 0
        self._device_clock: tuple[int, int] | None = None
        self._problem_key = ""
        self._frames_without_hello_since: float | None = None
        self._connected_s = 0.0  # monotonic: the port opened (or reopened)
        self._last_frame_s: float | None = None  # a valid frame from a known device
        self._last_valid_bytes_s = 0.0  # any valid frame, or the port opened
        self._last_zero_reference_s: float | None = None
        self.stream_problem = ""  # why the bytes that arrive are not usable ("" while they are)
        self.last_error = ""  # why the last (re)connection attempt failed

    # ---- life cycle ----

    def open(self) -> None:
        """Open the device; raises DeviceNotFoundError / DeviceOpenError with a clear message."""
        if not os.path.exists(self.device):
            raise DeviceNotFoundError(
                f"serial device {self.device!r} does not exist: is the BeAMS sensor plugged in, and is the "
                f"`device` parameter right (e.g. /dev/ttyUSB0 or a /dev/serial/by-id/ link)?"
            )
        self.port = self._open_port()
        self._opened = True
        self._connected()

    def _connected(self) -> None:
        """A new stream: the silences are measured from now."""
        self._connected_s = self._last_valid_bytes_s = self._monotonic()
        self._last_frame_s = self._last_zero_reference_s = None

    def close(self) -> None:
        """Close the port (idempotent); read() returns nothing afterwards."""
        self._opened = False
        self._close_port()

    def __enter__(self) -> "SerialEdgeSource":
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def connected(self) -> bool:
        return self.port is not None

    @property
    def drops(self) -> Counter[str]:
        """Every drop so far, by reason: the parser's (bytes and frames) and the assembler's (revolutions)."""
        return self.parser.drops + self.assembler.drops

    # ---- reading ----

    def read(self) -> list[RevolutionEdges]:
        """Wait at most about read_timeout_s for bytes; return the revolutions they complete. Never raises."""
        if not self._opened:
            return []
        if self.port is None and not self._reconnect():
            return []
        try:
            data = self.port.read(max(1, self.port.in_waiting))
        except (serial.SerialException, OSError) as error:
            self._lost(error)
            return []
        if not data:
            return []
        events = self.parser.feed(data)
        self._note_arrivals(events)
        self._check_stream(len(data))
        self._update_clock(events, self._clock())
        revolutions = self.assembler.feed(events)
        self._log_new_drops()
        return revolutions

    def _note_arrivals(self, events: list[FrameEvent]) -> None:
        if events:
            now = self._monotonic()
            self._last_frame_s = now
            if any(event.kind == EventKind.ZERO_REFERENCE for event in events):
                self._last_zero_reference_s = now

    def zero_reference_silence_s(self) -> float | None:
        """Seconds without a zero reference while frames of a known device arrive (since the stream began
        if none came yet); None while no frame arrives (another problem, said elsewhere)."""
        if self._last_frame_s is None:
            return None
        return self._monotonic() - (self._last_zero_reference_s or self._connected_s)

    def frame_silence_s(self) -> float:
        """Seconds since the last frame of a known device (since the stream began if none came)."""
        return self._monotonic() - (self._last_frame_s or self._connected_s)

    def _check_stream(self, n_bytes: int) -> None:
        """Say once why the bytes that arrive give no edges: no frame at all (the baud rate), a device
        of another protocol version (the parser's reason), or frames without a hello."""
        parser = self.parser
        frames = parser.event_frames + parser.hellos + parser.drops["protocol_v1_frames"]
        if frames == self._frames_seen:
            self._bytes_since_frame += n_bytes
            silent_s = self._monotonic() - self._last_valid_bytes_s
            if self._bytes_since_frame >= UNREADABLE_STREAM_BYTES and silent_s >= UNREADABLE_STREAM_S:
                self._report(
                    "no_frame",
                    f"serial device {self.device}: {self._bytes_since_frame} bytes and no valid frame: is "
                    f"baud_rate {self.baudrate} the sensor's (its default is {DEFAULT_BAUDRATE})?",
                )
            return
        self._frames_seen = frames
        self._bytes_since_frame = 0
        self._last_valid_bytes_s = self._monotonic()
        if parser.problem:
            self._report(parser.problem, f"serial device {self.device}: {parser.problem}")
        elif parser.device is None:
            now = time.monotonic()
            if self._frames_without_hello_since is None:
                self._frames_without_hello_since = now
            elif now - self._frames_without_hello_since >= HELLO_WAIT_S:
                self._report(
                    "no_hello",
                    f"serial device {self.device}: frames but no hello for {HELLO_WAIT_S:.0f} s: the "
                    f"turret's firmware must say its protocol version and clock (flash firmware/turret)",
                )
        else:
            self._frames_without_hello_since = None
            self.stream_problem = self._problem_key = ""

    def _report(self, key: str, problem: str) -> None:
        """Set stream_problem; log it once per kind of problem (key)."""
        if key != self._problem_key:
            self._problem_key = key
            self.stream_problem = problem
            self._log(problem)

    def _open_port(self) -> Any:
        try:
            return self._serial_factory(port=self.device, baudrate=self.baudrate, timeout=self.read_timeout_s)
        except (serial.SerialException, OSError, ValueError) as error:
            raise DeviceOpenError(open_failure_reason(self.device, self.baudrate, error)) from None

    def _close_port(self) -> None:
        port, self.port = self.port, None
        if port is not None:
            # The device may already be gone; there is nothing more to release then.
            with contextlib.suppress(serial.SerialException, OSError):
                port.close()

    def _lost(self, error: Exception) -> None:
        """The device vanished: close it and schedule the first reconnection attempt."""
        self._close_port()
        self.disconnections += 1
        self._device_missing = not os.path.exists(self.device)
        self.reconnect_delay_s = self.reconnect_initial_s
        self._next_attempt_s = time.monotonic() + self.reconnect_delay_s
        self._log(f"serial device {self.device} lost ({error}); reconnecting")

    def _reconnect(self) -> bool:
        """One attempt when the back-off allows it or the missing device path is back, else sleep a
        little; True when connected again."""
        now = time.monotonic()
        back = self._device_missing and os.path.exists(self.device)
        if now < self._next_attempt_s and not back:
            self._sleep(min(self.read_timeout_s, self._next_attempt_s - now))
            return False
        try:
            self._device_missing = not os.path.exists(self.device)
            if self._device_missing:
                raise DeviceNotFoundError(f"serial device {self.device} does not exist")
            self.port = self._open_port()
        except OSError as error:
            self.failed_reconnections += 1
            self.reconnect_delay_s = min(2.0 * self.reconnect_delay_s, self.reconnect_max_s)
            self._next_attempt_s = now + self.reconnect_delay_s
            if str(error) != self.last_error:
                self.last_error = str(error)
                self._log(self.last_error)
            return False
        # A new stream: its sequence numbers, timer epoch and open revolution are unrelated to the old one.
        self.parser.new_stream()
        self.assembler.reset()
        self._connected()
        self._offset_s = None
        self._bytes_since_frame = 0
        self._frames_without_hello_since = None
        self.stream_problem = self._problem_key = ""
        self.last_error = ""
        self.reconnections += 1
        self._log(f"serial device {self.device} reconnected")
        return True

    def _dropped(self, reason: str, count: int) -> None:
        """The parser or the assembler dropped something: kept for the next log line and the recent drops."""
        now = self._monotonic()
        self._unlogged_drops[reason] += count
        self._recent_drops.append((now, reason, count))
        while now - self._recent_drops[0][0] > RECENT_DROPS_WARN_S:
            self._recent_drops.popleft()

    def recent_drops(self) -> Counter[str]:
        """The drops of the last RECENT_DROPS_WARN_S seconds, by reason (for a warning that clears itself)."""
        since, recent = self._monotonic() - RECENT_DROPS_WARN_S, Counter()
        for s, reason, n in self._recent_drops:
            if s >= since:
                recent[reason] += n
        return +recent  # as a sum of Counters: no reason counted zero

    def _log_new_drops(self) -> None:
        """One line per drop_log_period_s at most, with the drops counted since the previous line."""
        now = time.monotonic()
        if now < self._next_drop_log_s or not self._unlogged_drops:
            return
        summary = ", ".join(f"{reason} {count}" for reason, count in sorted(self._unlogged_drops.items()))
        self._log(f"serial device {self.device}: dropped {summary}")
        self._unlogged_drops.clear()
        self._next_drop_log_s = now + self.drop_log_period_s

    def _update_clock(self, events: list[FrameEvent], arrival_s: float) -> None:
        """Map device ticks (its timer starts anywhere) onto the host clock with the smallest (arrival -
        capture) offset seen, the least delayed, allowed to grow by `max_clock_drift` s/s (a device clock
        that runs slow); a device reset or a new clock starts the mapping afresh."""
        if not events or self.parser.device is None:
            return
        device = self.parser.device
        clock = (device.timer_hz, device.ticks_per_revolution)
        if clock != self._device_clock or any(e.kind == EventKind.HELLO and e.hello.boot for e in events):
            self._offset_s = None  # a device reset or a new clock: the old mapping means nothing
            self._device_clock = clock
        candidate = arrival_s - events[-1].ticks / self.parser.device.timer_hz
        if self._offset_s is None:
            self._offset_s = candidate
        else:
            allowance = self.max_clock_drift * max(0.0, arrival_s - self._last_arrival_s)
            self._offset_s = min(candidate, self._offset_s + allowance)
        self._last_arrival_s = arrival_s
        self.assembler.time_offset_s = self._offset_s


def open_failure_reason(device: str, baudrate: int, error: Exception) -> str:
    """One line saying why the device could not be opened, and what to do about it."""
    if getattr(error, "errno", None) == errno.EACCES or "Permission denied" in str(error):
        try:
            group = grp.getgrgid(os.stat(device).st_gid).gr_name
        except (OSError, KeyError):
            group = "dialout"
        return (
            f"cannot open serial device {device!r}: permission denied: add the user to its group "
            f"(sudo usermod -aG {group} $USER, then log in again) or give it a udev rule"
        )
    if isinstance(error, ValueError) or "baud" in str(error).lower():
        return f"cannot open serial device {device!r} at baud_rate {baudrate}: {error}"
    return f"cannot open serial device {device!r}: {error}"


# ---- the serial device as the driver's EdgeSource (`source: serial`) ----

ZERO_REFERENCE_TIMEOUT = ParameterSpec(
    "zero_reference_timeout_s",
    2.0,
    "Seconds without a zero reference, while the turret's frames arrive, after which /diagnostics says "
    "ERROR (the turret stopped or its optical switch is unplugged); the start-up ramp takes about 1.2 s.",
    minimum=0.2,
    maximum=60.0,
)
MIN_REVOLUTION_TOLERANCE = ParameterSpec(
    "min_revolution_tolerance_s",
    MIN_SPAN_TOLERANCE_S,
    "Smallest tolerance (s) on a revolution's length against the measured turret speed (5 robust standard "
    "deviations of the recent lengths, at least this): a revolution outside it is refused, its bearings "
    "would be off by up to 2*pi*error/period.",
    minimum=1e-6,
    maximum=5e-3,
)
LOST_FRAMES_COST = ParameterSpec(
    "lost_frames_cost",
    "window",
    "What frames lost on the link (sequence gaps: line noise, the turret's queue overflowing) cost: "
    "'window' keeps the revolution and drops only the beacon windows within the decoder's timeout of where "
    "they were lost (a kept bearing is exactly the clean stream's); 'revolution' drops the revolution.",
    choices=LOST_FRAMES_COSTS,
)
SERIAL_PARAMETERS = (
    ParameterSpec("device", "/dev/ttyUSB0", "Serial device of the BeAMS sensor."),
    ParameterSpec("baud_rate", DEFAULT_BAUDRATE, "Serial baud rate.", minimum=9600, maximum=12_000_000),
    ZERO_REFERENCE_TIMEOUT,
    MIN_REVOLUTION_TOLERANCE,
    LOST_FRAMES_COST,
)
READ_WAIT_S = 0.05  # the reader thread's longest wait on the port: how soon close() stops it
READ_INTERVAL_S = 0.005  # between its reads: a stream (each edge, each byte as it comes) read in batches
MAX_PENDING_REVOLUTIONS = 100  # kept while the driver does not poll (inactive): 10 s, then dropped
# The drops /diagnostics warns about while recent, and what each means for the operator.
WARNED_DROPS = {
    "lost_frames": (
        "the turret lost {count} frames in the last {window} s: more edges than the link carries "
        "(its queue overflowed) or line noise; the {cost}s they touched were dropped"
    ),
    "zero_reference_too_early": (
        "{count} spurious zero references in the last {window} s (switch bounce or "
        "noise on its line): ignored"
    ),
    "missed_edges": (
        "the turret missed {count} receiver edges in the last {window} s (pulses or gaps of a few us: a "
        "glitching receiver); the {cost}s they touched were dropped"
    ),
    "bad_revolution_period": (
        "{count} revolutions of implausible length in the last {window} s (the turret "
        "stalled or changed speed, or a zero reference was missed): refused"
    ),
}


class SerialSource:
    """SerialEdgeSource as an EdgeSource, opened at start-up, read by a thread of its own that waits on the
    port and wakes the driver (`host.wake`) at each revolution; the lock keeps poll() and health() off it."""

    def __init__(self, values: Mapping[str, Any], _codes: Sequence[Any], host: SourceHost) -> None:
        def value(spec: ParameterSpec) -> Any:
            return values.get(spec.name, spec.default)

        self.zero_reference_timeout_s = float(value(ZERO_REFERENCE_TIMEOUT))
        self.lost_frames_cost = str(value(LOST_FRAMES_COST))
        self.serial = SerialEdgeSource(
            values["device"],
            values["baud_rate"],
            read_timeout_s=READ_WAIT_S,
            sleep=lambda _s: None,  # the reader thread waits for a lost device itself, not in the lock
            assembler=RevolutionAssembler(
                min_tolerance_s=float(value(MIN_REVOLUTION_TOLERANCE)),
                lost_frames_cost=self.lost_frames_cost,
            ),
            clock=host.now_s,
            log=host.log_warning,
        )
        self.serial.open()
        self._log_info, self._wake = host.log_info, host.wake
        self._lock, self._stopping = threading.Lock(), threading.Event()
        self._pending, self._broken = [], False
        self._reader = threading.Thread(target=self._read, name="serial_source", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        """The reader thread: wait for bytes (or a lost device's next attempt), read, keep, wake."""
        serial, reconnections = self.serial, 0
        while not self._stopping.wait(READ_INTERVAL_S):
            port = serial.port
            if port is None:  # a lost device: read() tries it again once its back-off allows
                self._stopping.wait(READ_WAIT_S)
            elif not select.select([port], [], [], READ_WAIT_S)[0]:
                continue
            with self._lock:
                revolutions = serial.read()
                # no window joins across a reconnection (the old stream's unpolled revolutions go) or a drop
                if serial.reconnections != reconnections or len(self._pending) >= MAX_PENDING_REVOLUTIONS:
                    reconnections, self._pending, self._broken = serial.reconnections, [], True
                self._pending += revolutions
            if revolutions:
                self._wake()

    def poll(self, now_s: float) -> SourcePoll:
        with self._lock:
            poll = SourcePoll(self._pending, continuity_broken=self._broken)
            self._pending, self._broken = [], False
        return poll

    def health(self) -> SourceHealth:
        with self._lock:
            return self._health()

    def _health(self) -> SourceHealth:
        serial = self.serial
        values: dict[str, Any] = {f"serial_drops_{reason}": count for reason, count in serial.drops.items()}
        values.update(
            serial_connected=serial.connected,
            serial_disconnections=serial.disconnections,
            serial_reconnections=serial.reconnections,
            serial_missed_edges=serial.parser.missed_edges,
        )
        device = serial.parser.device
        if device is not None:
            expected_ticks, tolerance_ticks = serial.assembler.expected_span()
            values.update(
                serial_device_protocol_version=device.version,
                serial_device_timer_hz=device.timer_hz,
                serial_device_ticks_per_revolution=device.ticks_per_revolution,
                serial_device_dropped_events=device.dropped_events,
                serial_turret_period_s=expected_ticks / device.timer_hz,
                serial_turret_period_tolerance_s=tolerance_ticks / device.timer_hz,
            )
        recent = serial.recent_drops()
        if not serial.connected:
            why = f" ({serial.last_error})" if serial.last_error else ""
            return SourceHealth("error", f"serial device {serial.device} lost, reconnecting{why}", values)
        if serial.stream_problem:
            return SourceHealth("error", serial.stream_problem, values)
        silence_s = serial.zero_reference_silence_s()
        if silence_s is not None and silence_s > self.zero_reference_timeout_s:
            return SourceHealth(
                "error",
                f"no zero reference for {silence_s:.1f} s: turret stopped or switch unplugged (the turret's "
                f"frames still arrive)",
                values,
            )
        if serial.frame_silence_s() > self.zero_reference_timeout_s:
            return SourceHealth(
                "error",
                f"no frame from the turret for {serial.frame_silence_s():.1f} s (the firmware sends a "
                f"heartbeat every 33 ms): its firmware hung or the link is cut",
                values,
            )
        warnings = [
            text.format(count=recent[reason], window=f"{RECENT_DROPS_WARN_S:.0f}", cost=self.lost_frames_cost)
            for reason, text in WARNED_DROPS.items()
            if recent[reason]
        ]
        if warnings:
            return SourceHealth("warn", "; ".join(warnings), values)
        return SourceHealth("ok", None, values)

    def close(self) -> None:
        self._stopping.set()
        self._reader.join(timeout=10 * READ_WAIT_S)
        self.serial.close()
        self._log_info(f"serial device {self.serial.device} released")


EDGE_SOURCE = EdgeSourceKind("serial", SERIAL_PARAMETERS, SerialSource)
