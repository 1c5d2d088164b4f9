"""Calibration benchmark (issue 6, thesis chapter 7): the whole calibration of the thesis's 48
configurations, measured by the driver's simulated sensor with thesis-sized biases, its cost and the
RMS errors next to table 7.5.

Usage: python bench/bench_calibration.py [--seed N]
(`rows()` is what bench/run_all.py collects.)
"""

import argparse
import math
import time
import timeit

import numpy as np

from beams_calibration import thesis_setup
from beams_calibration.calibrate import PARAMETER_COUNT, Problem, calibrate
from beams_calibration.dataset import to_arrays
from beams_common.bearing_correction import THESIS_CORRECTION

DEFAULT_SEED = 1
REVOLUTIONS = 100


def rows(seed: int = DEFAULT_SEED) -> list[tuple[str, float, str, str]]:
    sensor = thesis_setup.SimulatedSensor(
        thesis_setup.TRUE_BEACONS,
        np.random.default_rng(seed),
        correction=THESIS_CORRECTION,
        turret_offset_m=thesis_setup.THESIS_TURRET_OFFSET_M,
    )
    poses = thesis_setup.reference_poses()
    start = time.process_time()
    dataset = thesis_setup.capture_dataset(
        sensor,
        poses,
        revolutions=REVOLUTIONS,
        placement_sigma=thesis_setup.PLACEMENT_SIGMA,
        rng=np.random.default_rng(seed + 1),
    )
    capture_s = time.process_time() - start

    start = time.process_time()
    fitted = calibrate(dataset, leave_one_out=False)
    algorithm_s = time.process_time() - start
    start = time.process_time()
    result = calibrate(dataset)
    whole_s = time.process_time() - start
    table = calibrate(dataset, leave_one_out=False, with_table_7_5=True).table_7_5

    problem = Problem.of(to_arrays(dataset))
    vector = np.zeros(PARAMETER_COUNT)
    evaluations = 2000
    objective_us = timeit.timeit(lambda: problem.objective(vector), number=evaluations) / evaluations * 1e6

    loo = result.leave_one_out
    assert loo is not None and fitted.after == result.after
    count = len(dataset.configurations)
    table_rows = [
        (
            row.stage.replace("table 7.5", "calibration: table 7.5"),
            row.position_rms_m * 1e3,
            "mm",
            f"{position} mm",
        )
        for row, (position, _) in zip(table, thesis_setup.THESIS_TABLE_7_5, strict=True)
    ]
    return [
        (
            f"calibration: whole (Alg. 7.1 + leave-one-out), {count} configurations",
            whole_s,
            "s CPU",
            "< 60 s (issue 6)",
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
            "<= 0.5 mm (issue 6)",
        ),
        (
            "calibration: largest beacon error",
            float(np.max(np.hypot(*(result.beacon_map.xy - thesis_setup.TRUE_BEACONS.xy).T))) * 1e3,
            "mm",
            "<= 1.5 mm (issue 6)",
        ),
        *table_rows,
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    options = parser.parse_args()
    table = rows(options.seed)
    width = max(len(row[0]) for row in table)
    print(f"{'figure':<{width}} | {'value':>10} | {'unit':<14} | compared with")
    for figure, value, unit, compared in table:
        print(f"{figure:<{width}} | {value:>10.4g} | {unit:<14} | {compared}")


if __name__ == "__main__":
    main()
