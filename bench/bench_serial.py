"""Serial link and simulated world benchmark (issue 3): parser and assembler throughput against what the
serial link can carry, and the cost of the simulated robot and of a whole offline match.

Usage: python bench/bench_serial.py   (`rows()` is what bench/run_all.py collects.)
"""

import sys
import time
from collections.abc import Callable

import numpy as np

from beams_common.beacon_map import EUROBOT_BEACON_MAP
from beams_driver.sensor_sim import SensorSimConfig, SensorSimulator
from beams_driver.serial_protocol import (
    DEFAULT_BAUDRATE,
    FRAME_SIZE,
    FrameEncoder,
    FrameParser,
    RevolutionAssembler,
)
from beams_sim.simulated_match import simulate_match
from beams_sim.world import EurobotTrajectory, OdometrySimulator

# 8N1: ten line bits per byte.
LINK_FRAMES_PER_S = DEFAULT_BAUDRATE / 10 / FRAME_SIZE
REVOLUTIONS = 300


def _best_of(repeats: int, function: Callable[[], object]) -> float:
    """Shortest wall time of several runs (s): the least disturbed by the other processes."""
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - started)
    return best


def _stream() -> tuple[bytes, int]:
    """REVOLUTIONS simulated revolutions (robot at (1.0, 0.7), 3 beacons) as the device sends them."""
    config = SensorSimConfig()
    simulator = SensorSimulator(config, EUROBOT_BEACON_MAP, np.random.default_rng(0))
    pose = (1.0, 0.7, 0.4)
    revolutions = [simulator.revolution(lambda t: pose, k * config.period_s) for k in range(REVOLUTIONS)]
    data = FrameEncoder().revolutions(revolutions)
    return data, len(data) // FRAME_SIZE


def rows() -> list[tuple[str, float, str, str]]:
    data, frames = _stream()
    frames_per_revolution = frames / REVOLUTIONS

    def parse_in_chunks() -> None:
        parser = FrameParser()
        for offset in range(0, len(data), 4096):
            parser.feed(data[offset : offset + 4096])

    parse_s = _best_of(3, parse_in_chunks)
    events = FrameParser().feed(data)
    assemble_s = _best_of(3, lambda: RevolutionAssembler().feed(events))
    encode_s = _best_of(3, _stream)  # simulation included: an upper bound on the encoder's cost

    trajectory_s = _best_of(3, lambda: EurobotTrajectory.random(seed=0))
    trajectory = EurobotTrajectory.random(seed=0)
    instants = np.random.default_rng(1).uniform(0.0, 90.0, 20000).tolist()
    pose_s = _best_of(3, lambda: [trajectory.pose_at(t) for t in instants]) / len(instants)
    odometry_s = _best_of(3, lambda: OdometrySimulator(trajectory).run(50.0))
    match_s = _best_of(1, lambda: simulate_match(90.0, seed=0))

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
    ]


def main() -> int:
    table = rows()
    width = max(len(figure) for figure, *_ in table)
    print(f"{'figure':<{width}} | {'value':>10} | unit          | compared with")
    for figure, value, unit, compared in table:
        print(f"{figure:<{width}} | {value:>10.4g} | {unit:<13} | {compared}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
