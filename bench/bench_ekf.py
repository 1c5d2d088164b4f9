"""EKF benchmark (thesis fig. 8.1): accuracy and consistency on the simulated Eurobot match in the three
bearing-variance modes, odometry alone and ToTal alone, and the cost of a prediction and of a bearing update,
on both sensor models' calibrated matches ("published R": the driver's variance, correction included)."""

import math
import sys
import timeit
from dataclasses import dataclass

import numpy as np
from rows_table import Row, bench_main

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.bearing import Bearing
from beams_common.geometry.pose2d import compose
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake
from beams_ekf.bearing_ekf import BearingEkf
from beams_ekf.localiser import FilterSettings, Localiser, build_localiser, revolution_of
from beams_sim.sensor_sim import SensorSimConfig
from beams_sim.simulated_match import (
    SENSOR_MODELS,
    SimulatedMatch,
    calibrated_match,
    default_variance_model,
    sensor_config_of,
    simulate_match,
    table_natural_variance_rad2,
)
from beams_thesis.match_replay import match_odometry, offset_start, replay_match
from beams_thesis.replay import Accuracy, ReplayResult, accuracy

DEFAULT_SEED = 1
DEFAULT_DURATION_S = 90.0


@dataclass
class ModeRun:
    """One replay of the match with the bearings' variance from one model."""

    mode: str
    result: ReplayResult
    figures: Accuracy


def run_mode(match: SimulatedMatch, mode: str, config: SensorSimConfig | None = None) -> ModeRun:
    """Replay the match with the variance of `mode` ("published" keeps the decoder's exact variance)
    for the sensor `config` the match was simulated with."""
    variance = None
    if mode != "published":
        config = config or SensorSimConfig()
        model = default_variance_model(config.codes, config, table_natural_variance_rad2(config), mode)
        variance = lambda beacon_id, window: float(model.variance(beacon_id, window))  # noqa: E731
    # ekf_node's filter (its default settings: odometry error states, the wheels' random noise)
    localiser = build_localiser(match.beacon_map.as_dict(), match.turret_offset_m, FilterSettings())
    result = replay_match(localiser, match, *offset_start(match), variance_rad2=variance)
    return ModeRun(mode, result, accuracy(result))


def odometry_alone(match: SimulatedMatch) -> tuple[float, float, np.ndarray]:
    """RMS position (m) and heading (rad) of the odometry placed on the true start pose; its map poses."""
    poses = np.array([compose(match.initial_pose, tuple(p)) for p in match_odometry(match)])
    truth = match.ground_truth
    position = np.hypot(poses[:, 0] - truth.x_m, poses[:, 1] - truth.y_m)
    heading = np.array([wrap_to_pi(float(a)) for a in poses[:, 2] - truth.theta_rad])
    return float(np.sqrt(np.mean(position**2))), float(np.sqrt(np.mean(heading**2))), poses


def total_alone(match: SimulatedMatch) -> tuple[float, float, float, np.ndarray]:
    """RMS position and heading, and median position error, of ToTal per revolution (three bearings,
    no motion compensation) against the truth at the mean stamp of the three bearings; its fixes."""
    from beams_triangulation.total import triangulate

    ids = list(match.beacon_map.ids)
    errors, fixes = [], []
    for revolution in match.revolutions:
        by_id = {b.beacon_id: b for b in revolution.bearings}
        if set(ids) - set(by_id):
            continue
        fix = triangulate(match.beacon_map.xy, [by_id[i].bearing for i in ids], match.turret_offset_m)
        if not fix.ok:
            continue
        x, y, theta = match.truth_at(float(np.mean([by_id[i].stamp_s for i in ids])))
        errors.append((math.hypot(fix.x - x, fix.y - y), wrap_to_pi(fix.heading - theta)))
        fixes.append((fix.x, fix.y))
    errors_array = np.array(errors)
    # outliers (a wrongly stamped bearing) are part of ToTal alone's performance: no gate here
    rms = np.sqrt(np.mean(errors_array**2, axis=0))
    return float(rms[0]), float(rms[1]), float(np.median(errors_array[:, 0])), np.array(fixes)


