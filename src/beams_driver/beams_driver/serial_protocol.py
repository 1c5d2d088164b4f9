"""The serial wire format of the BeAMS turret's microcontroller, protocol version 2 (thesis section
2.4.1-2.4.2: the firmware streams every capture of its one timer; the host decodes). Both ends of the link:
`FrameEncoder` (the firmware's side, or the simulator's), `FrameParser` (bytes in, events out) and
`RevolutionAssembler` (events in, `RevolutionEdges` out). Frames and their faults: docs/firmware.md."""

import binascii
import itertools
import math
import statistics
import struct
from collections import Counter, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from beams_driver.edges import RevolutionEdges

PROTOCOL_VERSION = 2
SYNC = b"\xa5\x5b"
FRAME_SIZE = 10  # an event frame; a hello is HELLO_SIZE
HELLO_SIZE = 24
TIMER_MODULUS = 1 << 32
_HALF_MODULUS = TIMER_MODULUS // 2
# firmware/turret/config.h's link, clock and periodic frames (test_firmware_constants keeps them equal)
DEFAULT_BAUDRATE = 500_000
FIRMWARE_TIMER_HZ = 2_000_000
FIRMWARE_TICKS_PER_REVOLUTION = 200_000
HEARTBEAT_TICKS = 1 << 16
HEARTBEATS_PER_HELLO = 8
HEARTBEAT_PERIOD_S = HEARTBEAT_TICKS / FIRMWARE_TIMER_HZ  # 32.768 ms
HELLO_PERIOD_S = HEARTBEATS_PER_HELLO * HEARTBEAT_PERIOD_S  # 262.144 ms
# The simulated device's clock (FrameEncoder's defaults): the thesis's PIC timer (section 2.4.2).
TIMER_HZ = 625_000
TICKS_PER_REVOLUTION = 62_400
V1_SYNC = b"\xa5\x5a"
V1_FRAME_SIZE = 8
# Valid version-1 frames, with no version-2 frame among them, after which the stream is called v1.
V1_FRAMES_BEFORE_PROBLEM = 4
_CRC_INIT = 0xFFFF
_HEADER = struct.Struct("<BBI")  # kind, sequence, timer
_V1_BODY = struct.Struct("<BBH")  # protocol v1: kind, sequence, 16-bit timer
_HELLO_FIELDS = struct.Struct("<BBIII")  # version, flags, timer Hz, ticks per revolution, dropped events
_CRC = struct.Struct("<H")
_HELLO_BOOT_FLAG = 0x01
_TWO_PI = 2.0 * math.pi
# The measured turret speed: lengths kept, needed, tolerance in spreads and its floor (s; a zero reference
# is up to 10 us late, docs/firmware.md).
MEASURED_SPANS = 9
MIN_MEASURED_SPANS = 3
SPAN_SIGMAS = 5.0
MIN_SPAN_TOLERANCE_S = 20e-6
# What frames lost inside a revolution cost (RevolutionAssembler): the whole revolution, or only the beacon
# windows within the decoder's timeout of where they were lost (RevolutionEdges.lost_angles_rad).
LOST_FRAMES_COSTS = ("revolution", "window")
# 1.4826 MAD is the standard deviation of normal data.
_MAD_TO_SIGMA = 1.4826


class EventKind(IntEnum):
    """The kind byte of a frame."""

    RISING = 0x01
    FALLING = 0x02
    ZERO_REFERENCE = 0x03
    HEARTBEAT = 0x04
    MISSED_EDGE = 0x05
    HELLO = 0x10


# plain ints and a lookup table: the parser's per-frame path avoids the Enum machinery
_HELLO_KIND = int(EventKind.HELLO)
_EVENT_KIND_OF = {int(kind): kind for kind in EventKind if kind != EventKind.HELLO}
_V1_KINDS = frozenset((0x01, 0x02, 0x03, 0x04))


