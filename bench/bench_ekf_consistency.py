"""EKF consistency and optimality over seeds of the simulated match: NEES, the posterior Cramer-Rao bound
(PCRB: the wheels' true noise, each bearing's true variance, the odometry's systematic errors "unknown" with
the filter's prior or "known"), the odometry error states (two beacons hidden for 10 s) and the lost
detection, for the filters of `FILTERS` with ToTal's fixes, on both sensor models' calibrated matches
(beams_sim.simulated_match.calibrated_match)."""

import itertools
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from rows_table import Row, bench_main

from beams_common.geometry.pose2d import between
from beams_ekf.bearing_ekf import BearingEkf
from beams_ekf.localiser import FilterSettings, Localiser, build_localiser
from beams_ekf.odometry_errors import OdometryErrorStates
from beams_sim.sensor_sim import SensorSimConfig
from beams_sim.simulated_match import (
    SENSOR_MODELS,
    SimulatedMatch,
    calibrated_match,
    default_variance_model,
    sensor_config_of,
)
from beams_sim.world import OdometryDrift
from beams_thesis.match_replay import START_SIGMA, match_fixes, match_odometry, offset_start, replay_match
from beams_thesis.pcrb import PcrbTrack, WheelNoiseModel, trajectory_pcrb
from beams_thesis.replay import NEES_BAND, PoseEvent, ReplayResult

DEFAULT_SEEDS = 10
DEFAULT_DURATION_S = 90.0
SETTLE_S = 1.0  # the initial transient left out, as bench_ekf's accuracy() does
OCCLUSION_START_S, OCCLUSION_S, HIDDEN_BEACONS = 30.0, 10.0, (1, 2)
LOST_OFFSET_M, LOST_DIRECTIONS, LOST_MATCH_S = 0.05, 8, 6.0


@dataclass(frozen=True)
class Filter:
    """A filter configuration under test."""

    name: str
    build: Callable[[SimulatedMatch], Localiser]


FILTERS = (
    # BearingEkf's own ProcessNoise defaults; then ekf_node's (FilterSettings: systematic errors as states)
    Filter(
        "white odometry noise", lambda m: Localiser(BearingEkf(m.beacon_map.as_dict(), m.turret_offset_m))
    ),
    Filter(
        "error states", lambda m: build_localiser(m.beacon_map.as_dict(), m.turret_offset_m, FilterSettings())
    ),
    # the diagnosis: the wheels' random noise alone, without the states, cannot explain the drift
    Filter(
        "wheel noise, no error states",
        lambda m: build_localiser(
            m.beacon_map.as_dict(), m.turret_offset_m, FilterSettings(odometry_errors=None)
        ),
    ),
)


def true_bearing_variances(match: SimulatedMatch, config: SensorSimConfig) -> list[tuple[float, int, float]]:
    """(stamp, beacon id, true variance) of every decoded bearing: the simulator's exact variance
    plus natural variance at the true window (beam geometry at the true distance), not the decoded one;
    the thesis hardware's natural variance is its edge noise at that window."""
    model = default_variance_model(config.codes, config, 0.0)
    beacons = {b.beacon_id: b for b in match.true_beacons}
    result = []
    for revolution in match.revolutions:
        for b in revolution.bearings:
            turret = match.turret_at(b.stamp_s)
            beacon = beacons[b.beacon_id]
            window = config.window_rad(
                math.hypot(beacon.x_m - turret[0], beacon.y_m - turret[1]), beacon.power_scale
            )
            natural = (
                config.natural_variance_rad2
                if config.hardware is None
                else float(config.hardware.natural_variance_rad2(window, config.code(b.beacon_id)))
            )
            result.append((b.stamp_s, b.beacon_id, float(model.variance(b.beacon_id, window)) + natural))
    return result


def match_bound(match: SimulatedMatch, config: SensorSimConfig, errors_unknown: bool) -> PcrbTrack:
    """The PCRB of a match from the simulator's true noise models (see the module docstring)."""
    drift = OdometryDrift()
    odometry = match_odometry(match)
    truth = match.ground_truth
    increments = np.array([between(tuple(a), tuple(b)) for a, b in itertools.pairwise(odometry)])
    return trajectory_pcrb(
        truth.stamp_s,
        np.column_stack([truth.x_m, truth.y_m, truth.theta_rad]),
        increments,
        true_bearing_variances(match, config),
        match.beacon_map.as_dict(),
        match.truth_at,
        match.turret_offset_m,
        np.diag(np.square(START_SIGMA)),
        WheelNoiseModel(drift.noise_m_per_sqrt_m, drift.slip_std),
        OdometryErrorStates() if errors_unknown else None,
    )


