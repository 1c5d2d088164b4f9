"""The serial wire format: framing, CRC, timer unwrapping, resynchronisation, revolution assembly."""

import itertools
import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_driver import serial_protocol
from beams_driver.edges import RevolutionEdges
from beams_driver.serial_protocol import (
    FRAME_SIZE,
    HEARTBEAT_INTERVAL_TICKS,
    SYNC,
    TICKS_PER_REVOLUTION,
    TIMER_HZ,
    TIMER_MODULUS,
    EventKind,
    FrameEncoder,
    FrameParser,
    RevolutionAssembler,
    crc16,
    encode_frame,
)

PERIOD_S = TICKS_PER_REVOLUTION / TIMER_HZ
HALF_TICK_RAD = math.pi / TICKS_PER_REVOLUTION


def make_revolutions(
    count: int, seed: int = 0, first: int = 0, edges_per_rev: int = 40
) -> list[RevolutionEdges]:
    """Revolutions with random edge instants at the nominal turret speed (angles follow eq. 2.1)."""
    rng = np.random.default_rng(seed)
    revolutions = []
    for k in range(first, first + count):
        start_s = k * PERIOD_S
        fractions = np.sort(rng.uniform(0.0, 1.0, edges_per_rev))
        revolutions.append(
            RevolutionEdges(
                revolution=k,
                start_time_s=start_s,
                period_s=PERIOD_S,
                edge_times_s=start_s + fractions * PERIOD_S,
                edge_angles_rad=2.0 * np.pi * fractions,
                edge_rising=np.arange(edges_per_rev) % 2 == 0,
            )
        )
    return revolutions


def assemble(
    data: bytes, chunk: int | None = None
) -> tuple[list[RevolutionEdges], FrameParser, RevolutionAssembler]:
    parser, assembler = FrameParser(), RevolutionAssembler()
    step = chunk or max(1, len(data))
    revolutions = []
    for offset in range(0, len(data), step):
        revolutions += assembler.feed(parser.feed(data[offset : offset + step]))
    return revolutions, parser, assembler


def frame_offsets(data: bytes) -> list[int]:
    """Offsets of the frames an encoder produced back to back (every frame is 8 bytes)."""
    return list(range(0, len(data), FRAME_SIZE))


def accounted_bytes(parser: FrameParser) -> int:
    drops = parser.drops
    return (
        FRAME_SIZE * (parser.frames_ok + drops["unknown_kind"])
        + len(SYNC) * (drops["bad_crc"] + drops["truncated"])
        + drops["garbage_bytes"]
        + parser.pending_bytes
    )


def test_crc_is_ccitt_false() -> None:
    assert crc16(b"123456789") == 0x29B1


@pytest.mark.parametrize(
    ("kind", "sequence", "timer"),
    [(EventKind.RISING, 0, 0x1234), (EventKind.FALLING, 1, 0x1290), (EventKind.ZERO_REFERENCE, 255, 0xFFF0)],
)
def test_docstring_examples_are_what_the_encoder_sends(kind: EventKind, sequence: int, timer: int) -> None:
    frame = encode_frame(kind, sequence, timer)
    documented = re.findall(rf"A5 5A 0{int(kind)}(?: [0-9A-F]{{2}}){{5}}", serial_protocol.__doc__)
    assert len(frame) == FRAME_SIZE
    assert [frame.hex(" ").upper()] == [line.strip() for line in documented]


@pytest.mark.parametrize("chunk", [None, 1, 5, 4096])
def test_round_trip_restores_angles_to_half_a_tick(chunk: int | None) -> None:
    sent = make_revolutions(4, seed=1)
    received, parser, assembler = assemble(FrameEncoder().revolutions(sent), chunk)
    assert [r.revolution for r in received] == [0, 1, 2, 3]
    for original, decoded in zip(sent, received, strict=True):
        assert decoded.period_s == pytest.approx(PERIOD_S, abs=1e-12)
        assert decoded.start_time_s == pytest.approx(original.start_time_s, abs=0.5 / TIMER_HZ)
        np.testing.assert_array_equal(decoded.edge_rising, original.edge_rising)
        assert np.max(np.abs(decoded.edge_angles_rad - original.edge_angles_rad)) <= HALF_TICK_RAD * 1.0001
        assert np.max(np.abs(decoded.edge_times_s - original.edge_times_s)) <= 0.5 / TIMER_HZ + 1e-12
    assert sum(parser.drops.values()) == 0
    assert sum(assembler.drops.values()) == 0


