"""Calibration benchmark (thesis chapter 7): the whole calibration of the thesis's 48
configurations, measured by the driver's simulated sensor with thesis-sized biases, its cost; table 7.5
and figures 7.7 and 7.10 on the stand-in for the thesis's recordings (`thesis_setup.thesis_dataset`).
"""

import math
import sys
import time
import timeit

import numpy as np
from rows_table import Row, bench_main
from scipy.stats import spearmanr

from beams_calibration.calibrate import PARAMETER_COUNT, Problem, calibrate, optimise_groups
from beams_calibration.dataset import to_arrays
from beams_common.calibration.bearing_correction import THESIS_CORRECTION
from beams_thesis import thesis_figures, thesis_setup
from beams_triangulation.error_map import grid, monte_carlo_maps

DEFAULT_SEED = 1
REVOLUTIONS = 100


def rows(seed: int = DEFAULT_SEED) -> list[Row]:
    sensor = thesis_setup.SimulatedSensor(
        thesis_setup.TRUE_BEACONS,
        np.random.default_rng(seed),
        correction=THESIS_CORRECTION,
        turret_offset_m=thesis_setup.THESIS_TURRET_OFFSET_M,
    )

    def cpu_timed(work):  # (its result, the CPU time it took in s)
        start = time.process_time()
        return work(), time.process_time() - start

    poses, sigma = thesis_setup.reference_poses(), thesis_setup.PLACEMENT_SIGMA
    dataset, capture_s = cpu_timed(
        lambda: thesis_setup.capture_dataset(
            sensor, poses, revolutions=REVOLUTIONS, placement_sigma=sigma, rng=np.random.default_rng(seed + 1)
        )
    )
    fitted, algorithm_s = cpu_timed(lambda: calibrate(dataset, leave_one_out=False))
    result, whole_s = cpu_timed(lambda: calibrate(dataset))
    # Table 7.5 on the stand-in for the thesis's recordings (thesis-hardware receiver, chapter 7's biases).
    table = calibrate(thesis_setup.thesis_dataset(seed), leave_one_out=False, with_table_7_5=True).table_7_5

    problem = Problem.of(to_arrays(dataset))
    vector = np.zeros(PARAMETER_COUNT)
    evaluations = 2000
    objective_us = timeit.timeit(lambda: problem.objective(vector), number=evaluations) / evaluations * 1e6

    loo = result.leave_one_out
    assert loo is not None and fitted.after == result.after
    count = len(dataset.configurations)
    lines = [
        (row.stage.replace("table 7.5", "calibration: table 7.5"), row, thesis)
        for row, thesis in zip(table, thesis_setup.THESIS_TABLE_7_5, strict=True)
    ]
    table_rows = [(stage, row.position_rms_m * 1e3, "mm", f"{mm} mm") for stage, row, (mm, _) in lines]
    table_rows += [
        (f"{stage} (orientation)", math.degrees(row.orientation_rms_rad), "deg", f"{deg} deg")
        for stage, row, (_, deg) in lines
    ]
    return [
        (
            f"calibration: whole (Alg. 7.1 + leave-one-out), {count} configurations",
            whole_s,
            "s CPU",
            "< 60 s",
        ),
        ("calibration: Algorithm 7.1 alone", algorithm_s, "s CPU", "-"),
        (f"calibration: err_RMS evaluation (eq. 7.12, {count} ToTal fixes)", objective_us, "us", "-"),
        (
            f"calibration: simulated capture ({REVOLUTIONS} revolutions x {count})",
            capture_s / (REVOLUTIONS * count) * 1e3,
            "ms/revolution",
            "-",
        ),
        (
            "calibration: position RMS before",
            result.before.position_rms_m * 1e3,
            "mm",
            "8.75 mm (table 7.5, 1)",
        ),
        (
            "calibration: position RMS after",
            result.after.position_rms_m * 1e3,
            "mm",
            "2.16 mm (table 7.5, 11)",
        ),
        (
            "calibration: position RMS leave-one-position-out",
            loo.position_rms_m * 1e3,
            "mm",
            "not in the thesis",
        ),
        (
            "calibration: orientation RMS before",
            math.degrees(result.before.orientation_rms_rad),
            "deg",
            "0.4297 deg (table 7.5, 1)",
        ),
        (
            "calibration: orientation RMS after",
            math.degrees(result.after.orientation_rms_rad),
            "deg",
            "0.1806 deg (table 7.5, 11)",
        ),
        (
            "calibration: turret offset error",
            math.hypot(*np.subtract(result.turret_offset_m, thesis_setup.THESIS_TURRET_OFFSET_M)) * 1e3,
            "mm",
            "<= 0.5 mm",
        ),
        (
            "calibration: largest beacon error",
            float(np.max(np.hypot(*(result.beacon_map.xy - thesis_setup.TRUE_BEACONS.xy).T))) * 1e3,
            "mm",
            "<= 1.5 mm",
        ),
        *table_rows,
        *figure_rows(seed),
    ]


