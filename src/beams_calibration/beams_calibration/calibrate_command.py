"""`calibrate`: Algorithm 7.1 on a dataset file, offline (the same computation as the Calibrate service).

    calibrate DATASET.yaml -o calibration.yaml [--plots DIR] [--eta 1.0] [--threshold 0.1] [--dry-run]

Prints progress lines while it runs, then the RMS errors after each stage (table 7.5 for this dataset),
the leave-one-position-out error, the parameters and any plausibility warning. Exit status 0 on
success, 2 when the dataset is missing, malformed or refused, the calibration makes the RMS worse
(without --force), or an output cannot be written (then no file is changed).
"""

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from beams_calibration.calibrate import (
    DEFAULT_ETA_M_PER_RAD,
    DEFAULT_THRESHOLD,
    THESIS_TABLE_7_5,
    CalibrationRefusedError,
    CalibrationResult,
    calibrate,
)
from beams_calibration.dataset import load_dataset
from beams_calibration.outputs import rms_regression, write_outputs
from beams_common.config.command_line import command


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="calibrate", description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path, help="dataset file (YAML, written by calibration_node)")
    parser.add_argument(
        "-o", "--output", type=Path, default=Path("calibration.yaml"), help="calibration file"
    )
    parser.add_argument("--plots", type=Path, help="directory for the PNG figures")
    parser.add_argument("--eta", type=float, default=DEFAULT_ETA_M_PER_RAD, help="eta of eq. 7.12 (m/rad)")
    parser.add_argument("--threshold", type=float, default=DEFAULT_THRESHOLD, help="t of Algorithm 7.1")
    parser.add_argument("--max-iterations", type=int, default=10, help="bound on the loop of Algorithm 7.1")
    parser.add_argument(
        "--beacons", type=int, nargs=3, help="the three beacon ids to use (default: first three)"
    )
    parser.add_argument("--no-leave-one-out", action="store_true", help="skip the generalisation error")
    parser.add_argument(
        "--table-7-5", action="store_true", help="also fit each method alone and in pairs, as table 7.5 does"
    )
    parser.add_argument("--dry-run", action="store_true", help="do not write the calibration file")
    parser.add_argument("--force", action="store_true", help="write a calibration that makes the RMS worse")
    return parser


def format_report(result: CalibrationResult) -> str:
    """The stages table, leave-one-out error, parameters and warnings, as printed by the command."""
    lines = [f"{'stage':<44} {'position RMS (mm)':>18} {'orientation RMS (deg)':>22}"]
    rows = [*result.stages, *([result.leave_one_out] if result.leave_one_out else [])]
    lines += [
        f"{s.stage:<44} {s.position_rms_m * 1e3:>18.3f} {math.degrees(s.orientation_rms_rad):>22.4f}"
        for s in rows
    ]
    lines.append(f"Algorithm 7.1 loop ran {result.iterations} time(s)")
    if result.table_7_5:
        lines.append(
            f"{'table 7.5 for this dataset':<60} {'position (mm)':>14} {'orientation (deg)':>18}  thesis"
        )
        for row, (position_mm, orientation_deg) in zip(result.table_7_5, THESIS_TABLE_7_5, strict=True):
            position, orientation = row.position_rms_m * 1e3, math.degrees(row.orientation_rms_rad)
            lines.append(
                f"{row.stage:<60} {position:>14.3f} {orientation:>18.4f}  "
                f"{position_mm:.2f} mm, {orientation_deg:.4f} deg"
            )
    for beacon_id, (x, y) in zip(result.beacon_map.ids, result.beacon_map.xy, strict=True):
        lines.append(f"beacon {beacon_id}: ({x:.4f}, {y:.4f}) m")
    a, b, c, d = result.correction.power_bias_coefficients
    lines.append(f"power bias: a={a:.4g} b={b:.4g} c={c:.4g} d={d:.4g} (eq. 7.19, rad)")
    lines.append(
        "rotation bias: "
        + " ".join(
            f"{n}={v:.3e}" for n, v in zip("ABCD", result.correction.rotation_bias_coefficients, strict=True)
        )
        + " (eq. 7.25, rad)"
    )
    dx, dy = result.turret_offset_m
    lines.append(f"turret offset: ({dx * 1e3:.2f}, {dy * 1e3:.2f}) mm (eq. 7.26)")
    lines += [f"WARNING: {w}" for w in result.warnings]
    return "\n".join(lines)


@command("calibrate")
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `calibrate` console script; returns the exit status."""
    args = _parser().parse_args(argv)
    start = time.monotonic()

    def progress(line: str) -> None:
        print(f"[{time.monotonic() - start:6.1f} s] {line}", flush=True)

    dataset = load_dataset(args.dataset)
    progress(f"{len(dataset.configurations)} configurations read from {args.dataset}")
    result = calibrate(
        dataset,
        eta_m_per_rad=args.eta,
        threshold=args.threshold,
        max_iterations=args.max_iterations,
        leave_one_out=not args.no_leave_one_out,
        with_table_7_5=args.table_7_5,
        beacon_ids=args.beacons,
        progress=progress,
    )
    print(format_report(result))
    worse = rms_regression(result, args.eta)
    if worse and not args.force:
        raise CalibrationRefusedError(f"{worse} (--force writes it); nothing written")
    # all or nothing: a failure leaves every file as it was
    for path in write_outputs(result, None if args.dry_run else args.output, args.plots):
        progress(f"written: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
