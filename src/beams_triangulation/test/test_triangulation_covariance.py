"""Pose covariance by the Jacobian of the ToTal solution (thesis B.3)."""

import math

import numpy as np
import pytest

from beams_triangulation.pose_covariance import (
    distance_error_std_m,
    pose_covariance,
    pose_covariance_many,
    position_std_m,
)
from beams_triangulation.total import expected_bearings, triangulate, triangulate_many

BEACONS = np.array([[0.0, 1.0], [-0.866, -0.5], [0.866, -0.5]])
OFFSET = (0.06, -0.025)


def _numerical_jacobian(pose, offset, step=1e-7):
    bearings = expected_bearings(BEACONS, pose, offset)
    columns = []
    for k in range(3):
        shift = np.zeros(3)
        shift[k] = step
        plus = triangulate(BEACONS, bearings + shift, offset)
        minus = triangulate(BEACONS, bearings - shift, offset)
        columns.append(
            [
                (plus.x - minus.x) / (2 * step),
                (plus.y - minus.y) / (2 * step),
                math.remainder(plus.heading - minus.heading, 2 * math.pi) / (2 * step),
            ]
        )
    return np.array(columns).T


@pytest.mark.parametrize("pose", [(0.3, -1.7, 0.4), (0.1, 0.2, -2.0), (1.8, 1.5, 3.0), (-1.2, 0.4, 1.0)])
def test_covariance_is_the_jacobian_of_totals_solution(pose):
    variances = np.array([1e-4, 2.5e-4, 4e-4])
    jacobian = _numerical_jacobian(pose, OFFSET)
    expected = jacobian @ np.diag(variances) @ jacobian.T
    actual = pose_covariance(BEACONS, pose, variances, OFFSET)
    np.testing.assert_allclose(actual, expected, rtol=1e-5, atol=1e-12)


def test_vectorised_covariance_matches_the_scalar_one():
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-2, 2, (2, 50))
    heading = rng.uniform(-np.pi, np.pi, 50)
    variances = rng.uniform(1e-6, 1e-4, (50, 3))
    many = pose_covariance_many(BEACONS, (x, y, heading), variances, OFFSET)
    for i in range(50):
        scalar = pose_covariance(BEACONS, (x[i], y[i], heading[i]), variances[i], OFFSET)
        np.testing.assert_allclose(many[i], scalar, rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("pose", [(0.2, -0.1, 0.0), (1.6, -1.4, 1.0), (-0.3, 1.7, -2.5)])
def test_covariance_predicts_monte_carlo_scatter(pose):
    sigma = np.deg2rad(0.05)
    rng = np.random.default_rng(11)
    bearings = expected_bearings(BEACONS, pose) + rng.normal(0.0, sigma, (40_000, 3))
    batch = triangulate_many(BEACONS, bearings)
    sample = np.cov(np.vstack([batch.x, batch.y, np.unwrap(batch.heading)]))
    predicted = pose_covariance(BEACONS, pose, [sigma**2] * 3)
    # 40 000 draws: the sample variances scatter by about 1%.
    np.testing.assert_allclose(np.diag(sample), np.diag(predicted), rtol=0.04)
    scale = math.sqrt(predicted[0, 0] * predicted[1, 1])
    assert sample[0, 1] == pytest.approx(predicted[0, 1], abs=0.04 * scale)


def test_covariance_and_inverse_abs_d_blow_up_together_at_the_critical_circle():
    radii = np.array([0.5, 0.9, 0.99, 0.999])
    poses = (radii * math.cos(2.0), radii * math.sin(2.0), np.zeros(4))
    inverse_abs_d = triangulate_many(BEACONS, expected_bearings(BEACONS, poses)).inverse_abs_d
    std = position_std_m(pose_covariance_many(BEACONS, poses, [1e-6] * 3))
    assert np.all(np.diff(std) > 0) and np.all(np.diff(inverse_abs_d) > 0)
    # The std grows as 1/distance to the circle; 1/|D| as 1/distance^2 (the three circle centres
    # converge to the circumcentre, so their triangle's area D shrinks as distance^2).
    assert std[3] / std[2] == pytest.approx(10.0, rel=0.1)
    assert inverse_abs_d[3] / inverse_abs_d[2] == pytest.approx(100.0, rel=0.1)


def test_covariance_scales_with_the_bearing_variance():
    small = pose_covariance(BEACONS, (0.4, 0.3, 0.2), [1e-6] * 3)
    large = pose_covariance(BEACONS, (0.4, 0.3, 0.2), [4e-6] * 3)
    np.testing.assert_allclose(large, 4.0 * small, rtol=1e-12)


def test_covariance_at_a_beacon_is_infinite_not_an_exception():
    assert np.all(np.isinf(pose_covariance(BEACONS, (0.0, 1.0, 0.0), [1e-6] * 3)))


def test_distance_error_std_of_known_distributions():
    # Isotropic: Rayleigh, std sqrt(2 - pi/2) sigma; degenerate: half-normal, std sqrt(1 - 2/pi) sigma.
    assert distance_error_std_m(np.diag([4.0, 4.0, 0.0])) == pytest.approx(2.0 * math.sqrt(2 - math.pi / 2))
    assert distance_error_std_m(np.diag([9.0, 0.0, 0.0])) == pytest.approx(3.0 * math.sqrt(1 - 2 / math.pi))
    rng = np.random.default_rng(2)
    covariance = np.array([[2.0, 0.7, 0.0], [0.7, 0.5, 0.0], [0.0, 0.0, 1.0]])
    samples = rng.multivariate_normal([0, 0], covariance[:2, :2], 400_000)
    assert distance_error_std_m(covariance) == pytest.approx(np.std(np.hypot(*samples.T)), rel=0.01)