def run(filter_: Filter, match: SimulatedMatch, fixes: list[PoseEvent], start=None) -> ReplayResult:
    pose, covariance = start or offset_start(match)
    return replay_match(filter_.build(match), match, pose, covariance, fixes)


@dataclass
class Pooled:
    """Errors, NEES and bounds of one filter pooled over the seeds (after SETTLE_S)."""

    errors: list[np.ndarray]
    nees: list[np.ndarray]
    bound_unknown: list[np.ndarray]
    bound_known: list[np.ndarray]
    lost_detections: int = 0

    def add(self, result: ReplayResult, unknown: PcrbTrack, known: PcrbTrack) -> None:
        keep = result.times_s >= result.times_s[0] + SETTLE_S
        self.errors.append(result.errors()[keep])
        self.nees.append(result.nees()[keep])
        self.bound_unknown.append(unknown.at(result.times_s[keep]))
        self.bound_known.append(known.at(result.times_s[keep]))
        self.lost_detections += result.counts.get("lost_detections", 0)

    def figures(self) -> dict[str, float]:
        errors, nees = np.concatenate(self.errors), np.concatenate(self.nees)
        figures = {
            "rms_position_m": float(np.sqrt(np.mean(errors[:, 0] ** 2 + errors[:, 1] ** 2))),
            "rms_heading_rad": float(np.sqrt(np.mean(errors[:, 2] ** 2))),
            "nees_mean": float(nees.mean()),
            "nees_in_band": float(np.mean((nees >= NEES_BAND[0]) & (nees <= NEES_BAND[1]))),
        }
        for name, bounds in (("unknown", self.bound_unknown), ("known", self.bound_known)):
            b = np.concatenate(bounds)
            figures[f"bound_{name}_position_m"] = float(np.sqrt(np.mean(b[:, 0, 0] + b[:, 1, 1])))
            figures[f"bound_{name}_heading_rad"] = float(np.sqrt(np.mean(b[:, 2, 2])))
        return figures


def hidden(beacon_id: int, time_s: float) -> bool:
    """Two beacons hidden for OCCLUSION_S from OCCLUSION_START_S."""
    return beacon_id in HIDDEN_BEACONS and OCCLUSION_START_S <= time_s < OCCLUSION_START_S + OCCLUSION_S


def occlusion_growth(result: ReplayResult) -> tuple[float, float]:
    """(largest position error during the occlusion, mean NEES during it)."""
    inside = (result.times_s >= OCCLUSION_START_S) & (result.times_s < OCCLUSION_START_S + OCCLUSION_S + 0.2)
    errors = result.errors()[inside]
    return float(np.hypot(errors[:, 0], errors[:, 1]).max()), float(result.nees()[inside].mean())


def lost_recovery_s(seeds: range, sensor_model: str) -> tuple[float, int]:
    """Worst time (s) until the position error stays under 1 cm from starts LOST_OFFSET_M off in
    LOST_DIRECTIONS directions with a 1 mm covariance (confidently wrong), and how many never recovered."""
    worst, failed = 0.0, 0
    for seed in seeds:
        match = calibrated_match(sensor_model, LOST_MATCH_S, seed)
        fixes = match_fixes(match)
        x, y, theta = match.initial_pose
        for angle in np.linspace(0.0, 2.0 * math.pi, LOST_DIRECTIONS, endpoint=False):
            start = (
                (x + LOST_OFFSET_M * math.cos(angle), y + LOST_OFFSET_M * math.sin(angle), theta),
                np.diag([1e-6, 1e-6, 1e-6]),
            )
            result = run(FILTERS[1], match, fixes, start)
            off = np.flatnonzero(np.hypot(*result.errors()[:, :2].T) > 0.01)
            if len(off) and off[-1] == len(result.times_s) - 1:
                failed += 1
                continue
            # the first estimate from which the error stays under 1 cm, from the start of the match
            first_good = off[-1] + 1 if len(off) else 0
            worst = max(worst, float(result.times_s[first_good] - match.odometry.stamp_s[0]))
    return worst, failed