@dataclass(frozen=True)
class DeviceHello:
    """What the device says of itself in a hello frame."""

    version: int
    timer_hz: int
    ticks_per_revolution: int
    dropped_events: int = 0
    boot: bool = False

    @property
    def clock(self) -> tuple[int, int]:
        return self.timer_hz, self.ticks_per_revolution

    def problem(self) -> str:
        """Why this host cannot use the device ("" when it can)."""
        if self.version != PROTOCOL_VERSION:
            newer = self.version > PROTOCOL_VERSION
            return (
                f"the turret's firmware speaks BeAMS serial protocol v{self.version} and this host speaks "
                f"v{PROTOCOL_VERSION}: "
                + ("update the host (beams_driver)" if newer else "flash firmware/turret (docs/firmware.md)")
            )
        if self.timer_hz <= 0 or self.ticks_per_revolution <= 0:
            return (
                f"the turret's hello says timer {self.timer_hz} Hz, {self.ticks_per_revolution} ticks per "
                f"revolution: both must be positive (a firmware built with a wrong configuration)"
            )
        return ""


V1_STREAM_PROBLEM = (
    f"the turret's firmware speaks BeAMS serial protocol v1 (8-byte frames, 16-bit 625 kHz timer, no hello) "
    f"and this host speaks v{PROTOCOL_VERSION}: flash firmware/turret (docs/firmware.md)"
)


class FrameEvent(NamedTuple):
    """One correctly framed event, its timer unwrapped to monotonic ticks; `hello` for kind HELLO."""

    kind: EventKind
    ticks: int
    sequence: int
    after_gap: bool
    hello: DeviceHello | None = None


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of data (poly 0x1021, init 0xFFFF)."""
    return binascii.crc_hqx(data, _CRC_INIT)


def _framed(body: bytes, sync: bytes = SYNC) -> bytes:
    return sync + body + _CRC.pack(crc16(body))


def encode_frame(kind: EventKind | int, sequence: int, timer: int) -> bytes:
    """One 10-byte event frame; the timer is taken modulo 2^32 as the device's extended count is."""
    return _framed(_HEADER.pack(int(kind), sequence & 0xFF, timer % TIMER_MODULUS))


def encode_v1_frame(kind: int, sequence: int, timer: int) -> bytes:
    """A protocol v1 frame (the old firmware's), which the parser recognises to name the old firmware."""
    return _framed(_V1_BODY.pack(kind, sequence & 0xFF, timer % (1 << 16)), V1_SYNC)


def encode_hello(sequence: int, timer: int, hello: DeviceHello) -> bytes:
    """One 24-byte hello frame."""
    header = _HEADER.pack(int(EventKind.HELLO), sequence & 0xFF, timer % TIMER_MODULUS)
    flags = _HELLO_BOOT_FLAG if hello.boot else 0
    fields = _HELLO_FIELDS.pack(
        hello.version & 0xFF, flags, hello.timer_hz, hello.ticks_per_revolution, hello.dropped_events
    )
    return _framed(header + fields)