def test_timer_unwraps_across_many_wraps_and_idle_revolutions() -> None:
    # 30 revolutions (28 wraps of the 16-bit timer), edges only in every fifth: heartbeats bridge the rest.
    sent = [r for r in make_revolutions(30, seed=2, first=1000) if r.revolution % 5 == 0]
    encoder = FrameEncoder()
    data = bytearray()
    last = None
    for revolution in make_revolutions(30, seed=2, first=1000):
        if revolution.revolution % 5 != 0:
            revolution = RevolutionEdges(
                revolution.revolution,
                revolution.start_time_s,
                PERIOD_S,
                np.empty(0),
                np.empty(0),
                np.empty(0, bool),
            )
        data += encoder.revolution(revolution)
        last = revolution
    data += encoder.event(EventKind.ZERO_REFERENCE, round((last.start_time_s + PERIOD_S) * TIMER_HZ))
    events = FrameParser().feed(bytes(data))
    ticks = np.array([e.ticks for e in events])
    kinds = [e.kind for e in events]
    assert np.all(np.diff(ticks) > 0)
    assert np.max(np.diff(ticks)) <= HEARTBEAT_INTERVAL_TICKS
    assert kinds.count(EventKind.ZERO_REFERENCE) == 31
    assert kinds.count(EventKind.HEARTBEAT) == 24  # one per empty revolution: 62400 > 32768 ticks apart
    # Unwrapped ticks advance exactly as the device's timer did (first frame taken as the origin).
    zero_ticks = ticks[[k == EventKind.ZERO_REFERENCE for k in kinds]]
    np.testing.assert_array_equal(np.diff(zero_ticks), TICKS_PER_REVOLUTION)
    revolutions = RevolutionAssembler().feed(events)
    with_edges = [r for r in revolutions if r.n_edges]
    assert [r.n_edges for r in with_edges] == [r.n_edges for r in sent]
    for original, decoded in zip(sent, with_edges, strict=True):
        assert np.max(np.abs(decoded.edge_angles_rad - original.edge_angles_rad)) <= HALF_TICK_RAD * 1.0001


def test_encoder_frames_carry_the_timer_modulo_65536() -> None:
    frame = FrameEncoder().event(EventKind.RISING, 3 * TIMER_MODULUS + 7)
    assert frame == encode_frame(EventKind.RISING, 0, 7)
    with pytest.raises(ValueError, match="time order"):
        encoder = FrameEncoder()
        encoder.event(EventKind.RISING, 10)
        encoder.event(EventKind.RISING, 9)


def corrupt(data: bytes, frame_index: int, byte_in_frame: int) -> bytes:
    damaged = bytearray(data)
    damaged[frame_index * FRAME_SIZE + byte_in_frame] ^= 0x10
    return bytes(damaged)


def test_bad_checksum_drops_one_frame_and_the_revolution_it_falls_in() -> None:
    sent = make_revolutions(5, seed=3)
    data = FrameEncoder().revolutions(sent)
    frames_per_revolution = 1 + 40
    damaged = corrupt(data, 2 * frames_per_revolution + 10, 5)  # an edge in revolution 2
    received, parser, assembler = assemble(damaged, chunk=64)
    assert parser.drops["bad_crc"] == 1
    assert parser.drops["lost_frames"] == 1  # the sequence numbers confirm the frame is missing
    assert parser.frames_ok == len(data) // FRAME_SIZE - 1
    assert [r.revolution for r in received] == [0, 1, 3, 4]
    assert assembler.drops["revolution_with_gap"] == 1
    assert accounted_bytes(parser) == len(damaged)