def figure_rows(seed: int) -> list[Row]:
    """Figure 7.7 (rotation experiment at P_9, corrected by the table 7.5 line-3 fit) and figure 7.10
    (beacon coordinates with 1 cm of noise against bearings with 0.1 deg, section 6.4.1's layout)."""
    problem = Problem.of(to_arrays(thesis_setup.thesis_dataset(seed)))
    vector, _ = optimise_groups(problem, np.zeros(PARAMETER_COUNT), ["rotation", "turret"])
    rotation = thesis_figures.rotation_experiment(
        thesis_setup.thesis_dataset(
            seed + 100,
            thesis_setup.rotation_experiment_poses(),
            placement_sigma=thesis_setup.ROTATION_PLACEMENT_SIGMA,
        ),
        problem.model(vector),
    )
    thesis_before, thesis_after = thesis_setup.THESIS_ROTATION_EXPERIMENT_RMS_MM
    beacons = thesis_figures.SECTION_6_4_1_BEACONS
    x, y = grid(thesis_figures.SECTION_6_4_1_AREA, 0.1)
    sigma_m = thesis_figures.FIGURE_7_10_BEACON_SIGMA_M
    beacon_noise = thesis_figures.beacon_noise_maps(beacons, x, y, sigma_m, 400, np.random.default_rng(seed))
    angle_noise = monte_carlo_maps(
        beacons, x, y, thesis_figures.FIGURE_7_10_ANGLE_SIGMA_RAD, 400, np.random.default_rng(seed + 1)
    )
    equivalent = thesis_figures.equivalent_angle_maps(beacons, x, y, sigma_m)
    radius = np.hypot(x, y)
    away = np.min(np.hypot(x[..., None] - beacons[:, 0], y[..., None] - beacons[:, 1]), axis=-1) > 0.2
    near = (np.abs(radius - 1.0) < 0.3) & away
    regular = (np.abs(radius - 1.0) > 0.2) & away
    centre = np.unravel_index(np.argmin(radius), radius.shape)
    return [
        (
            "calibration: fig. 7.7 position RMS before",
            rotation.before.position_rms_m * 1e3,
            "mm",
            f"{thesis_before} mm",
        ),
        (
            "calibration: fig. 7.7 position RMS after",
            rotation.after.position_rms_m * 1e3,
            "mm",
            f"{thesis_after} mm",
        ),
        (
            "calibration: fig. 7.7 bearing periodic error before (harmonics 1-2, RMS)",
            math.degrees(rotation.bearing_harmonics_rad(rotation.residuals_before)),
            "deg",
            "0.117 deg (fig. 7.12 function) + turret offset: 0.171 deg by geometry",
        ),
        (
            "calibration: fig. 7.7 bearing periodic error after",
            math.degrees(rotation.bearing_harmonics_rad(rotation.residuals_after)),
            "deg",
            "-",
        ),
        (
            "calibration: fig. 7.10 beacon-noise / equivalent-angle prediction (median)",
            float(np.median(beacon_noise.position_std_m[regular] / equivalent.position_std_m[regular])),
            "ratio",
            "1 (section 7.3.4: equivalent angle error)",
        ),
        (
            "calibration: fig. 7.10 rank correlation of the two maps near the critical circle",
            float(spearmanr(beacon_noise.position_std_m[near], angle_noise.position_std_m[near]).statistic),
            "Spearman",
            "'similar, especially around the critical circumference'",
        ),
        (
            "calibration: fig. 7.10 beacon map at the circle centre (sigma 1 cm)",
            float(beacon_noise.position_std_m[centre]) * 1e3,
            "mm",
            f"5.73 x the 0.1 deg map ({float(angle_noise.position_std_m[centre]) * 1e3:.2f} mm)",
        ),
    ]


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