class FrameEncoder:
    """The firmware's side of the link (a simulated device), hellos and heartbeats as firmware/turret.

    `event(..., lost=True)`: an event captured with no room to send it: numbered, counted, not sent.
    """

    def __init__(
        self,
        first_sequence: int = 0,
        timer_hz: int = TIMER_HZ,
        ticks_per_revolution: int = TICKS_PER_REVOLUTION,
        version: int = PROTOCOL_VERSION,
    ) -> None:
        self._sequence = first_sequence & 0xFF
        self._last_ticks: int | None = None
        self.timer_hz = int(timer_hz)
        self.ticks_per_revolution = int(ticks_per_revolution)
        self.version = version
        self.dropped_events = 0
        self._heartbeat_ticks = max(1, round(HEARTBEAT_PERIOD_S * timer_hz))
        self._next_periodic: int | None = None
        self._periodic_count = 0
        self._booted = False

    def event(self, kind: EventKind, ticks: int, *, lost: bool = False) -> bytes:
        """The frame of one capture, preceded by the periodic frames (hello, heartbeats) due before it."""
        if self._last_ticks is not None and ticks < self._last_ticks:
            raise ValueError(f"captures must be in time order: {ticks} after {self._last_ticks}")
        out = bytearray()
        if self._next_periodic is None:  # start-up: the boot hello
            out += self._hello(ticks)
            self._next_periodic = ticks + self._heartbeat_ticks
        while self._next_periodic <= ticks:
            self._periodic_count += 1
            due = self._next_periodic
            out += (
                self._hello(due)
                if self._periodic_count % HEARTBEATS_PER_HELLO == 0
                else self._frame(EventKind.HEARTBEAT, due)
            )
            self._next_periodic += self._heartbeat_ticks
        if lost:
            self._sequence = (self._sequence + 1) & 0xFF
            self.dropped_events += 1
            self._last_ticks = ticks
        else:
            out += self._frame(kind, ticks)
        return bytes(out)

    def revolution(self, edges: RevolutionEdges, tick_rate_hz: float | None = None) -> bytes:
        """The frames of one revolution: its opening zero reference, then every edge in time order."""
        rate = self.timer_hz if tick_rate_hz is None else tick_rate_hz
        opening_ticks = seconds_to_ticks(edges.start_time_s, rate)
        out = bytearray(self.event(EventKind.ZERO_REFERENCE, opening_ticks))
        ticks = np.rint(np.asarray(edges.edge_times_s, dtype=float) * rate).astype(np.int64)
        for tick, rising in zip(ticks.tolist(), np.asarray(edges.edge_rising).tolist(), strict=True):
            out += self.event(EventKind.RISING if rising else EventKind.FALLING, tick)
        return bytes(out)

    def revolutions(self, revolutions: Iterable[RevolutionEdges], tick_rate_hz: float | None = None) -> bytes:
        """Consecutive revolutions, closed by the zero reference that ends the last one."""
        rate = self.timer_hz if tick_rate_hz is None else tick_rate_hz
        out = bytearray()
        last: RevolutionEdges | None = None
        for edges in revolutions:
            out += self.revolution(edges, rate)
            last = edges
        if last is not None:
            closing_s = last.start_time_s + last.period_s
            out += self.event(EventKind.ZERO_REFERENCE, seconds_to_ticks(closing_s, rate))
        return bytes(out)

    def _hello(self, ticks: int) -> bytes:
        hello = DeviceHello(
            self.version, self.timer_hz, self.ticks_per_revolution, self.dropped_events, not self._booted
        )
        self._booted = True
        frame = encode_hello(self._sequence, ticks, hello)
        self._advance(ticks)
        return frame

    def _frame(self, kind: EventKind, ticks: int) -> bytes:
        frame = encode_frame(kind, self._sequence, ticks)
        self._advance(ticks)
        return frame

    def _advance(self, ticks: int) -> None:
        self._sequence = (self._sequence + 1) & 0xFF
        self._last_ticks = ticks


def seconds_to_ticks(time_s: float, tick_rate_hz: float = TIMER_HZ) -> int:
    """The timer count at an instant (nearest tick)."""
    return round(time_s * tick_rate_hz)


class Drops(Counter[str]):
    """Drops counted by reason; every listener(reason, count) hears of each drop as it is counted."""

    def __init__(self) -> None:
        super().__init__()
        self.listeners: list[Callable[[str, int], None]] = []

    def add(self, reason: str, count: int = 1) -> None:
        self[reason] += count
        self.notify(reason, count)

    def notify(self, reason: str, count: int = 1) -> None:
        """Tell the listeners without counting: a loss reported elsewhere (a missed-edge frame)."""
        for listener in self.listeners:
            listener(reason, count)


