"""ToTal benchmark (thesis ch. 6): cost of the scalar and vectorised forms, and the accuracy
of gated poses on the simulated Eurobot match with and without odometry.
"""

import math
import sys

import numpy as np
from rows_table import Row, bench_main, best_per_call_s

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_sim.simulated_match import simulate_match
from beams_triangulation.gating import GateConfig, PoseEstimate, gated_estimate
from beams_triangulation.motion_compensation import interpolate_pose
from beams_triangulation.pipeline import RevolutionEstimator
from beams_triangulation.pose_covariance import pose_covariance_many
from beams_triangulation.total import expected_bearings, triangulate, triangulate_many

THESIS_BEACONS = np.array([[0.0, 1.0], [-0.866, -0.5], [0.866, -0.5]])
VECTOR_COUNT = 1_000_000
DEFAULT_SEED = 4


def scalar_rows() -> list[Row]:
    beacons = EUROBOT_BEACON_MAP.xy.tolist()
    bearings = expected_bearings(EUROBOT_BEACON_MAP.xy, (1.2, 0.8, 0.4)).tolist()
    variances = [np.deg2rad(0.1) ** 2] * 3
    config = GateConfig()

    def full_call():
        return gated_estimate(triangulate(beacons, bearings), beacons, variances, (1, 2, 3), config)

    return [
        (
            "ToTal scalar call: pose + covariance + gate",
            best_per_call_s(full_call, 20_000) * 1e6,
            "us",
            "under 10 us in CPython",
        ),
        (
            "ToTal scalar call: pose only (triangulate)",
            best_per_call_s(lambda: triangulate(beacons, bearings), 20_000) * 1e6,
            "us",
            "-",
        ),
    ]


def vector_rows() -> list[Row]:
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-2.0, 2.0, (2, VECTOR_COUNT))
    heading = rng.uniform(-np.pi, np.pi, VECTOR_COUNT)
    bearings = expected_bearings(THESIS_BEACONS, (x, y, heading))
    best_total = best_per_call_s(lambda: triangulate_many(THESIS_BEACONS, bearings), 1, 5)
    best_covariance = best_per_call_s(
        lambda: pose_covariance_many(THESIS_BEACONS, (x, y, heading), [1e-6] * 3), 1, 5
    )
    return [
        (
            "ToTal vectorised, 10^6 triplets, one core",
            best_total / VECTOR_COUNT * 1e9,
            "ns/pose",
            "<= 60 ns; thesis table 6.1: 163 ns in C (i7 920)",
        ),
        ("pose covariance vectorised, 10^6 poses", best_covariance / VECTOR_COUNT * 1e9, "ns/pose", "-"),
    ]


def match_rows(seed: int = DEFAULT_SEED) -> list[Row]:
    match = simulate_match(90.0, seed=seed)
    odometry = match.odometry
    samples = np.column_stack([odometry.x_m, odometry.y_m, odometry.theta_rad])

    def odometry_at(t):
        return interpolate_pose(odometry.stamp_s, samples, t)

    rows: list[Row] = []
    targets = {
        "with odometry": (">= 90%", "< 20 mm", "< 0.5 deg"),
        "without odometry": ("measured and recorded",) * 3,
    }
    for label, source in (("with odometry", odometry_at), ("without odometry", None)):
        estimator = RevolutionEstimator(match.beacon_map, turret_offset_m=match.turret_offset_m)
        errors = []
        for revolution in match.revolutions:
            outcome = estimator.update([b.as_bearing() for b in revolution.bearings], source)
            estimate = outcome.result
            if isinstance(estimate, PoseEstimate) and estimate.accepted:
                x, y, theta = match.truth_at(outcome.stamp_s)
                heading_error = wrap_to_pi(estimate.heading - theta)
                errors.append((math.hypot(estimate.x - x, estimate.y - y), heading_error))
        errors = np.array(errors)
        rows += [
            (
                f"simulated match {label}: poses accepted",
                100.0 * len(errors) / len(match.revolutions),
                "%",
                targets[label][0],
            ),
            (
                f"simulated match {label}: position RMS (accepted)",
                1000.0 * math.sqrt(np.mean(errors[:, 0] ** 2)),
                "mm",
                targets[label][1],
            ),
            (
                f"simulated match {label}: heading RMS (accepted)",
                math.degrees(math.sqrt(np.mean(errors[:, 1] ** 2))),
                "deg",
                targets[label][2],
            ),
        ]
    return rows


def rows(seed: int = DEFAULT_SEED) -> list[Row]:
    return scalar_rows() + vector_rows() + match_rows(seed)


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