def test_truncated_frame_is_counted_and_the_next_frame_survives() -> None:
    data = FrameEncoder().revolutions(make_revolutions(3, seed=4))
    cut = 45 * FRAME_SIZE
    damaged = data[: cut + 5] + data[cut + FRAME_SIZE :]  # frame 45 loses its last 3 bytes
    received, parser, _ = assemble(damaged)
    assert parser.drops["truncated"] == 1
    assert parser.drops["bad_crc"] == 0
    assert parser.frames_ok == len(data) // FRAME_SIZE - 1
    assert [r.revolution for r in received] == [0, 2]
    assert accounted_bytes(parser) == len(damaged)


def test_garbage_between_frames_is_skipped_without_losing_a_frame() -> None:
    sent = make_revolutions(3, seed=5)
    data = FrameEncoder().revolutions(sent)
    rng = np.random.default_rng(5)
    noisy = bytearray()
    garbage_total = 0
    for offset in frame_offsets(data):
        garbage = bytes(rng.choice([0x00, 0x5A, 0xFF, 0x13], size=rng.integers(0, 4)).astype(np.uint8))
        garbage_total += len(garbage)
        noisy += garbage + data[offset : offset + FRAME_SIZE]
    received, parser, assembler = assemble(bytes(noisy), chunk=7)
    assert parser.drops["garbage_bytes"] == garbage_total
    assert parser.frames_ok == len(data) // FRAME_SIZE
    assert [r.revolution for r in received] == [0, 1, 2]
    assert sum(assembler.drops.values()) == 0


def test_lost_frames_are_counted_from_sequence_numbers() -> None:
    data = FrameEncoder(first_sequence=250).revolutions(make_revolutions(3, seed=6))
    damaged = data[: 50 * FRAME_SIZE] + data[53 * FRAME_SIZE :]  # three whole frames vanish (seq wraps)
    received, parser, assembler = assemble(damaged)
    assert parser.drops["lost_frames"] == 3
    assert [r.revolution for r in received] == [0, 2]
    assert assembler.drops["revolution_with_gap"] == 1


def test_unknown_kind_with_valid_crc_is_skipped_whole() -> None:
    data = b"".join(
        [
            encode_frame(EventKind.RISING, 0, 100),
            encode_frame(0x7F, 1, 200),
            encode_frame(EventKind.FALLING, 2, 300),
        ]
    )
    events = (parser := FrameParser()).feed(data)
    assert [(e.kind, e.ticks) for e in events] == [(EventKind.RISING, 100), (EventKind.FALLING, 300)]
    assert parser.drops["unknown_kind"] == 1
    assert accounted_bytes(parser) == len(data)


def test_flush_counts_a_dangling_partial_frame() -> None:
    parser = FrameParser()
    parser.feed(encode_frame(EventKind.RISING, 0, 1) + encode_frame(EventKind.RISING, 1, 2)[:5])
    assert parser.pending_bytes == 5
    assert parser.flush() == 5
    assert parser.drops["truncated"] == 1
    assert parser.drops["garbage_bytes"] == 3


def capture_list(revolutions: list[RevolutionEdges]) -> list[tuple[EventKind, int]]:
    """(kind, ticks) of every capture the firmware makes during these revolutions, closing zero included."""
    captures = []
    for revolution in revolutions:
        captures.append((EventKind.ZERO_REFERENCE, round(revolution.start_time_s * TIMER_HZ)))
        for time_s, rising in zip(revolution.edge_times_s, revolution.edge_rising, strict=True):
            captures.append((EventKind.RISING if rising else EventKind.FALLING, round(time_s * TIMER_HZ)))
    end_s = revolutions[-1].start_time_s + revolutions[-1].period_s
    return [*captures, (EventKind.ZERO_REFERENCE, round(end_s * TIMER_HZ))]


def test_capture_list_matches_the_encoder() -> None:
    revolutions = make_revolutions(2, seed=9)
    encoder = FrameEncoder()
    sent = b"".join(encoder.event(*c) for c in capture_list(revolutions))
    assert sent == FrameEncoder().revolutions(revolutions)


def test_missing_zero_reference_gives_a_bad_period_and_numbering_follows_the_turret() -> None:
    captures = capture_list(make_revolutions(4, seed=7))
    missed = captures.index((EventKind.ZERO_REFERENCE, 2 * TICKS_PER_REVOLUTION))
    encoder = FrameEncoder()  # the optical switch missed revolution 2's zero reference: no frame at all
    data = b"".join(encoder.event(*c) for i, c in enumerate(captures) if i != missed)
    received, parser, assembler = assemble(data)
    assert parser.drops.total() == 0
    assert [r.revolution for r in received] == [0, 3]
    assert assembler.drops["bad_revolution_period"] == 1


