"""The serial wire format of the BeAMS sensor microcontroller: edge captures, framed and checksummed.

The sensor's PIC drives the stepper motor and captures the receiver's edges with one common timer
(thesis section 2.4.1-2.4.2): a 625 kHz timer, 62400 timer ticks per turret revolution (0.1 mrad per
tick, 625000/62400 = 10.016 turn/s), and an optical switch that marks the zero angle reference.
Instead of decoding on the microcontroller, the firmware streams every capture to the host, which
runs the decoder (`beams_driver.decoder`). This module is both ends of that link: `FrameEncoder`
(what the firmware, or the simulator standing in for it, sends), `FrameParser` (bytes in, events
out) and `RevolutionAssembler` (events in, `RevolutionEdges` out).

Frame layout (8 bytes, multi-byte fields little-endian)::

    offset  size  field
    0       1     sync 1 = 0xA5
    1       1     sync 2 = 0x5A
    2       1     kind: 0x01 rising edge, 0x02 falling edge, 0x03 zero reference, 0x04 heartbeat
    3       1     sequence number, +1 per frame sent, modulo 256
    4       2     timer value latched at the event (625 kHz, uint16, wraps every 65536 ticks = 104.9 ms)
    6       2     CRC-16/CCITT-FALSE of bytes 2..5 (poly 0x1021, init 0xFFFF, no reflection, xorout 0)

The CRC is the one `binascii.crc_hqx(data, 0xFFFF)` computes (check value of b"123456789": 0x29B1).

Kinds:
- rising / falling edge: the receiver output went 0 -> 1 / 1 -> 0 (section 2.4.3, phi_R and phi_F);
- zero reference: the turret passed the optical switch (section 2.4.2); it opens a revolution;
- heartbeat: sent when no other frame went out for `HEARTBEAT_INTERVAL_TICKS` (half the timer's wrap
  period), so that consecutive frames are always less than one wrap apart and the host can unwrap
  the 16-bit timer even when no beacon is in sight or the turret stalls.

Examples (hex)::

    rising edge,    seq 0,   timer 0x1234:  A5 5A 01 00 34 12 56 09
    falling edge,   seq 1,   timer 0x1290:  A5 5A 02 01 90 12 00 74
    zero reference, seq 255, timer 0xFFF0:  A5 5A 03 FF F0 FF 4E DD

Link: 460800 baud, 8N1 by default (57600 frames/s at most; a revolution with 5 beacons in sight
carries a few hundred edges, i.e. a few thousand frames/s).

Host side. The parser hunts for the sync pair and checks the CRC and the kind; on a bad checksum it
drops the candidate's sync pair and hunts again from the byte after it, so that a corrupted byte, a
truncated frame (another sync pair starts inside the candidate) or a bad checksum costs only the
frames it touches. Every drop is counted by reason in `FrameParser.drops`. The 16-bit timer is
unwrapped into a monotonic tick count by adding the forward difference modulo 65536 between
consecutive frames; a gap in the sequence numbers (lost frames) marks the next event `after_gap`, and the
assembler then discards the revolution it falls in, since the unwrapping across a gap is ambiguous.
The angle of an edge is 2*pi * (ticks since the revolution's zero reference) / (ticks between the
two zero references that bound the revolution) (eq. 2.1 with the measured turret speed).
"""

import binascii
import math
import struct
from collections import Counter
from collections.abc import Iterable
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from beams_driver.edges import RevolutionEdges

TIMER_HZ = 625_000
TICKS_PER_REVOLUTION = 62_400
TIMER_MODULUS = 1 << 16
HEARTBEAT_INTERVAL_TICKS = TIMER_MODULUS // 2
SYNC = b"\xa5\x5a"
FRAME_SIZE = 8
DEFAULT_BAUDRATE = 460_800
_CRC_INIT = 0xFFFF
_BODY = struct.Struct("<BBH")  # kind, sequence, timer
_CRC = struct.Struct("<H")
_TWO_PI = 2.0 * math.pi


