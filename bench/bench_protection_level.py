"""Protection levels against the truth (docs/protection_level.md): the EKF on simulated matches of the thesis
hardware as ekf_node runs with its defaults (`beams_thesis.replay`: its intakes, its protection level and its
status at every estimate), perfectly calibrated and uncalibrated but self-calibrating, each over the same
seeds; then two faults from FAULT_START_S: one beacon's bearings biased 0.5 deg for 10 s, one beacon moved
3 cm (the map not told). Misleading: an error beyond its protection level while the status is tracking (the
status is degraded while a level exceeds its alert limit). Time to alert: the fault's onset to the first
estimate that is not tracking. `--plot-directory`: a Stanford plot (error against protection level) per
scenario."""

import math
import pathlib
import sys
from dataclasses import replace

import numpy as np
from bench_self_calibration import default_driver_matches, run
from rows_table import Row, bench_main

from beams_common.geometry.angles import wrap_to_pi
from beams_ekf.power_bias_states import PowerBiasStates
from beams_sim.simulated_match import SimulatedMatch
from beams_thesis.replay import ReplayResult

DEFAULT_SEEDS = 10
DEFAULT_DURATION_S = 180.0
SETTLE_S = 1.0
FAULT_START_S = 60.0
FAULTY_BEACON = 2
BIAS_RAD, BIAS_S = math.radians(0.5), 10.0
MOVE_M = (0.03, 0.0)


def biased(match: SimulatedMatch) -> SimulatedMatch:
    """FAULTY_BEACON's bearings BIAS_RAD off from FAULT_START_S for BIAS_S (a reflection, a bent mount)."""
    return _faulty(match, lambda b: BIAS_RAD if FAULT_START_S <= b.stamp_s < FAULT_START_S + BIAS_S else 0.0)


def moved(match: SimulatedMatch) -> SimulatedMatch:
    """FAULTY_BEACON moved by MOVE_M at FAULT_START_S, its bearings seen from the true turret pose."""
    x, y = np.asarray(match.beacon_map.as_dict()[FAULTY_BEACON])

    def shift(b) -> float:
        if b.stamp_s < FAULT_START_S:
            return 0.0
        tx, ty, _ = match.turret_at(b.stamp_s)
        now = math.atan2(y + MOVE_M[1] - ty, x + MOVE_M[0] - tx)
        return float(wrap_to_pi(now - math.atan2(y - ty, x - tx)))

    return _faulty(match, shift)


def _faulty(match: SimulatedMatch, offset_rad) -> SimulatedMatch:
    revolutions = [
        replace(
            r,
            bearings=[
                replace(b, bearing=float(wrap_to_pi(b.bearing + offset_rad(b))))
                if b.beacon_id == FAULTY_BEACON
                else b
                for b in r.bearings
            ],
        )
        for r in match.revolutions
    ]
    return replace(match, revolutions=revolutions)


# (scenario, calibrated, fault)
SCENARIOS = (
    ("perfectly calibrated", True, None),
    ("uncalibrated, self-calibrating", False, None),
    ("0.5 deg bias on one beacon for 10 s", True, biased),
    ("one beacon moved 3 cm", True, moved),
)


def judged(result: ReplayResult) -> dict[str, np.ndarray]:
    """Per estimate after SETTLE_S: errors, levels, whether tracking, whether misleading."""
    keep = result.times_s >= result.times_s[0] + SETTLE_S
    errors = result.errors()[keep]
    horizontal, heading = np.hypot(errors[:, 0], errors[:, 1]), np.abs(errors[:, 2])
    levels, tracking = result.protection_levels[keep], result.tracking[keep]
    exceeded = (horizontal > levels[:, 0]) | (heading > levels[:, 1])
    return {
        "t": result.times_s[keep],
        "error": horizontal,
        "level": levels[:, 0],
        "heading_level": levels[:, 1],
        "exceeded": exceeded,
        "tracking": tracking,
        "misleading": exceeded & tracking,
    }


