"""Serial link and simulated world benchmark: parser and assembler throughput against what the
serial link can carry, and the cost of the simulated robot and of a whole offline match; the link's
integrity: revolutions kept under line noise, and the worst bearing error under spurious
zero references.
"""

import sys

import numpy as np
from rows_table import Row, bench_main, best_per_call_s

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_driver.decoder import BearingDecoder
from beams_driver.edges import RevolutionEdges
from beams_driver.serial_protocol import (
    DEFAULT_BAUDRATE,
    FRAME_SIZE,
    HELLO_SIZE,
    TIMER_HZ,
    EventKind,
    FrameEncoder,
    FrameParser,
    RevolutionAssembler,
)
from beams_driver.variance import VarianceModel
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator
from beams_sim.simulated_match import default_variance_model, simulate_match
from beams_sim.world import EurobotTrajectory, OdometrySimulator
from beams_tools.serial_feed import with_line_noise

# 8N1: ten line bits per byte.
LINK_FRAMES_PER_S = DEFAULT_BAUDRATE / 10 / FRAME_SIZE
REVOLUTIONS = 300


def _simulated(count: int, seed: int) -> tuple[SensorSimConfig, list[RevolutionEdges], SensorSimulator]:
    """`count` simulated revolutions of a robot standing at (1.0, 0.7), 3 beacons."""
    config = SensorSimConfig()
    simulator = SensorSimulator(config, EUROBOT_BEACON_MAP, np.random.default_rng(seed))
    revolutions = [simulator.revolution(lambda t: (1.0, 0.7, 0.4), k * config.period_s) for k in range(count)]
    return config, revolutions, simulator


def _stream() -> tuple[bytes, int]:
    """REVOLUTIONS simulated revolutions as the device sends them, and their frame count."""
    data = FrameEncoder().revolutions(_simulated(REVOLUTIONS, seed=0)[1])
    return data, len(data) // FRAME_SIZE


def _bearings(config: SensorSimConfig, revolutions: list[RevolutionEdges]) -> dict[tuple[float, int], float]:
    """{(revolution start to 0.1 ms, beacon): bearing}, decoded in order."""
    decoder = BearingDecoder(config.codes, VarianceModel(config.codes))
    return {
        (round(r.start_time_s, 4), b.beacon_id): b.bearing
        for r in revolutions
        for b in decoder.decode(r).bearings
    }


def _assemble(data: bytes, assembler: RevolutionAssembler | None = None) -> list[RevolutionEdges]:
    parser, assembler = FrameParser(), assembler or RevolutionAssembler()
    revolutions: list[RevolutionEdges] = []
    for offset in range(0, len(data), 4096):
        revolutions += assembler.feed(parser.feed(data[offset : offset + 4096]))
    return revolutions


def noise_rows(byte_error_rate: float) -> list[Row]:
    """Random byte substitutions at byte_error_rate over REVOLUTIONS simulated revolutions: the share of
    the revolutions the noise did not touch (their frames, opening and closing zero references included)
    that are published, and of all revolutions."""
    config, revolutions, _ = _simulated(REVOLUTIONS, seed=2)
    encoder = FrameEncoder()
    chunks = [encoder.revolution(r) for r in revolutions]
    end_ticks = round((revolutions[-1].start_time_s + revolutions[-1].period_s) * TIMER_HZ)
    chunks.append(encoder.event(EventKind.ZERO_REFERENCE, end_ticks))
    zero_offsets, position = [], 0
    for chunk in chunks:
        offset = 0
        while chunk[offset + 2] != EventKind.ZERO_REFERENCE:
            offset += HELLO_SIZE if chunk[offset + 2] == EventKind.HELLO else FRAME_SIZE
        zero_offsets.append(position + offset)
        position += len(chunk)
    data = np.frombuffer(b"".join(chunks), dtype=np.uint8).copy()
    rng = np.random.default_rng(3)
    hit = rng.random(len(data)) < byte_error_rate
    hit[:HELLO_SIZE] = False  # the boot hello: the host would wait 0.25 s for the next one
    data[hit] = rng.integers(0, 256, int(hit.sum()))
    clean = {
        round(revolutions[k].start_time_s, 4)
        for k in range(REVOLUTIONS)
        if not hit[zero_offsets[k] : zero_offsets[k + 1] + FRAME_SIZE].any()
    }
    whole = _assemble(data.tobytes())
    published = {round(r.start_time_s, 4) for r in whole}
    clean_bearings = _bearings(config, _assemble(b"".join(chunks)))
    by_window = _bearings(config, _assemble(data.tobytes(), RevolutionAssembler(lost_frames_cost="window")))
    wrong = sum(by_window[key] != clean_bearings.get(key) for key in by_window)
    percent = f"{100 * byte_error_rate:g} %"
    return [
        (
            f"clean revolutions published, {percent} of the bytes replaced",
            100.0 * len(clean & published) / len(clean) if clean else float("nan"),
            "%",
            f"{len(clean)} of {REVOLUTIONS} untouched by the noise (nan: none); goal 100 %",
        ),
        (
            f"all revolutions published, {percent} of the bytes replaced",
            100.0 * len(published) / REVOLUTIONS,
            "%",
            "a touched revolution is dropped whole (edges may be missing)",
        ),
        (
            f"bearings kept, {percent} of the bytes replaced, lost_frames_cost window",
            100.0 * len(by_window) / len(clean_bearings),
            "%",
            f"revolution: {100.0 * len(_bearings(config, whole)) / len(clean_bearings):.0f} %; "
            f"{wrong} differ from the clean stream's (goal 0)",
        ),
    ]


