"""BeAMS sensor model benchmark: decoding plus variance of one revolution with 5 beacons
(target < 1 ms on one core) and the edge-level simulation of one revolution (target < 2 ms); the
thesis-hardware and ideal noise models against table 5.1's experiment column, and the
detection rate against the window with one or two complete codes required (section 2.5.2).
"""

import sys

import numpy as np
from rows_table import Row, bench_main, best_per_call_s

from beams_driver.codes import BeaconCode, code_family
from beams_driver.decoder import BearingDecoder
from beams_driver.variance import VarianceModel
from beams_sim.sensor_sim import (
    SensorSimConfig,
    SensorSimulator,
    SimulatedBeacon,
    fixed_window_bearing_errors,
)
from beams_thesis.receiver_experiment import window_experiment

REVOLUTIONS = 200
# Section 5.2's test codes (None: the unmodulated C_k) and table 5.1's experiment column.
TABLE_5_1 = {
    "C_k": (None, 0.0, 3.93e-3),
    "C_5": ("111110111110", -4.85e-2, 5.49e-3),
    "C_5b": ("11111001111100", -9.53e-2, 1.00e-2),
    "C_5c": ("1111100011111000", -1.56e-1, 1.82e-2),
}
DETECTION_DISTANCES_M = (3.6, 4.5, 5.0, 5.5, 6.0)
# Five beacons around a robot in the middle of a 3 m x 2 m table, all in range, none overlapping.
BEACONS = [
    SimulatedBeacon(1, -0.062, -0.062),
    SimulatedBeacon(2, -0.062, 2.062),
    SimulatedBeacon(3, 3.062, 1.0),
    SimulatedBeacon(4, 3.062, -0.062),
    SimulatedBeacon(5, 1.5, 2.062),
]


def rows() -> list[Row]:
    """(figure, value, unit, compared with) for the table of BENCHMARKS.md."""
    config = SensorSimConfig()
    codes = code_family()

    def pose_at(t: float) -> tuple[float, float, float]:
        return (1.5 + 0.2 * np.sin(t), 1.0, 0.3 + 1.5 * t)

    simulator = SensorSimulator(config, BEACONS, np.random.default_rng(1))
    revolutions = [simulator.revolution(pose_at, k * config.period_s) for k in range(REVOLUTIONS)]
    model = VarianceModel(codes, natural_variance_rad2=config.natural_variance_rad2)
    decoder = BearingDecoder(codes, model)
    decoded = [decoder.decode(r) for r in revolutions]
    bearings = sum(len(d.bearings) for d in decoded) / REVOLUTIONS

    def decode_all() -> None:
        decoder.reset()
        for revolution in revolutions:
            decoder.decode(revolution)

    decode_s = best_per_call_s(decode_all, 1, 5) / REVOLUTIONS
    counter = iter(range(10**9))
    simulate_s = best_per_call_s(
        lambda: simulator.revolution(pose_at, next(counter) * config.period_s), 100, 5
    )
    custom = VarianceModel([BeaconCode.from_string(9, "11111001111100")])
    lookup_s = best_per_call_s(lambda: custom.variance(9, 0.1), 2000, 5)
    closed_s = best_per_call_s(lambda: model.variance(3, 0.1), 2000, 5)
    windows = np.linspace(0.0, 13.0, 131) * codes[0].bit_time_s
    sweep_s = best_per_call_s(lambda: fixed_window_bearing_errors(codes[2], windows, 998401e-7, 3696), 1, 3)
    return [
        (
            "decode + variance, 1 revolution, 5 beacons",
            decode_s * 1e3,
            "ms",
            f"< 1 ms ({bearings:.2f} bearings/rev)",
        ),
        ("decode throughput vs real time", config.period_s / decode_s, "x", ">= 100x (10 Hz turret)"),
        ("simulate 1 revolution, 5 beacons, moving robot", simulate_s * 1e3, "ms", "< 2 ms"),
        ("variance, closed form (family code)", closed_s * 1e6, "us", "per bearing"),
        ("variance, enumeration lookup (custom code)", lookup_s * 1e6, "us", "per bearing"),
        ("section-4.3 sweep: 131 windows x 3696 turns", sweep_s * 1e3, "ms", "figures 4.9-4.13, one code"),
        *table_5_1_rows("thesis_hardware", SensorSimConfig.thesis_hardware()),
        *table_5_1_rows("ideal", SensorSimConfig()),
        *detection_rows(),
    ]


def table_5_1_rows(name: str, config: SensorSimConfig) -> list[Row]:
    """Section 5.3's experiment on the simulated receiver: 100 windows (1-6 m) x 1000 measures per code."""
    rng = np.random.default_rng(0)
    windows = np.linspace(config.window_rad(6.0), config.window_rad(1.0), 100)
    rows, reference = [], None
    for code_name, (bits, bias_deg, variance_deg2) in TABLE_5_1.items():
        code = None if bits is None else BeaconCode.from_string(1, bits)
        rising, falling = window_experiment(config, code, windows, 1000, rng)
        mean_window = np.degrees(np.mean(falling - rising, axis=1))
        reference = mean_window if reference is None else reference
        variance = np.degrees(np.degrees(np.var(0.5 * (rising + falling), axis=1))).max()
        if code is not None:
            bias = float(np.mean(mean_window - reference))
            rows.append(
                (
                    f"{name}: window bias {code_name}",
                    bias * 1e3,
                    "mdeg",
                    f"{bias_deg * 1e3:.1f} (table 5.1 exp.)",
                )
            )
        rows.append(
            (
                f"{name}: max variance {code_name}",
                variance * 1e3,
                "e-3 deg2",
                f"{variance_deg2 * 1e3:.2f} (table 5.1 exp.)",
            )
        )
    return rows


def detection_rows() -> list[Row]:
    """Bearings per revolution of one beacon (codes 1-5 in turn) against its window, thesis_hardware."""
    config = SensorSimConfig.thesis_hardware()
    phi0 = config.codes[0].bit_time_s * config.turret_speed_rad_s
    rows = []
    for distance_m in DETECTION_DISTANCES_M:
        rates = []
        for needed in (1, 2):
            seen = 0
            for code in config.codes:
                simulator = SensorSimulator(
                    config,
                    [SimulatedBeacon(code.code_id, distance_m, 0.0)],
                    np.random.default_rng(code.code_id),
                )
                decoder = BearingDecoder(
                    config.codes, VarianceModel(config.codes), min_codes_seen=needed, receiver=config.receiver
                )
                for k in range(101):
                    decoded = decoder.decode(
                        simulator.revolution(lambda t: (0.0, 0.0, -1.0), k * config.period_s)
                    )
                    seen += len(decoded.bearings) if k else 0
            rates.append(seen / (100 * len(config.codes)))
        bits = float(config.window_rad(distance_m)) / phi0
        rows.append(
            (
                f"detection at {distance_m} m ({bits:.0f} bits), 2 codes",
                rates[1],
                "",
                f"{rates[0]:.2f} with 1 code (min_complete_codes)",
            )
        )
    return rows


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