def time_to_alert_s(series: dict[str, np.ndarray]) -> float:
    """From FAULT_START_S to the first estimate not tracking (inf: none)."""
    alerted = series["t"][(series["t"] >= FAULT_START_S) & ~series["tracking"]]
    return float(alerted[0] - FAULT_START_S) if alerted.size else math.inf


def stanford_plot(name: str, series: dict[str, np.ndarray], path: pathlib.Path) -> None:
    """Error against horizontal protection level (log-log), the line where they are equal; above it the
    bound failed; misleading points (tracking) red."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(5.5, 5))
    level_mm, error_mm = 1e3 * series["level"], np.maximum(1e3 * series["error"], 1e-3)
    axes.hist2d(level_mm, error_mm, bins=[np.geomspace(0.5, 500, 80), np.geomspace(1e-3, 500, 80)], cmin=1)
    axes.plot([1e-3, 500], [1e-3, 500], "k-", lw=1)
    misleading = series["misleading"]
    axes.plot(level_mm[misleading], error_mm[misleading], "r.", ms=3)
    axes.set(xscale="log", yscale="log", xlabel="horizontal protection level (mm)", ylabel="error (mm)")
    axes.set_title(f"{name}: {int(misleading.sum())} misleading of {misleading.size}", fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    plt.close(figure)


def rows(
    seeds: int = DEFAULT_SEEDS,
    duration_s: float = DEFAULT_DURATION_S,
    plot_directory: pathlib.Path | None = None,
) -> list[Row]:
    pooled: dict[str, list[dict[str, np.ndarray]]] = {name: [] for name, *_ in SCENARIOS}
    for seed in range(seeds):
        matches = default_driver_matches(duration_s, seed)
        for name, calibrated, fault in SCENARIOS:
            match = fault(matches[calibrated]) if fault else matches[calibrated]
            result, _ = run(match, PowerBiasStates(), calibrated)
            pooled[name].append(judged(result))
        print(f"seed {seed} done", file=sys.stderr)
    label, table = f"{seeds} seeds x {duration_s:.0f} s", []
    for name, _, fault in SCENARIOS:
        runs = pooled[name]
        series = {key: np.concatenate([r[key] for r in runs]) for key in runs[0]}
        table += [
            (f"{name}: misleading estimates ({label})", int(series["misleading"].sum()), "count", "0"),
            (
                f"{name}: estimates beyond their protection level",
                float(series["exceeded"].mean()),
                "fraction",
                f"{int(series['exceeded'].sum())} of {series['exceeded'].size}; integrity risk 1e-05",
            ),
            (f"{name}: available (tracking)", 100 * float(series["tracking"].mean()), "%", "-"),
        ]
        if fault is None:
            table += [
                (f"{name}: horizontal protection level p50", 1e3 * np.median(series["level"]), "mm", "-"),
                (
                    f"{name}: horizontal protection level p99",
                    1e3 * np.quantile(series["level"], 0.99),
                    "mm",
                    "50",
                ),
                (
                    f"{name}: heading protection level p99",
                    math.degrees(np.quantile(series["heading_level"], 0.99)),
                    "deg",
                    "3",
                ),
            ]
        else:
            alerts = np.array([time_to_alert_s(r) for r in runs])
            finite = alerts[np.isfinite(alerts)]
            table.append(
                (
                    f"{name}: time to alert p50 / p99 (s)",
                    float(np.median(finite)) if finite.size else math.inf,
                    "s",
                    f"p99 {np.quantile(finite, 0.99) if finite.size else math.inf:.2f} s; {finite.size} of "
                    f"{alerts.size} seeds alerted; goal p99 <= 0.1 s",
                )
            )
        if plot_directory is not None:
            slug = "".join(c if c.isalnum() else "_" for c in name).strip("_")
            stanford_plot(name, series, plot_directory / f"stanford_{slug}.png")
    return table


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