def inserted_noise_rows(bytes_per_revolution: int = 5) -> list[Row]:
    """The line-noise fault (the fault campaign's): random bytes inserted at random places of
    every revolution's frames; the share of the clean stream's bearings kept with each lost_frames_cost,
    and how many of them differ from the clean stream's."""
    config, revolutions, _ = _simulated(REVOLUTIONS, seed=5)
    encoder, rng = FrameEncoder(), np.random.default_rng(6)
    data = b"".join(with_line_noise(encoder.revolution(r), bytes_per_revolution, rng) for r in revolutions)
    clean = _bearings(config, _assemble(FrameEncoder().revolutions(revolutions)))
    kept = {
        cost: _bearings(config, _assemble(data, RevolutionAssembler(lost_frames_cost=cost)))
        for cost in ("revolution", "window")
    }
    wrong = sum(kept["window"][key] != clean.get(key) for key in kept["window"])
    return [
        (
            f"bearings kept, {bytes_per_revolution} random bytes inserted per revolution, cost window",
            100.0 * len(kept["window"]) / len(clean),
            "%",
            f"cost revolution: {100.0 * len(kept['revolution']) / len(clean):.0f} %; {wrong} differ from the "
            f"clean stream's (goal 0)",
        )
    ]


def spurious_zero_rows() -> list[Row]:
    """A spurious zero reference 1.2 ms before every real one. The worst error of the
    published bearings against the simulator's truth, in their own published standard deviations, with
    the measured turret speed and with the nominal +-2 % alone (a tolerance of 2 % of a turn)."""
    config, revolutions, simulator = _simulated(REVOLUTIONS, seed=4)
    captures = []
    for r in revolutions:
        captures.append((EventKind.ZERO_REFERENCE, round(r.start_time_s * TIMER_HZ)))
        if r.revolution:
            captures.append((EventKind.ZERO_REFERENCE, round((r.start_time_s - 0.0012) * TIMER_HZ)))
        for time_s, rising in zip(r.edge_times_s, r.edge_rising, strict=True):
            captures.append((EventKind.RISING if rising else EventKind.FALLING, round(time_s * TIMER_HZ)))
    end_ticks = round((revolutions[-1].start_time_s + config.period_s) * TIMER_HZ)
    captures.append((EventKind.ZERO_REFERENCE, end_ticks))
    encoder = FrameEncoder()
    data = b"".join(encoder.event(kind, ticks) for kind, ticks in sorted(captures, key=lambda c: c[1]))
    pose = (1.0, 0.7, 0.4)
    truth = {beacon: simulator.true_bearing(beacon, pose)[0] for beacon in (1, 2, 3)}

    def worst(assembler: RevolutionAssembler, stream: bytes = data) -> tuple[float, float, int]:
        decoder = BearingDecoder(
            config.codes, default_variance_model(config.codes, config), receiver=config.receiver
        )
        errors, sigmas, published = [], [], 0
        for revolution in _assemble(stream, assembler):
            published += 1
            for bearing in decoder.decode(revolution).bearings:
                error = (bearing.bearing - truth[bearing.beacon_id] + np.pi) % (2 * np.pi) - np.pi
                errors.append(abs(error))
                sigmas.append(np.sqrt(bearing.variance))
        ratio = np.array(errors) / np.array(sigmas)
        return float(np.max(ratio)), float(np.max(errors)), published

    clean_sigmas, clean_rad, _ = worst(RevolutionAssembler(), FrameEncoder().revolutions(revolutions))
    measured_sigmas, measured_rad, measured_count = worst(RevolutionAssembler())
    nominal_sigmas, nominal_rad, nominal_count = worst(
        RevolutionAssembler(min_tolerance_s=0.02 * config.period_s)
    )
    return [
        (
            "spurious zero ref 1.2 ms early: worst published bearing error",
            measured_sigmas,
            "sigma",
            f"{1e3 * measured_rad:.2f} mrad, {measured_count}/{REVOLUTIONS} revolutions published; clean "
            f"stream: {clean_sigmas:.2f} sigma ({1e3 * clean_rad:.2f} mrad); "
            f"nominal +-2 % alone: {nominal_sigmas:.0f} sigma ({1e3 * nominal_rad:.0f} mrad, "
            f"{nominal_count} published)",
        )
    ]


