"""Self-calibration of the power bias while driving (issue 19): the EKF on simulated matches of the thesis
hardware as the nodes run with their own defaults, uncalibrated or perfectly calibrated.

Runs, each over the same seeds (trajectory, sensor and odometry noise):
- "uncalibrated, bias as white noise": ekf_node's defaults with power_bias_states 'off' (the filter before
  issue 19);
- "uncalibrated, bias considered": power_bias_states 'consider' (Schmidt-Kalman: the bias's prior carried
  in the covariance, never estimated);
- "uncalibrated, self-calibrating": ekf_node's defaults (power_bias_states 'estimate'), its figures over
  the windows [1, 30), [30, 60), [60, 120), [120, 180) s of the match (after 30, 60, 120 s of
  self-calibration);
- "perfectly calibrated": the bearings corrected by the simulated bias inverted (beams_sim's
  calibration_of) and flagged calibrated, the filter's defaults (its bias states then unused).

The driver's variances are its defaults' (driver_node's parameter table: the thesis hardware's natural
variance, linear in the window). The PCRB ("bound") is bench_ekf_consistency's, from the simulator's true
noise models with the odometry's systematic errors unknown and the bias known (a calibrated sensor): the
ratio RMS / bound says what is left to gain. The self-calibrated curve's error is the RMS over the table's
windows of (estimated - true bias). Each mean NEES comes with its range over the seeds (one seed's
mean over the period).

Usage: python bench/bench_self_calibration.py [--seeds N] [--duration S]
"""

import argparse
import math
import sys
import time
from dataclasses import dataclass, replace

import numpy as np
from bench_ekf_consistency import START_SIGMA, match_bound

from beams_driver.parameters import SENSOR_PARAMETERS, variance_model_of
from beams_ekf.localiser import FilterSettings, Localiser, build_localiser
from beams_ekf.power_bias_states import PowerBiasStates
from beams_sim.simulated_match import SimulatedMatch, calibration_of, sensor_config_of, simulate_match
from beams_thesis.match_replay import match_fixes, replay_match
from beams_thesis.replay import ReplayResult

DEFAULT_SEEDS = 10
DEFAULT_DURATION_S = 180.0
SETTLE_S = 1.0
# the figures of each period: from the start, after 30 s, 60 s and 120 s of self-calibration
PERIODS_S = ((SETTLE_S, 30.0), (30.0, 60.0), (60.0, 120.0), (120.0, 180.0))
SENSOR_MODEL = "thesis_hardware"


def default_driver_match(duration_s: float, seed: int, calibrated: bool) -> SimulatedMatch:
    """A match of the thesis hardware as driver_node publishes it with its defaults: its variance model,
    and, `calibrated`, the bearings corrected by a perfect chapter-7 calibration."""
    config = sensor_config_of(SENSOR_MODEL)
    model = variance_model_of(SENSOR_PARAMETERS.defaults(), config.codes, config)
    match = simulate_match(duration_s, seed, sensor_config=config, variance_model=model)
    return match.corrected(calibration_of(config)) if calibrated else match


def filter_of(match: SimulatedMatch, power_bias: PowerBiasStates | None) -> Localiser:
    beacons = dict(zip(match.beacon_map.ids, map(tuple, match.beacon_map.xy), strict=True))
    return build_localiser(beacons, match.turret_offset_m, replace(FilterSettings(), power_bias=power_bias))


def run(
    match: SimulatedMatch, power_bias: PowerBiasStates | None, calibrated: bool
) -> tuple[ReplayResult, Localiser]:
    """The replay of a match from ToTal's first fix (bench_ekf_consistency's start), and its localiser."""
    x, y, theta = match.initial_pose
    start = (x + START_SIGMA[0], y - START_SIGMA[1], theta + START_SIGMA[2])
    localiser = filter_of(match, power_bias)
    result = replay_match(
        localiser, match, start, np.diag(np.square(START_SIGMA)), match_fixes(match), calibrated=calibrated
    )
    return result, localiser


def nees(result: ReplayResult) -> np.ndarray:
    errors = result.errors()
    return np.einsum("ki,kij,kj->k", errors, np.linalg.inv(result.covariances), errors)


def bias_curve_error_rad(localiser: Localiser, match: SimulatedMatch) -> float:
    """RMS over the windows the table gives (0.2 m to 3.7 m from a beacon) of the estimated power bias
    minus the simulated one, both less their mean (a constant bias is the heading's)."""
    config = sensor_config_of(SENSOR_MODEL)
    states = localiser.ekf.power_bias
    coefficients, _ = localiser.ekf.power_bias_estimate
    windows = config.window_rad(np.linspace(0.2, 3.7, 200))
    estimated = np.array([states.bias_rad(coefficients, w) for w in windows])
    true = config.hardware.power_bias_rad(windows)
    difference = (estimated - estimated.mean()) - (true - true.mean())
    return float(np.sqrt(np.mean(difference**2)))