def timings_us() -> dict[str, float]:
    """Best-of-5 mean cost (us) of a prediction, a bearing update and a revolution through the localiser."""
    beacons = {1: (-0.062, -0.062), 2: (-0.062, 2.062), 3: (3.062, 1.0)}
    ekf = BearingEkf(beacons, (0.02, 0.0))
    ekf.initialise((1.0, 1.0, 0.3), np.diag([1e-4, 1e-4, 1e-4]))
    expected, _ = ekf.predicted_bearing(2)
    saved = ekf.state()
    predict = timeit.Timer(lambda: ekf.predict((0.008, 0.0, 0.01)))
    # every timed update starts from the same state, so it is accepted (never a cheap gated-out one)
    restore = timeit.Timer(lambda: ekf.restore(saved))
    update = timeit.Timer(lambda: (ekf.restore(saved), ekf.update_bearing(2, expected + 1e-4, 1e-6)))
    ekf.restore(saved)
    assert ekf.update_bearing(2, expected + 1e-4, 1e-6).accepted

    localiser = Localiser(BearingEkf(beacons, (0.02, 0.0)))
    localiser.on_pose(planar_pose_intake(PoseSource.OPERATOR, 0.0, (1.0, 1.0, 0.3), np.diag([1e-4] * 3)))
    clock = {"t": 0.0, "pose": (0.0, 0.0, 0.0)}

    def revolution() -> None:
        # 5 odometry samples (50 Hz) then the three bearings of the revolution, stamped in the past
        for _ in range(5):
            clock["t"] += 0.02
            clock["pose"] = compose(clock["pose"], (0.008, 0.0, 0.01))
            localiser.on_odometry(clock["t"], clock["pose"])
        t = clock["t"]
        bearings = [Bearing(t - ago, beacon, 0.0, 1e-6) for beacon, ago in ((1, 0.09), (2, 0.05), (3, 0.01))]
        localiser.on_bearings(revolution_of(localiser, bearings))

    timers = (
        ("predict", predict, 2000),
        ("update", update, 2000),
        ("restore", restore, 2000),
        ("revolution", timeit.Timer(revolution), 200),
    )
    cost = {name: 1e6 * min(timer.repeat(repeat=5, number=number)) / number for name, timer, number in timers}
    cost["update"] -= cost.pop("restore")
    return cost


def plot_trajectory(
    match: SimulatedMatch, run: ModeRun, odometry_poses: np.ndarray, fixes: np.ndarray, path: str
) -> None:
    """Truth, EKF, odometry alone and ToTal fixes on the table (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (table, error) = plt.subplots(1, 2, figsize=(14, 5.2), gridspec_kw={"width_ratios": [1.5, 1]})
    table.plot(match.ground_truth.x_m, match.ground_truth.y_m, color="black", lw=2.5, label="ground truth")
    table.plot(odometry_poses[:, 0], odometry_poses[:, 1], color="tab:orange", lw=1, label="odometry alone")
    table.plot(fixes[:, 0], fixes[:, 1], ".", ms=2, color="tab:green", label="ToTal alone (per revolution)")
    table.plot(
        run.result.estimates[:, 0],
        run.result.estimates[:, 1],
        color="tab:blue",
        lw=1,
        label="EKF (odometry + every bearing)",
    )
    table.plot(*np.array(match.beacon_map.xy).T, "r^", ms=10, label="beacons")
    table.add_patch(plt.Rectangle((0, 0), 3, 2, fill=False, ls="--", color="grey"))
    table.set(
        xlim=(-0.3, 3.3),
        ylim=(-0.3, 2.3),
        aspect="equal",
        xlabel="x (m)",
        ylabel="y (m)",
        title="Simulated Eurobot match (map frame)",
    )
    table.legend(loc="upper center", fontsize=8, ncol=2)
    errors = run.result.errors()
    sigma = np.sqrt(run.result.covariances[:, 0, 0] + run.result.covariances[:, 1, 1])
    error.plot(
        run.result.times_s, 1000 * np.hypot(errors[:, 0], errors[:, 1]), lw=0.8, label="EKF position error"
    )
    error.plot(run.result.times_s, 1000 * sigma, lw=0.8, label="EKF sqrt(Pxx + Pyy)")
    error.set(xlabel="t (s)", ylabel="mm", title=f"EKF error ({run.mode} variance)", ylim=(0, None))
    error.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def rows(
    seed: int = DEFAULT_SEED, duration_s: float = DEFAULT_DURATION_S, plot_path: str | None = None
) -> list[Row]:
    """(figure, value, unit, compared with) rows: each sensor model's, then the costs, then the ideal
    receiver's variance modes."""
    table = []
    for sensor_model in SENSOR_MODELS:
        plot = plot_path if sensor_model == SENSOR_MODELS[0] else None
        table += [
            (f"{sensor_model} sensor: {figure}", value, unit, compared)
            for figure, value, unit, compared in _match_rows(sensor_model, seed, duration_s, plot)
        ]
    cost = timings_us()
    table += [
        ("EKF prediction (one odometry step)", cost["predict"], "us", "target < 50 us"),
        ("EKF bearing update (one accepted bearing, gate included)", cost["update"], "us", "target < 100 us"),
        (
            "localiser revolution (5 odometry + 3 late bearings)",
            cost["revolution"],
            "us",
            "100 ms revolution",
        ),
    ]
    table += _ideal_receiver_rows(seed, duration_s)
    return table