class EventKind(IntEnum):
    """The kind byte of a frame."""

    RISING = 0x01
    FALLING = 0x02
    ZERO_REFERENCE = 0x03
    HEARTBEAT = 0x04


_KNOWN_KINDS = frozenset(int(kind) for kind in EventKind)


class FrameEvent(NamedTuple):
    """One correctly framed capture, with the timer unwrapped to a monotonic tick count."""

    kind: EventKind
    ticks: int
    sequence: int
    after_gap: bool


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of data (poly 0x1021, init 0xFFFF)."""
    return binascii.crc_hqx(data, _CRC_INIT)


def encode_frame(kind: EventKind, sequence: int, timer: int) -> bytes:
    """One 8-byte frame; the timer is taken modulo 65536 as the 16-bit hardware timer would."""
    body = _BODY.pack(int(kind), sequence & 0xFF, timer % TIMER_MODULUS)
    return SYNC + body + _CRC.pack(crc16(body))


class FrameEncoder:
    """The firmware's side of the link: numbers the frames and inserts heartbeats (a simulated device).

    Ticks are given unwrapped (monotonic); the frames carry them modulo 65536.
    """

    def __init__(self, first_sequence: int = 0) -> None:
        self._sequence = first_sequence & 0xFF
        self._last_ticks: int | None = None

    def event(self, kind: EventKind, ticks: int) -> bytes:
        """The frame of one capture, preceded by the heartbeats the firmware sends while idle."""
        if self._last_ticks is not None and ticks < self._last_ticks:
            raise ValueError(f"captures must be in time order: {ticks} after {self._last_ticks}")
        out = bytearray()
        if self._last_ticks is not None:
            while ticks - self._last_ticks > HEARTBEAT_INTERVAL_TICKS:
                out += self._frame(EventKind.HEARTBEAT, self._last_ticks + HEARTBEAT_INTERVAL_TICKS)
        out += self._frame(kind, ticks)
        return bytes(out)

    def revolution(self, edges: RevolutionEdges, tick_rate_hz: float = TIMER_HZ) -> bytes:
        """The frames of one revolution: its opening zero reference, then every edge in time order."""
        opening_ticks = seconds_to_ticks(edges.start_time_s, tick_rate_hz)
        out = bytearray(self.event(EventKind.ZERO_REFERENCE, opening_ticks))
        ticks = np.rint(np.asarray(edges.edge_times_s, dtype=float) * tick_rate_hz).astype(np.int64)
        for tick, rising in zip(ticks.tolist(), np.asarray(edges.edge_rising).tolist(), strict=True):
            out += self.event(EventKind.RISING if rising else EventKind.FALLING, tick)
        return bytes(out)

    def revolutions(self, revolutions: Iterable[RevolutionEdges], tick_rate_hz: float = TIMER_HZ) -> bytes:
        """Consecutive revolutions, closed by the zero reference that ends the last one."""
        out = bytearray()
        last: RevolutionEdges | None = None
        for edges in revolutions:
            out += self.revolution(edges, tick_rate_hz)
            last = edges
        if last is not None:
            closing_s = last.start_time_s + last.period_s
            out += self.event(EventKind.ZERO_REFERENCE, seconds_to_ticks(closing_s, tick_rate_hz))
        return bytes(out)

    def _frame(self, kind: EventKind, ticks: int) -> bytes:
        frame = encode_frame(kind, self._sequence, ticks)
        self._sequence = (self._sequence + 1) & 0xFF
        self._last_ticks = ticks
        return frame


def seconds_to_ticks(time_s: float, tick_rate_hz: float = TIMER_HZ) -> int:
    """The timer count at an instant (nearest tick)."""
    return round(time_s * tick_rate_hz)


class FrameParser:
    """Incremental stream parser: `feed(bytes)` returns the events of every complete, valid frame.

    Drop reasons counted in `drops` (frames unless stated):
    - "garbage_bytes": bytes skipped while hunting for a sync pair (bytes, not frames);
    - "bad_crc": a candidate frame whose checksum does not match;
    - "truncated": a candidate cut short by the next frame's sync pair (so its checksum fails too);
    - "unknown_kind": a frame with a valid checksum but a kind this host does not know;
    - "lost_frames": frames missing according to the sequence numbers.
    Byte accounting: bytes fed = 8 * (events + unknown_kind) + 2 * (bad_crc + truncated)
    + garbage_bytes + pending bytes.
    """

    def __init__(self) -> None:
        self.drops: Counter[str] = Counter()
        self.frames_ok = 0
        self.bytes_fed = 0
        self._buffer = bytearray()
        self._last_sequence: int | None = None
        self._last_timer = 0
        self._ticks = 0
        self._gap = False

    @property
    def pending_bytes(self) -> int:
        """Bytes held back because they may start a frame that is not complete yet."""
        return len(self._buffer)

    def new_stream(self) -> None:
        """Forget the partial frame and the sequence (the device was reconnected); ticks stay monotonic."""
        self._buffer.clear()
        self._last_sequence = None
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
            start = buffer.find(SYNC, position)
            if start < 0:
                # A trailing 0xA5 may be the first half of the next sync pair.
                keep = 1 if end > position and buffer[end - 1] == SYNC[0] else 0
                self._skip(end - keep - position)
                position = end - keep
                break
            self._skip(start - position)
            position = start
            if end - start < FRAME_SIZE:
                break
            event = self._parse_candidate(buffer, start)
            if event is None:
                position = start + len(SYNC)
                continue
            position = start + FRAME_SIZE
            if event is not _UNKNOWN:
                events.append(event)
        del buffer[:position]
        return events

    def flush(self) -> int:
        """Drop a pending partial frame at the end of a stream (a truncated frame); returns its bytes."""
        pending = len(self._buffer)
        if pending >= len(SYNC):
            self.drops["truncated"] += 1
            self._skip(pending - len(SYNC))
        else:
            self._skip(pending)
        self._buffer.clear()
        self._gap = self._gap or pending > 0
        return pending

    def _skip(self, n_bytes: int) -> None:
        if n_bytes > 0:
            self.drops["garbage_bytes"] += n_bytes

    def _parse_candidate(self, buffer: bytearray, start: int) -> FrameEvent | object | None:
        """The event of the frame at start, _UNKNOWN for an unknown kind, None for a rejected candidate."""
        body = bytes(buffer[start + 2 : start + 6])
        (received_crc,) = _CRC.unpack_from(buffer, start + 6)
        if crc16(body) != received_crc:
            truncated = buffer.find(SYNC, start + 1, start + FRAME_SIZE) >= 0
            self.drops["truncated" if truncated else "bad_crc"] += 1
            self._gap = True
            return None
        kind, sequence, timer = _BODY.unpack(body)
        if kind not in _KNOWN_KINDS:
            self.drops["unknown_kind"] += 1
            return _UNKNOWN
        return self._accept(EventKind(kind), sequence, timer)

    def _accept(self, kind: EventKind, sequence: int, timer: int) -> FrameEvent:
        if self._last_sequence is not None:
            lost = (sequence - self._last_sequence - 1) & 0xFF
            if lost:
                self.drops["lost_frames"] += lost
                self._gap = True
        # Consecutive frames are less than one wrap apart (heartbeats), so the forward difference is exact.
        self._ticks += (timer - self._last_timer) % TIMER_MODULUS
        self._last_timer = timer
        self._last_sequence = sequence
        event = FrameEvent(kind, self._ticks, sequence, self._gap)
        self._gap = False
        self.frames_ok += 1
        return event


_UNKNOWN = object()


class RevolutionAssembler:
    """Events in, `RevolutionEdges` out: one revolution between two consecutive zero references.

    The angle of an edge is 2*pi times its ticks since the opening zero reference over the ticks of the
    whole revolution (eq. 2.1, the turret speed measured over that revolution). Times are the device's
    ticks divided by `tick_rate_hz` plus `time_offset_s` (which the owner may update to map the device
    clock onto its own). Drops counted in `drops` (revolutions unless stated):
    - "edges_before_zero_reference": edges before the first zero reference (edges);
    - "revolution_with_gap": a revolution during which frames were lost or rejected;
    - "bad_revolution_period": a revolution whose tick count is off the nominal by more than
      `period_tolerance` (the turret stalled or a zero reference was missed).
    """

    def __init__(
        self,
        tick_rate_hz: float = TIMER_HZ,
        ticks_per_revolution: int = TICKS_PER_REVOLUTION,
        period_tolerance: float = 0.02,
        time_offset_s: float = 0.0,
    ) -> None:
        if not tick_rate_hz > 0 or not ticks_per_revolution > 0 or not 0 < period_tolerance < 0.5:
            raise ValueError(
                f"tick_rate_hz ({tick_rate_hz}) and ticks_per_revolution ({ticks_per_revolution}) must be "
                f"positive and period_tolerance ({period_tolerance}) in (0, 0.5)"
            )
        self.tick_rate_hz = float(tick_rate_hz)
        self.ticks_per_revolution = int(ticks_per_revolution)
        self.period_tolerance = float(period_tolerance)
        self._tolerance_ticks = period_tolerance * ticks_per_revolution
        self.time_offset_s = float(time_offset_s)
        self.drops: Counter[str] = Counter()
        self.revolutions_ok = 0
        self._zero_ticks: int | None = None
        self._open_revolution = 0
        self._edge_ticks: list[int] = []
        self._edge_rising: list[bool] = []
        self._gap = False

    def reset(self) -> None:
        """Forget the open revolution (e.g. after a reconnection); the next zero reference opens one."""
        if self._zero_ticks is not None:
            self._open_revolution += 1
        self._zero_ticks = None
        self._edge_ticks.clear()
        self._edge_rising.clear()
        self._gap = False

    def feed(self, events: Iterable[FrameEvent]) -> list[RevolutionEdges]:
        """Consume events; returns the revolutions they completed."""
        completed: list[RevolutionEdges] = []
        for event in events:
            if event.after_gap:
                self._gap = True
            kind = event.kind
            if kind == EventKind.ZERO_REFERENCE:
                revolution = self._close(event.ticks)
                if revolution is not None:
                    completed.append(revolution)
            elif kind != EventKind.HEARTBEAT:
                if self._zero_ticks is None:
                    self.drops["edges_before_zero_reference"] += 1
                    continue
                self._edge_ticks.append(event.ticks)
                self._edge_rising.append(kind == EventKind.RISING)
        return completed

    def _close(self, zero_ticks: int) -> RevolutionEdges | None:
        """Close the open revolution at this zero reference and open the next one."""
        result = None
        if self._zero_ticks is not None:
            span_ticks = zero_ticks - self._zero_ticks
            if self._gap:
                self.drops["revolution_with_gap"] += 1
            elif abs(span_ticks - self.ticks_per_revolution) > self._tolerance_ticks:
                self.drops["bad_revolution_period"] += 1
            else:
                result = self._build(span_ticks)
            # Revolutions lost in a gap still advance the count, so numbers follow the turret.
            self._open_revolution += max(1, round(span_ticks / self.ticks_per_revolution))
        self._zero_ticks = zero_ticks
        self._edge_ticks = []
        self._edge_rising = []
        self._gap = False
        return result

    def _build(self, span_ticks: int) -> RevolutionEdges:
        """The revolution opened by the last zero reference and spanning span_ticks."""
        assert self._zero_ticks is not None
        since_zero = np.asarray(self._edge_ticks, dtype=np.int64) - self._zero_ticks
        # An edge latched on the closing zero reference's tick stays inside [0, 2*pi).
        angles = np.minimum(_TWO_PI * since_zero / span_ticks, math.nextafter(_TWO_PI, 0.0))
        self.revolutions_ok += 1
        return RevolutionEdges(
            revolution=self._open_revolution,
            start_time_s=self._zero_ticks / self.tick_rate_hz + self.time_offset_s,
            period_s=span_ticks / self.tick_rate_hz,
            edge_times_s=np.asarray(self._edge_ticks, dtype=float) / self.tick_rate_hz + self.time_offset_s,
            edge_angles_rad=angles,
            edge_rising=np.asarray(self._edge_rising, dtype=bool),
        )
