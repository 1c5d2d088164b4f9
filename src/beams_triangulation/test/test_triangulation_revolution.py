"""The revolution pipeline without odometry: one ToTal solution per revolution, the motion since the
previous pose in the variances only (the pose is the same as without it)."""

import numpy as np

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.bearing import Bearing
from beams_triangulation import revolution
from beams_triangulation.gating import PoseEstimate
from beams_triangulation.revolution import RevolutionEstimator, estimate_revolution
from beams_triangulation.total import expected_bearings

VARIANCE_RAD2 = float(np.deg2rad(0.1) ** 2)


def _truth(t: float) -> tuple[float, float, float]:
    """A robot driving at 0.5 m/s and turning at 1 rad/s."""
    return (0.8 + 0.5 * t, 1.0, 0.2 + 1.0 * t)


def _revolution(start_s: float) -> list[Bearing]:
    stamps = (start_s + 0.01, start_s + 0.04, start_s + 0.075)
    return [
        Bearing(t, i, float(expected_bearings(EUROBOT_BEACON_MAP.subset([i]), _truth(t))[0]), VARIANCE_RAD2)
        for i, t in zip(EUROBOT_BEACON_MAP.ids, stamps, strict=True)
    ]


def test_one_solution_per_revolution_and_the_motion_only_in_the_covariance(monkeypatch):
    solved = []
    original = revolution.triangulate
    monkeypatch.setattr(revolution, "triangulate", lambda *a: solved.append(a) or original(*a))
    estimator = RevolutionEstimator(EUROBOT_BEACON_MAP)
    previous = None
    for k in range(4):
        bearings = _revolution(0.1 * k)
        before = len(solved)
        outcome = estimator.update(bearings)
        assert len(solved) == before + 1  # ToTal once per revolution, the motion included
        alone = estimate_revolution(bearings, EUROBOT_BEACON_MAP).result
        given = estimate_revolution(bearings, EUROBOT_BEACON_MAP, previous=previous).result
        result = outcome.result
        assert isinstance(result, PoseEstimate) and isinstance(alone, PoseEstimate)
        assert (result.x, result.y, result.heading) == (alone.x, alone.y, alone.heading)
        np.testing.assert_array_equal(result.covariance, given.covariance)
        if previous is None:  # the first revolution: no motion to add
            np.testing.assert_array_equal(result.covariance, alone.covariance)
        else:  # 0.5 m/s and 1 rad/s over the 65 ms of the revolution: the position std grows
            assert result.position_std_m > 1.5 * alone.position_std_m
        previous = ((result.x, result.y, result.heading), outcome.stamp_s)