def _match_rows(sensor_model: str, seed: int, duration_s: float, plot_path: str | None) -> list[Row]:
    """The EKF's accuracy and consistency in each variance mode, odometry alone and ToTal alone, on the
    match of one sensor model."""
    config = sensor_config_of(sensor_model)
    match = calibrated_match(sensor_model, duration_s, seed)
    runs = [run_mode(match, mode, config) for mode in ("published", "exact", "bound", "constant")]
    odometry_position, odometry_heading, odometry_poses = odometry_alone(match)
    total_position, total_heading, total_median, fixes = total_alone(match)
    label = f"{duration_s:.0f} s match seed {seed}"
    per_run = [  # (position, heading, NEES) of each run
        (
            (f"EKF RMS position ({r.mode} R), {label}", 1000 * f.rms_position_m, "mm", "target <= 10 mm"),
            (f"EKF RMS heading ({r.mode} R)", math.degrees(f.rms_heading_rad), "deg", "target <= 0.3 deg"),
            (
                f"EKF NEES in 95% band ({r.mode} R)",
                100 * f.nees_in_band,
                "%",
                f"target >= 90% (mean NEES {f.nees_mean:.2f}, ideal 3)",
            ),
        )
        for r, f in ((run, run.figures) for run in runs)
    ]
    table = [row for kind in zip(*per_run, strict=True) for row in kind] + [
        (
            "EKF bearings gated (published R)",
            float(runs[0].result.counts.get("bearings_gated", 0)),
            "bearings",
            f"of {sum(len(r.bearings) for r in match.revolutions)}",
        ),
        ("odometry alone RMS position", 1000 * odometry_position, "mm", "EKF row above"),
        ("odometry alone RMS heading", math.degrees(odometry_heading), "deg", "EKF row above"),
        ("ToTal alone, uncompensated, RMS position", 1000 * total_position, "mm", "EKF row above"),
        ("ToTal alone, uncompensated, RMS heading", math.degrees(total_heading), "deg", "EKF row above"),
        ("ToTal alone, uncompensated, median error", 1000 * total_median, "mm", "EKF row above"),
    ]
    if plot_path:
        plot_trajectory(match, runs[0], odometry_poses, fixes, plot_path)
    return table


def _ideal_receiver_rows(seed: int, duration_s: float) -> list[Row]:
    """The variance modes when the OOK noise of chapters 3-4 is the only bearing noise (ideal receiver):
    what the exact variance buys once the natural noise no longer hides it."""
    config = SensorSimConfig.ideal()
    match = simulate_match(duration_s, seed, sensor_config=config)
    rows = []
    for mode in ("exact", "bound", "constant"):
        figures = run_mode(match, mode, config).figures
        rows += [
            (
                f"ideal receiver: EKF RMS position ({mode} R)",
                1000 * figures.rms_position_m,
                "mm",
                "same match, OOK noise only",
            ),
            (
                f"ideal receiver: EKF NEES in 95% band ({mode} R)",
                100 * figures.nees_in_band,
                "%",
                f"mean NEES {figures.nees_mean:.2f}, ideal 3",
            ),
        ]
    return rows


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