def rows(
    seeds: int = DEFAULT_SEEDS,
    duration_s: float = DEFAULT_DURATION_S,
    sensor_models: tuple[str, ...] = SENSOR_MODELS,
) -> list[Row]:
    """(figure, value, unit, compared with) rows of every sensor model, each row named by its model."""
    return [
        (f"{model} sensor: {figure}", value, unit, compared)
        for model in sensor_models
        for figure, value, unit, compared in model_rows(seeds, duration_s, model)
    ]


def model_rows(seeds: int, duration_s: float, sensor_model: str) -> list[Row]:
    """(figure, value, unit, compared with) rows of one sensor model."""
    config = sensor_config_of(sensor_model)
    pooled = {f.name: Pooled([], [], [], []) for f in FILTERS}
    occluded: dict[str, list[tuple[float, float]]] = {f.name: [] for f in FILTERS}
    for seed in range(seeds):
        match = calibrated_match(sensor_model, duration_s, seed)
        fixes = match_fixes(match)
        unknown, known = match_bound(match, config, True), match_bound(match, config, False)
        for filter_ in FILTERS:
            pooled[filter_.name].add(run(filter_, match, fixes), unknown, known)
        if duration_s > OCCLUSION_START_S + OCCLUSION_S:
            hidden_match = calibrated_match(sensor_model, duration_s, seed, occlusion=hidden)
            for filter_ in FILTERS:
                occluded[filter_.name].append(occlusion_growth(run(filter_, hidden_match, [])))
    label = f"{seeds} seeds x {duration_s:.0f} s"
    table = []
    for name, pool in pooled.items():
        f = pool.figures()
        table += [
            (
                f"EKF mean NEES ({name}), {label}",
                f["nees_mean"],
                "",
                "target 2.4-3.6 (3 for a consistent filter)",
            ),
            (f"EKF NEES in 95% band ({name})", 100 * f["nees_in_band"], "%", "target >= 90%"),
            (
                f"EKF RMS position ({name})",
                1000 * f["rms_position_m"],
                "mm",
                f"bound {1000 * f['bound_unknown_position_m']:.3g} mm (errors unknown), "
                f"{1000 * f['bound_known_position_m']:.3g} mm (known)",
            ),
            (
                f"EKF RMS position / PCRB, errors unknown ({name})",
                f["rms_position_m"] / f["bound_unknown_position_m"],
                "",
                "goal <= 1.2",
            ),
            (
                f"EKF RMS heading ({name})",
                math.degrees(f["rms_heading_rad"]),
                "deg",
                f"bound {math.degrees(f['bound_unknown_heading_rad']):.3g} deg (errors unknown), "
                f"{math.degrees(f['bound_known_heading_rad']):.3g} deg (known)",
            ),
            (
                f"EKF RMS heading / PCRB, errors unknown ({name})",
                f["rms_heading_rad"] / f["bound_unknown_heading_rad"],
                "",
                "goal <= 1.2",
            ),
            (f"lost detections over the seeds ({name})", float(pool.lost_detections), "", "target 0"),
        ]
    for name, values in occluded.items():
        if values:
            growth = np.array(values)
            table += [
                (
                    f"beacons {HIDDEN_BEACONS} hidden {OCCLUSION_S:.0f} s: max position error, worst seed "
                    f"({name})",
                    1000 * float(growth[:, 0].max()),
                    "mm",
                    f"median over seeds {1000 * np.median(growth[:, 0]):.3g} mm",
                ),
                (
                    f"beacons {HIDDEN_BEACONS} hidden {OCCLUSION_S:.0f} s: mean NEES while hidden ({name})",
                    float(growth[:, 1].mean()),
                    "",
                    "3 for a consistent filter",
                ),
            ]
    worst_s, failed = lost_recovery_s(range(min(seeds, 3)), sensor_model)
    table += [
        (
            f"recovery from a confident {100 * LOST_OFFSET_M:.0f} cm wrong start, worst of "
            f"{LOST_DIRECTIONS * min(seeds, 3)} (error < 1 cm from then on)",
            worst_s,
            "s",
            f"target <= 2 s; {failed} never recovered",
        ),
    ]
    return table


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