def test_edges_before_the_first_zero_reference_are_dropped() -> None:
    encoder = FrameEncoder()
    data = encoder.event(EventKind.RISING, 10) + encoder.event(EventKind.FALLING, 20)
    data += FrameEncoder(first_sequence=2).revolutions(make_revolutions(1, seed=8, first=1))
    received, _, assembler = assemble(data)
    assert assembler.drops["edges_before_zero_reference"] == 2
    assert [r.revolution for r in received] == [0]


def test_assembler_rejects_nonsense_configuration() -> None:
    with pytest.raises(ValueError, match="period_tolerance"):
        RevolutionAssembler(period_tolerance=0.7)


# ---- fuzzing -------------------------------------------------------------------------------------


def valid_frames_in(data: bytes) -> set[tuple[int, int, int]]:
    """(kind, sequence, timer) of every well-formed frame at any offset of data."""
    found = set()
    for offset in range(len(data) - FRAME_SIZE + 1):
        frame = data[offset : offset + FRAME_SIZE]
        well_formed = frame[:2] == SYNC and crc16(frame[2:6]) == int.from_bytes(frame[6:8], "little")
        if well_formed and frame[2] in {int(k) for k in EventKind}:
            found.add((frame[2], frame[3], int.from_bytes(frame[4:6], "little")))
    return found


frame_strategy = st.builds(
    encode_frame, st.sampled_from(list(EventKind)), st.integers(0, 255), st.integers(0, TIMER_MODULUS - 1)
)
stream_strategy = st.lists(st.one_of(st.binary(max_size=12), frame_strategy), max_size=30).map(b"".join)


@settings(max_examples=300, deadline=None)
@given(data=stream_strategy, cuts=st.lists(st.integers(0, 400), max_size=6))
def test_fuzz_parser_never_raises_and_emits_only_framed_events(data: bytes, cuts: list[int]) -> None:
    parser = FrameParser()
    events = []
    bounds = sorted({0, len(data), *(c for c in cuts if c < len(data))})
    for start, end in itertools.pairwise(bounds):
        events += parser.feed(data[start:end])
    genuine = valid_frames_in(data)
    last_ticks = None
    for event in events:
        assert (int(event.kind), event.sequence, event.ticks % TIMER_MODULUS) in genuine
        assert last_ticks is None or event.ticks >= last_ticks
        last_ticks = event.ticks
    assert accounted_bytes(parser) == len(data)
    for revolution in RevolutionAssembler().feed(events):  # never raises either, and only sane revolutions
        assert abs(revolution.period_s * TIMER_HZ - TICKS_PER_REVOLUTION) <= 0.02 * TICKS_PER_REVOLUTION
        angles = revolution.edge_angles_rad
        assert np.all((angles >= 0.0) & (angles < 2.0 * np.pi)) and np.all(np.diff(angles) >= 0.0)


@settings(max_examples=200, deadline=None)
@given(
    timers=st.lists(st.integers(0, TIMER_MODULUS - 1), min_size=1, max_size=25),
    garbage=st.lists(
        st.binary(max_size=10).map(lambda b: b.replace(SYNC[:1], b"")), min_size=26, max_size=26
    ),
)
def test_fuzz_every_frame_survives_garbage_without_a_sync_byte(
    timers: list[int], garbage: list[bytes]
) -> None:
    frames = [encode_frame(EventKind.RISING, i, timer) for i, timer in enumerate(timers)]
    data = b"".join(g + f for g, f in zip(garbage, frames, strict=False)) + garbage[-1]
    parser = FrameParser()
    events = parser.feed(data)
    assert [(e.sequence, e.ticks % TIMER_MODULUS) for e in events] == list(enumerate(timers))
    assert parser.drops["garbage_bytes"] == sum(len(g) for g in garbage[: len(timers)]) + len(garbage[-1])
    assert not any(e.after_gap for e in events)