class FrameParser:
    """Incremental stream parser: `feed(bytes)` returns the events of every complete, valid frame.

    `drops` by reason (docs/serial_integrity.md, with the byte accounting); `device` is the last accepted
    hello, `problem` why the stream cannot be used ("" while it can).
    """

    def __init__(self) -> None:
        self.drops = Drops()
        self.frames_ok = 0
        self.missed_edges = 0
        self.event_frames = 0
        self.hellos = 0
        self.bytes_fed = 0
        self.device: DeviceHello | None = None
        self.problem = ""
        self._buffer = bytearray()
        self._last_sequence: int | None = None
        self._last_timer: int | None = None
        self._ticks = 0
        self._gap = False
        self._v1_run = 0

    @property
    def pending_bytes(self) -> int:
        """Bytes held back because they may start a frame that is not complete yet."""
        return len(self._buffer)

    def new_stream(self) -> None:
        """Forget the partial frame, the sequence and the device (reconnected); ticks stay monotonic."""
        self._buffer.clear()
        self._last_sequence = None
        self._last_timer = None
        self.device = None
        self.problem = ""
        self._v1_run = 0
        self._gap = True

    def feed(self, data: bytes) -> list[FrameEvent]:
        """Parse the bytes received so far; never raises on any input."""
        self.bytes_fed += len(data)
        buffer = self._buffer
        buffer += data
        events: list[FrameEvent] = []
        position = 0
        end = len(buffer)
        while True:
            start = buffer.find(SYNC[:1], position)
            if start < 0:
                self._skip(end - position)
                position = end
                break
            self._skip(start - position)
            position = start
            if end - start < 3:
                break  # the sync pair and the kind are needed to know the candidate's size
            if buffer[start + 1] == V1_SYNC[1]:
                consumed = self._v1_candidate(buffer, start, end)
            elif buffer[start + 1] == SYNC[1]:
                consumed = self._candidate(buffer, start, end, events)
            else:
                consumed = -1
            if consumed == 0:
                break  # incomplete: wait for more bytes
            if consumed < 0:
                self._skip(1)  # a lone 0xA5
                position = start + 1
            else:
                position = start + consumed
        del buffer[:position]
        return events

    def flush(self) -> int:
        """Drop a pending partial frame at the end of a stream (a truncated frame); returns its bytes."""
        pending = len(self._buffer)
        if pending >= len(SYNC) and self._buffer[:2] == SYNC:
            self.drops.add("truncated")
            self._skip(pending - len(SYNC))
        else:
            self._skip(pending)
        self._buffer.clear()
        self._gap = self._gap or pending > 0
        return pending

    def _skip(self, n_bytes: int) -> None:
        if n_bytes > 0:
            self.drops.add("garbage_bytes", n_bytes)

    def _v1_candidate(self, buffer: bytearray, start: int, end: int) -> int:
        """Bytes consumed by a version-1 frame at start, 0 if incomplete, -1 if it is not one."""
        if end - start < V1_FRAME_SIZE:
            return 0
        body = bytes(buffer[start + 2 : start + 6])
        if body[0] not in _V1_KINDS or crc16(body) != _CRC.unpack_from(buffer, start + 6)[0]:
            return -1
        self.drops.add("protocol_v1_frames")
        self._v1_run += 1
        if self._v1_run >= V1_FRAMES_BEFORE_PROBLEM:
            self.problem = V1_STREAM_PROBLEM
        return V1_FRAME_SIZE

    def _candidate(self, buffer: bytearray, start: int, end: int, events: list[FrameEvent]) -> int:
        """Bytes consumed by the version-2 candidate at start (2 for a rejected one), 0 if incomplete."""
        size = HELLO_SIZE if buffer[start + 2] == _HELLO_KIND else FRAME_SIZE
        if end - start < size:
            return 0
        crc_at = start + size - 2
        if binascii.crc_hqx(buffer[start + 2 : crc_at], _CRC_INIT) != _CRC.unpack_from(buffer, crc_at)[0]:
            truncated = buffer.find(SYNC, start + 1, start + size) >= 0
            self.drops.add("truncated" if truncated else "bad_crc")
            self._gap = True
            return len(SYNC)
        self._v1_run = 0
        if self.problem == V1_STREAM_PROBLEM:
            self.problem = ""
        kind, sequence, timer = _HEADER.unpack_from(buffer, start + 2)
        if kind == _HELLO_KIND:
            fields = _HELLO_FIELDS.unpack_from(buffer, crc_at - _HELLO_FIELDS.size)  # before the CRC
            version, flags, timer_hz, ticks, dropped = fields
            hello = DeviceHello(version, timer_hz, ticks, dropped, bool(flags & _HELLO_BOOT_FLAG))
            event = self._hello(sequence, timer, hello)
        else:
            self.event_frames += 1
            event_kind = _EVENT_KIND_OF.get(kind)
            if event_kind is None:
                self.drops.add("unknown_kind")
                return size
            event = self._accept(event_kind, sequence, timer)
        if event is not None:
            events.append(event)
        return size

    def _hello(self, sequence: int, timer: int, hello: DeviceHello) -> FrameEvent | None:
        self.hellos += 1
        problem = hello.problem()
        if problem:
            self.problem = problem
            self.device = None
            self._gap = True
            return None
        if hello.boot or (self.device is not None and hello.clock != self.device.clock):
            # a reset (or reflashed) device: its numbering and its timer start again
            self._last_sequence = None
            self._last_timer = None
            self._gap = True
        self.device = hello
        self.problem = ""
        return self._accept(EventKind.HELLO, sequence, timer, hello)

    def _accept(
        self, kind: EventKind, sequence: int, timer: int, hello: DeviceHello | None = None
    ) -> FrameEvent | None:
        if self._last_sequence is not None:
            lost = (sequence - self._last_sequence - 1) & 0xFF
            if lost:
                self.drops.add("lost_frames", lost)
                self._gap = True
        self._last_sequence = sequence
        # 32-bit counts, taken as a signed difference: frames are less than 2^31 ticks apart (heartbeats)
        # but may leave the device a few ticks out of time order (interrupt priorities).
        if self._last_timer is not None:
            self._ticks += (timer - self._last_timer + _HALF_MODULUS) % TIMER_MODULUS - _HALF_MODULUS
        self._last_timer = timer
        if self.device is None:
            self.drops.add("incompatible_device" if self.problem else "before_hello")
            return None
        event = FrameEvent(kind, self._ticks, sequence, self._gap, hello)
        self._gap = False
        self.frames_ok += 1
        if kind == EventKind.MISSED_EDGE:
            self.missed_edges += 1
            self.drops.notify("missed_edges")  # heard as a drop: the windows it touches are dropped
        return event