@dataclass
class Pool:
    """Errors, NEES and bounds of one run kind over the seeds, per period of the match."""

    errors: dict[tuple[float, float], list[np.ndarray]]
    nees: dict[tuple[float, float], list[np.ndarray]]
    bounds: dict[tuple[float, float], list[np.ndarray]]

    @classmethod
    def empty(cls) -> "Pool":
        return cls(*({p: [] for p in PERIODS_S} for _ in range(3)))

    def add(self, result: ReplayResult, bound) -> None:
        t = result.times_s - result.times_s[0]
        values = nees(result)
        for period in PERIODS_S:
            keep = (t >= period[0]) & (t < period[1])
            if keep.any():
                self.errors[period].append(result.errors()[keep])
                self.nees[period].append(values[keep])
                self.bounds[period].append(bound.at(result.times_s[keep]))

    def figures(self, period: tuple[float, float]) -> dict[str, float] | None:
        if not self.errors[period]:
            return None
        errors, values = np.concatenate(self.errors[period]), np.concatenate(self.nees[period])
        bound = np.concatenate(self.bounds[period])
        rms = float(np.sqrt(np.mean(errors[:, 0] ** 2 + errors[:, 1] ** 2)))
        per_seed = [float(v.mean()) for v in self.nees[period]]
        return {
            "rms_m": rms,
            "nees": float(values.mean()),
            "nees_seed_min": min(per_seed),
            "nees_seed_max": max(per_seed),
            "bound_m": float(np.sqrt(np.mean(bound[:, 0, 0] + bound[:, 1, 1]))),
        }


RUNS = (
    ("uncalibrated, bias as white noise", False, None),
    ("uncalibrated, bias considered", False, PowerBiasStates(estimate=False)),
    ("uncalibrated, self-calibrating", False, PowerBiasStates()),
    ("perfectly calibrated", True, PowerBiasStates()),
)


def rows(
    seeds: int = DEFAULT_SEEDS, duration_s: float = DEFAULT_DURATION_S
) -> list[tuple[str, float, str, str]]:
    config = sensor_config_of(SENSOR_MODEL)
    pools = {name: Pool.empty() for name, _, _ in RUNS}
    curve_errors: list[float] = []
    for seed in range(seeds):
        matches = {c: default_driver_match(duration_s, seed, c) for c in (False, True)}
        bound = match_bound(matches[True], config, True)
        for name, calibrated, states in RUNS:
            result, localiser = run(matches[calibrated], states, calibrated)
            pools[name].add(result, bound)
            if name == "uncalibrated, self-calibrating":
                curve_errors.append(bias_curve_error_rad(localiser, matches[False]))
    label = f"{seeds} seeds"
    calibrated_rms = {p: (pools["perfectly calibrated"].figures(p) or {}).get("rms_m") for p in PERIODS_S}
    table = []
    for name, _, _ in RUNS:
        for period in PERIODS_S:
            f = pools[name].figures(period)
            if f is None:
                continue
            when = f"{period[0]:.0f}-{period[1]:.0f} s"
            table += [
                (
                    f"{name}: EKF mean NEES, {when}, {label}",
                    f["nees"],
                    "",
                    f"per seed {f['nees_seed_min']:.2f}-{f['nees_seed_max']:.2f}; "
                    "target 2.0-4.5 (3 consistent)",
                ),
                (
                    f"{name}: EKF RMS position, {when}",
                    1000 * f["rms_m"],
                    "mm",
                    f"PCRB {1000 * f['bound_m']:.3g} mm (ratio {f['rms_m'] / f['bound_m']:.2f}); perfectly "
                    f"calibrated {1000 * calibrated_rms[period]:.3g} mm "
                    f"(ratio {f['rms_m'] / calibrated_rms[period]:.2f}, goal <= 1.3 after 60 s)",
                ),
            ]
    table.append(
        (
            f"self-calibrated power-bias curve error at {duration_s:.0f} s (RMS over the table's windows, "
            "constant removed), mean over seeds",
            math.degrees(float(np.mean(curve_errors))),
            "deg",
            "the bias spans 0.23 deg (thesis 5.7)",
        )
    )
    return table


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=DEFAULT_SEEDS)
    parser.add_argument("--duration", type=float, default=DEFAULT_DURATION_S)
    options = parser.parse_args()
    started = time.monotonic()
    print("| figure | value | unit | compared with |\n|---|---|---|---|")
    for figure, value, unit, compared in rows(options.seeds, options.duration):
        print(f"| {figure} | {value:.4g} | {unit} | {compared} |")
    print(f"({time.monotonic() - started:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