def rows() -> list[Row]:
    data, frames = _stream()
    frames_per_revolution = frames / REVOLUTIONS

    def parse_in_chunks() -> None:
        parser = FrameParser()
        for offset in range(0, len(data), 4096):
            parser.feed(data[offset : offset + 4096])

    parse_s = best_per_call_s(parse_in_chunks, 1, 3)
    events = FrameParser().feed(data)
    assemble_s = best_per_call_s(lambda: RevolutionAssembler().feed(events), 1, 3)
    encode_s = best_per_call_s(_stream, 1, 3)  # simulation included: an upper bound on the encoder's cost

    trajectory_s = best_per_call_s(lambda: EurobotTrajectory.random(seed=0), 1, 3)
    trajectory = EurobotTrajectory.random(seed=0)
    instants = np.random.default_rng(1).uniform(0.0, 90.0, 20000).tolist()
    pose_s = best_per_call_s(lambda: [trajectory.pose_at(t) for t in instants], 1, 3) / len(instants)
    odometry_s = best_per_call_s(lambda: OdometrySimulator(trajectory).run(50.0), 1, 3)
    match_s = best_per_call_s(lambda: simulate_match(90.0, seed=0), 1, 1)

    parser_rate = frames / parse_s
    return [
        (
            "serial frames per revolution (3 beacons in sight, simulated)",
            frames_per_revolution,
            "frames",
            f"link capacity {LINK_FRAMES_PER_S / 10.016:.0f} per revolution at {DEFAULT_BAUDRATE} baud",
        ),
        (
            "frame parser throughput",
            parser_rate,
            "frames/s",
            f"{parser_rate / LINK_FRAMES_PER_S:.0f}x a saturated {DEFAULT_BAUDRATE} baud link",
        ),
        (
            "frame parser throughput",
            len(data) / parse_s / 1e6,
            "MB/s",
            f"link: {DEFAULT_BAUDRATE / 10 / 1e6:.3f} MB/s",
        ),
        ("revolution assembly", assemble_s / REVOLUTIONS * 1e3, "ms/revolution", "period 99.84 ms"),
        (
            "simulate + encode one revolution",
            encode_s / REVOLUTIONS * 1e3,
            "ms/revolution",
            "period 99.84 ms",
        ),
        ("random 90 s trajectory construction", trajectory_s * 1e3, "ms", "once per match"),
        ("trajectory pose_at (scalar)", pose_s * 1e6, "us/call", "a few per beacon window (sensor_sim)"),
        ("odometry of a 90 s match at 50 Hz", odometry_s * 1e3, "ms", "4500 samples"),
        (
            "simulate_match, 90 s (trajectory, sensor, decoder, odometry)",
            match_s,
            "s",
            f"{90.0 / match_s:.0f}x real time",
        ),
        *noise_rows(0.001),
        *noise_rows(0.01),
        *inserted_noise_rows(),
        *spurious_zero_rows(),
    ]


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