class RevolutionAssembler:
    """Events in, `RevolutionEdges` out: one revolution between two consecutive zero references.

    An edge's angle is 2*pi times its ticks since the opening zero reference over the revolution's ticks
    (eq. 2.1 with the measured turret speed); times are ticks / timer Hz + `time_offset_s`. The clock is
    the hello's. Length judgement and drop reasons: docs/serial_integrity.md.
    """

    def __init__(
        self,
        tick_rate_hz: float | None = None,
        ticks_per_revolution: int | None = None,
        period_tolerance: float = 0.02,
        time_offset_s: float = 0.0,
        min_tolerance_s: float = MIN_SPAN_TOLERANCE_S,
        lost_frames_cost: str = "revolution",
    ) -> None:
        if not 0 < period_tolerance < 0.5:
            raise ValueError(f"period_tolerance ({period_tolerance}) must be in (0, 0.5)")
        if not min_tolerance_s > 0:
            raise ValueError(f"min_tolerance_s ({min_tolerance_s}) must be positive")
        if lost_frames_cost not in LOST_FRAMES_COSTS:
            raise ValueError(f"lost_frames_cost ({lost_frames_cost!r}) must be one of {LOST_FRAMES_COSTS}")
        self.lost_frames_cost = lost_frames_cost
        self.period_tolerance = float(period_tolerance)
        self.min_tolerance_s = float(min_tolerance_s)
        self.tick_rate_hz: float | None = None
        self.ticks_per_revolution: int | None = None
        self._spans: deque[int] = deque(maxlen=MEASURED_SPANS)
        if tick_rate_hz is not None or ticks_per_revolution is not None:
            self.set_clock(tick_rate_hz, ticks_per_revolution)
        self.time_offset_s = float(time_offset_s)
        self.drops = Drops()
        self.revolutions_ok = 0
        self._zero_ticks: int | None = None
        self._open_revolution = 0
        self._edge_ticks: list[int] = []
        self._edge_rising: list[bool] = []
        self._gap = False
        # a slightly early zero reference: (ticks, edges received before it), until the next one decides
        self._pending: tuple[int, int] | None = None
        # where frames were lost: (ticks of the events received before and after), and whether a loss
        # could not be placed (no event before it)
        self._lost_ticks: list[tuple[int, int]] = []
        self._unplaced_gap = False
        self._last_event_ticks: int | None = None

    def set_clock(self, tick_rate_hz: float | None, ticks_per_revolution: int | None) -> None:
        """The device's timer frequency (Hz) and nominal ticks per revolution; both must be positive."""
        if tick_rate_hz is None or ticks_per_revolution is None or not tick_rate_hz > 0:
            raise ValueError(f"tick_rate_hz ({tick_rate_hz}) must be positive")
        if not ticks_per_revolution > 0:
            raise ValueError(f"ticks_per_revolution ({ticks_per_revolution}) must be positive")
        self.tick_rate_hz = float(tick_rate_hz)
        self.ticks_per_revolution = int(ticks_per_revolution)
        self._tolerance_ticks = self.period_tolerance * self.ticks_per_revolution
        self._min_tolerance_ticks = self.min_tolerance_s * self.tick_rate_hz
        self._spans.clear()  # lengths measured with another clock mean nothing now
        self._measure_span()

    def expected_span(self) -> tuple[float, float]:
        """(ticks, tolerance in ticks) of the next revolution: measured (robust spread) once known."""
        assert self.ticks_per_revolution is not None
        return self._expected_span

    def _measure_span(self) -> None:
        """The expected span, again at each span measured (read at every zero reference and poll)."""
        if len(self._spans) < MIN_MEASURED_SPANS:
            self._expected_span = float(self.ticks_per_revolution), self._min_tolerance_ticks
            return
        spans = [float(span) for span in self._spans]  # a few: numpy's median costs more than sorting
        median = statistics.median(spans)
        sigma = _MAD_TO_SIGMA * statistics.median([abs(span - median) for span in spans])
        self._expected_span = median, max(self._min_tolerance_ticks, SPAN_SIGMAS * sigma)

    def reset(self) -> None:
        """Forget the open revolution (a reconnection); the measured turret speed is kept."""
        if self._zero_ticks is not None:
            self._open_revolution += 1
        self._zero_ticks = None
        self._edge_ticks.clear()
        self._edge_rising.clear()
        self._gap = False
        self._pending = None
        self._lost_ticks.clear()
        self._unplaced_gap = False

    def feed(self, events: Iterable[FrameEvent]) -> list[RevolutionEdges]:
        """Consume events; returns the revolutions they completed."""
        completed: list[RevolutionEdges] = []
        for event in events:
            if event.after_gap or event.kind == EventKind.MISSED_EDGE:
                self._gap = True
                if self._last_event_ticks is None:
                    self._unplaced_gap = True
                else:
                    ends = (self._last_event_ticks, event.ticks)
                    self._lost_ticks.append((min(ends), max(ends)))
            self._last_event_ticks = event.ticks
            kind = event.kind
            if kind == EventKind.HELLO:
                self._hello(event.hello)
            elif self.tick_rate_hz is None:
                if kind in (EventKind.RISING, EventKind.FALLING):
                    self.drops.add("edges_before_hello")
            elif kind == EventKind.ZERO_REFERENCE:
                completed += self._zero_reference(event.ticks)
            elif kind in (EventKind.RISING, EventKind.FALLING):
                if self._zero_ticks is None:
                    self.drops.add("edges_before_zero_reference")
                    continue
                self._edge_ticks.append(event.ticks)
                self._edge_rising.append(kind == EventKind.RISING)
        return completed

    def _hello(self, hello: DeviceHello | None) -> None:
        """A new clock or a boot hello starts the revolutions afresh (the cut one counts as with a gap)."""
        if hello is None:
            return
        if hello.clock != (self.tick_rate_hz, self.ticks_per_revolution):
            self.set_clock(hello.timer_hz, hello.ticks_per_revolution)
        elif not hello.boot:
            return
        if self._zero_ticks is not None:
            self.drops.add("revolution_with_gap")
        self.reset()

    def _zero_reference(self, zero_ticks: int) -> list[RevolutionEdges]:
        """Ignored when far too early, held when a little early, else closes the open revolution."""
        if self._zero_ticks is None:
            self._zero_ticks = zero_ticks
            self._gap = self._unplaced_gap = False  # losses before the first revolution cost it nothing
            self._lost_ticks.clear()
            return []
        expected, tolerance = self.expected_span()
        span = zero_ticks - self._zero_ticks
        if span < expected - self._tolerance_ticks:
            self.drops.add("zero_reference_too_early")  # a bounce or noise on the switch's line
            return []
        if abs(span - expected) <= tolerance:
            if self._pending is not None:
                self.drops.add("zero_reference_too_early")  # the held one was spurious
            return self._close(zero_ticks, len(self._edge_ticks), plausible=True)
        if span < expected and self._pending is None:
            self._pending = (zero_ticks, len(self._edge_ticks))  # spurious or a faster turret: wait
            return []
        completed: list[RevolutionEdges] = []
        if self._pending is not None:
            # the held one was no spurious zero reference: it closes the revolution (too short), and this
            # one is judged against it
            completed += self._close(*self._pending, plausible=False)
            completed += self._zero_reference(zero_ticks)
            return completed
        return self._close(zero_ticks, len(self._edge_ticks), plausible=False)

    def _close(self, zero_ticks: int, n_edges: int, *, plausible: bool) -> list[RevolutionEdges]:
        """Close the open revolution at this zero reference (its first n_edges edges) and open the next."""
        assert self._zero_ticks is not None and self.ticks_per_revolution is not None
        span_ticks = zero_ticks - self._zero_ticks
        expected, _ = self.expected_span()
        if abs(span_ticks - self.ticks_per_revolution) <= self._tolerance_ticks:
            self._spans.append(span_ticks)  # the measured turret speed, refused lengths included
            self._measure_span()
        else:
            plausible = False
        result = []
        if not plausible:
            self.drops.add("bad_revolution_period")
        elif self._gap and (self.lost_frames_cost == "revolution" or self._unplaced_gap):
            self.drops.add("revolution_with_gap")
        elif any(b < a for a, b in itertools.pairwise(self._edge_ticks[:n_edges])):
            self.drops.add("edges_out_of_order")  # a forged frame (noise that passed the CRC)
        else:
            if self._gap:
                self.drops.add("revolution_with_lost_frames")
            result.append(self._build(span_ticks, n_edges))
        # Revolutions lost in a gap still advance the count, so numbers follow the turret.
        self._open_revolution += max(1, round(span_ticks / expected))
        self._zero_ticks = zero_ticks
        split = n_edges < len(self._edge_ticks)
        self._edge_ticks = self._edge_ticks[n_edges:]
        self._edge_rising = self._edge_rising[n_edges:]
        self._gap = self._gap and split  # a gap before a held zero reference may lie after it: keep it
        self._unplaced_gap = self._unplaced_gap and split
        self._lost_ticks = [lost for lost in self._lost_ticks if lost[1] > zero_ticks]
        self._pending = None
        return result

    def _build(self, span_ticks: int, n_edges: int) -> RevolutionEdges:
        """The revolution opened by the last zero reference, spanning span_ticks, of its first n_edges."""
        assert self._zero_ticks is not None and self.tick_rate_hz is not None
        edge_ticks = self._edge_ticks[:n_edges]
        since_zero = np.asarray(edge_ticks, dtype=np.int64) - self._zero_ticks
        # An edge latched on the closing zero reference's tick stays inside [0, 2*pi); one latched a few
        # ticks before the opening one (its interrupt came first) is at angle 0.
        angles = np.clip(_TWO_PI * since_zero / span_ticks, 0.0, math.nextafter(_TWO_PI, 0.0))
        self.revolutions_ok += 1
        return RevolutionEdges(
            revolution=self._open_revolution,
            start_time_s=self._zero_ticks / self.tick_rate_hz + self.time_offset_s,
            period_s=span_ticks / self.tick_rate_hz,
            edge_times_s=np.asarray(edge_ticks, dtype=float) / self.tick_rate_hz + self.time_offset_s,
            edge_angles_rad=angles,
            edge_rising=np.asarray(self._edge_rising[:n_edges], dtype=bool),
            lost_angles_rad=_TWO_PI
            * (np.asarray(self._lost_ticks, dtype=float).reshape(-1, 2) - self._zero_ticks)
            / span_ticks,
        )
