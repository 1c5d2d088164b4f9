"""Validation benchmark: what the checks of every input and output cost per revolution, and
what a flood costs the EKF now that a revolution over MAX_BEARINGS_PER_REVOLUTION is refused whole.
"""

import sys

import numpy as np
from rows_table import Row, bench_main, best_per_call_s

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.bearing import Bearing
from beams_common.intake.bearing_intake import RevolutionIntake, revolution_intake
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake
from beams_common.intake.validation import bearing_problem, one_sighting_per_beacon, planar_estimate_problem
from beams_ekf.localiser import FilterSettings, build_localiser
from beams_triangulation.total import expected_bearings

TRUE_POSE = (1.2, 0.8, 0.4)
FLOOD_BEARINGS = 10_000


def _revolution(count: int) -> list[Bearing]:
    angles = expected_bearings(EUROBOT_BEACON_MAP.xy, TRUE_POSE)
    return [Bearing(10.0 + 1e-5 * k, 1 + k % 3, float(angles[k % 3]), 3e-7) for k in range(count)]


def _localiser():
    localiser = build_localiser(EUROBOT_BEACON_MAP.as_dict(), (0.0, 0.0), FilterSettings())
    localiser.on_pose(planar_pose_intake(PoseSource.OPERATOR, 10.0, TRUE_POSE, np.diag([1e-4, 1e-4, 1e-3])))
    return localiser


def rows() -> list[Row]:
    revolution = _revolution(3)
    ids = EUROBOT_BEACON_MAP.ids
    covariance = np.diag([1e-6, 1e-6, 1e-5])

    def input_checks():
        for b in revolution:
            bearing_problem(b.beacon_id, b.bearing_rad, b.variance_rad2, b.stamp_s, ids)
        one_sighting_per_beacon(revolution)

    flood = _revolution(FLOOD_BEARINGS)
    # what the EKF did without the intake's size rule (every bearing of the message kept) and does now
    all_through = best_per_call_s(lambda: _localiser().on_bearings(RevolutionIntake(flood)), 1, repeat=3)
    refused = best_per_call_s(lambda: _localiser().on_bearings(revolution_intake(flood, ids)), 5, repeat=3)
    return [
        (
            "input checks of a 3-bearing revolution (bearing rule, one sighting per beacon)",
            best_per_call_s(input_checks, 20_000) * 1e6,
            "us",
            "ToTal scalar call (bench_triangulation)",
        ),
        (
            "output check of a pose (finite, covariance SPD)",
            best_per_call_s(lambda: planar_estimate_problem(TRUE_POSE, covariance), 20_000) * 1e6,
            "us",
            "-",
        ),
        (
            f"EKF on a {FLOOD_BEARINGS}-bearing revolution, every bearing filtered, without the intake "
            "(filter set-up included)",
            all_through * 1e3,
            "ms",
            "0.5 s without output over DDS",
        ),
        (
            f"EKF on a {FLOOD_BEARINGS}-bearing revolution, refused whole, now (filter set-up included)",
            refused * 1e3,
            "ms",
            "the row above",
        ),
    ]


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
