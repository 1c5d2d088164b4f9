"""Plausibility benchmark: the EKF's worst position error on the synthetic match (beams_thesis.synthetic)
under well-formed but wrong inputs, with the checks and without, and what the checks cost: the odometry
shifted by +100 m from 3 s on, re-referenced with `MotionLimits` and followed without."""

import sys
from itertools import groupby
from math import hypot

import numpy as np
from rows_table import Row, bench_main, best_per_call_s

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.bearing import Bearing
from beams_common.intake.plausibility import (
    MotionLimits,
    StampTolerance,
    odometry_step_problem,
    stamp_problem,
)
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake
from beams_ekf.localiser import build_localiser, revolution_of
from beams_ekf.settings import FilterSettings
from beams_thesis.synthetic import synthetic_match

FAULT_S = 3.0
MATCH_S = 10.0


def _worst_error_m(odometry_offset_m: float = 0.0, checks: bool = True) -> float:
    """The EKF's worst position error (m) over the match, the odometry shifted from FAULT_S on."""
    match = synthetic_match(MATCH_S, seed=5)
    limits = MotionLimits() if checks else MotionLimits(1e9, 1e9)
    localiser = build_localiser(
        EUROBOT_BEACON_MAP.as_dict(), (0.0, 0.0), FilterSettings(motion_limits=limits)
    )
    tolerance = StampTolerance()
    start = float(match.times_s[0])
    localiser.on_odometry(start, tuple(match.odometry[0]))
    localiser.on_pose(
        planar_pose_intake(PoseSource.OPERATOR, start, match.truth_at(start), np.diag([1e-4] * 3))
    )
    worst, k = 0.0, 1
    for arrival_s, group in groupby(match.bearings, key=lambda b: b.arrival_s):
        while k < len(match.times_s) and match.times_s[k] <= arrival_s:
            t = float(match.times_s[k])
            pose = np.array(match.odometry[k]) + np.array([odometry_offset_m * (t >= FAULT_S), 0.0, 0.0])
            localiser.on_odometry(t, tuple(pose))
            k += 1
        bearings = [Bearing(b.stamp_s, b.beacon_id, b.bearing_rad, b.variance_rad2) for b in group]
        newest_s = max(b.stamp_s for b in bearings)
        if not (checks and stamp_problem("revolution", newest_s, arrival_s, tolerance)):
            localiser.on_bearings(revolution_of(localiser, bearings))
        estimate = localiser.estimate()
        truth = match.truth_at(estimate.stamp_s)
        worst = max(worst, hypot(estimate.pose[0] - truth[0], estimate.pose[1] - truth[1]))
    return worst


def rows() -> list[Row]:
    result: list[Row] = []
    for checks in ("on", "off"):
        worst = _worst_error_m(100.0, checks == "on")
        result.append(
            (f"EKF worst error, odometry +100 m, checks {checks}", worst, "m", "35 m then 77 m, 'tracking'")
        )
    result.append(("EKF worst error, no fault", _worst_error_m(), "m", "~1 cm RMS"))
    tolerance, limits = StampTolerance(), MotionLimits()
    result.append(
        (
            "stamp check + odometry step check, per message",
            best_per_call_s(
                lambda: (
                    stamp_problem("x", 99.9, 100.0, tolerance),
                    odometry_step_problem(0.02, (0.01, 0.0, 0.01), limits),
                ),
                50_000,
            )
            * 1e6,
            "us",
            "input checks of a revolution (bench_validation)",
        )
    )
    return result


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
