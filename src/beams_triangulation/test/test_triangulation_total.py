"""ToTal (thesis Algorithm 6.1): exactness, beacon orders, pseudo-singular and singular cases."""

import itertools
import math

import numpy as np
import pytest

from beams_common.geometry.angles import wrap_to_pi
from beams_triangulation.total import (
    COT_BOUND,
    NO_FIX_INVERSE_ABS_D,
    REASON_CRITICAL,
    REASON_NON_FINITE,
    expected_bearings,
    triangulate,
    triangulate_many,
)

# The thesis's equilateral setup (section 6.4.1); its critical circumference is the unit circle.
THESIS_BEACONS = np.array([[0.0, 1.0], [-0.866, -0.5], [0.866, -0.5]])
THESIS_CIRCLE_RADIUS = math.hypot(0.866, 0.5)


def _random_poses(count: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-2.0, 2.0, (2, count))
    return x, y, rng.uniform(-np.pi, np.pi, count)


def _inside_triangle(x: np.ndarray, y: np.ndarray, beacons: np.ndarray) -> np.ndarray:
    signs = []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        edge = beacons[b] - beacons[a]
        signs.append(edge[0] * (y - beacons[a, 1]) - edge[1] * (x - beacons[a, 0]))
    signs = np.array(signs)
    return np.all(signs > 0, axis=0) | np.all(signs < 0, axis=0)


@pytest.mark.parametrize("order", list(itertools.permutations(range(3))))
def test_noise_free_positions_are_exact_for_every_beacon_order(order):
    x, y, theta = _random_poses(100_000, seed=sum(i * 10**k for k, i in enumerate(order)))
    beacons = THESIS_BEACONS[list(order)]
    result = triangulate_many(beacons, expected_bearings(beacons, (x, y, theta)))
    away = np.abs(np.hypot(x, y) - THESIS_CIRCLE_RADIUS) > 1e-4
    inside = _inside_triangle(x, y, THESIS_BEACONS)
    position_error = np.hypot(result.x - x, result.y - y)
    heading_error = np.abs(wrap_to_pi(result.heading - theta))
    assert result.ok[away].all()
    for region in (away & inside, away & ~inside):
        assert region.sum() > 5_000  # both regions really are exercised
        assert position_error[region].max() < 1e-9
        assert heading_error[region].max() < 1e-9


def test_scalar_and_vectorised_forms_give_the_same_numbers():
    x, y, theta = _random_poses(300, seed=7)
    rng = np.random.default_rng(8)
    # Noisy bearings and a few pseudo-singular rows (equal bearings) as well.
    bearings = expected_bearings(THESIS_BEACONS, (x, y, theta)) + rng.normal(0.0, 0.01, (300, 3))
    bearings[:5, 1] = bearings[:5, 0]
    batch = triangulate_many(THESIS_BEACONS, bearings, turret_offset_m=(0.05, -0.02))
    for index in range(len(bearings)):
        fix = triangulate(THESIS_BEACONS, bearings[index], turret_offset_m=(0.05, -0.02))
        np.testing.assert_allclose(
            [fix.x, fix.y, fix.heading, fix.inverse_abs_d],
            [batch.x[index], batch.y[index], batch.heading[index], batch.inverse_abs_d[index]],
            rtol=1e-11,
            atol=1e-11,
        )
        assert fix.ok == batch.ok[index]


def test_per_row_beacons_match_shared_beacons():
    x, y, theta = _random_poses(40_000, seed=3)
    bearings = expected_bearings(THESIS_BEACONS, (x, y, theta))
    shared = triangulate_many(THESIS_BEACONS, bearings)
    per_row = triangulate_many(np.broadcast_to(THESIS_BEACONS, (40_000, 3, 2)), bearings)
    np.testing.assert_array_equal(shared.x, per_row.x)
    np.testing.assert_array_equal(shared.heading, per_row.heading)


def test_turret_offset_gives_the_robot_centre():
    offset = (0.08, -0.03)
    x, y, theta = 0.7, 1.4, 2.5
    bearings = expected_bearings(THESIS_BEACONS, (x, y, theta), turret_offset_m=offset)
    robot = triangulate(THESIS_BEACONS, bearings, turret_offset_m=offset)
    turret = triangulate(THESIS_BEACONS, bearings)
    assert robot.x == pytest.approx(x, abs=1e-12)
    assert robot.y == pytest.approx(y, abs=1e-12)
    assert robot.heading == pytest.approx(theta, abs=1e-12)
    # Without the offset, the fix is the turret centre: the offset rotated by the heading.
    assert turret.x - robot.x == pytest.approx(math.cos(theta) * 0.08 + math.sin(theta) * 0.03, abs=1e-12)
    assert turret.y - robot.y == pytest.approx(math.sin(theta) * 0.08 - math.cos(theta) * 0.03, abs=1e-12)


# Beacons with a vertical B1B2 line, so that exact phi_ij = 0 and pi are representable.
LINE_BEACONS = np.array([[0.0, 1.0], [0.0, -1.0], [1.5, 0.2]])


@pytest.mark.parametrize(
    ("position", "which"),
    [
        ((0.0, 0.3), "phi_12 = pi (between B1 and B2)"),
        ((0.0, 2.5), "phi_12 = 0 (beyond B1)"),
        ((0.0, -1.8), "phi_12 = 0 (beyond B2)"),
        ((0.75, -0.4), "phi_23 = pi (between B2 and B3)"),
        ((-1.5, -2.2), "phi_23 = 0 (beyond B2)"),
        ((0.75, 0.6), "phi_31 = pi (between B3 and B1)"),
        ((3.0, -0.6), "phi_31 = 0 (beyond B3)"),
    ],
)
def test_robot_on_a_beacon_line_gives_the_right_pose(position, which):
    x, y = position
    theta = 0.3
    bearings = expected_bearings(LINE_BEACONS, (x, y, theta))
    fix = triangulate(LINE_BEACONS, bearings)
    assert fix.ok, which
    # The bounded cotangent stands for an angle of 1/COT_BOUND rad: the error stays at that scale.
    assert math.hypot(fix.x - x, fix.y - y) < 100.0 / COT_BOUND, which
    assert abs(wrap_to_pi(fix.heading - theta)) < 100.0 / COT_BOUND, which


def test_exactly_equal_bearings_hit_the_cotangent_bound_not_infinity():
    # The robot beyond B1 on the B1B2 line sees B1 and B2 in exactly the same direction.
    third = expected_bearings(LINE_BEACONS, (0.0, 2.5, 0.0))[2]
    fix = triangulate(LINE_BEACONS, [-math.pi / 2, -math.pi / 2, third])
    assert fix.ok
    assert math.hypot(fix.x, fix.y - 2.5) < 1e-6


@pytest.mark.parametrize("angle", [0.3, 1.7, -2.4, 3.0])
def test_robot_on_the_critical_circle_gives_an_explicit_no_fix(angle):
    beacons = np.array([[1.0, 0.0], [-0.5, math.sqrt(3) / 2], [-0.5, -math.sqrt(3) / 2]])
    on_circle = (math.cos(angle), math.sin(angle), 0.2)
    fix = triangulate(beacons, expected_bearings(beacons, on_circle))
    batch = triangulate_many(beacons, expected_bearings(beacons, on_circle)[None, :])
    # Exactly on the circle D is 0 up to rounding: either no fix, or a huge 1/|D| the gate rejects.
    if fix.ok:
        assert fix.inverse_abs_d > 1e8
    else:
        assert fix.reason == REASON_CRITICAL
        assert (fix.x, fix.y, fix.heading) == (0.0, 0.0, 0.0)
        assert fix.inverse_abs_d == NO_FIX_INVERSE_ABS_D
        assert not batch.ok[0]
    assert all(math.isfinite(v) for v in (fix.x, fix.y, fix.heading, fix.inverse_abs_d))
    assert np.all(np.isfinite([batch.x, batch.y, batch.heading, batch.inverse_abs_d]))


def test_d_is_exactly_zero_on_the_circle_through_a_symmetric_layout():
    # Square layout: the robot at the fourth corner is concyclic with the three beacons and every
    # quantity is exactly representable, so D is exactly 0.
    beacons = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    fix = triangulate(beacons, expected_bearings(beacons, (0.0, -1.0, 0.0)))
    assert not fix.ok
    assert fix.reason == REASON_CRITICAL
    assert not triangulate_many(beacons, expected_bearings(beacons, (0.0, -1.0, 0.0))[None, :]).ok[0]


def test_collinear_beacons_work_off_their_line_and_fail_cleanly_on_it():
    beacons = np.array([[0.0, 0.0], [1.0, 0.0], [2.5, 0.0]])
    off_line = triangulate(beacons, expected_bearings(beacons, (1.2, 0.9, -0.4)))
    assert off_line.ok
    assert math.hypot(off_line.x - 1.2, off_line.y - 0.9) < 1e-9
    for robot_x in (4.0, 0.5, -1.0):
        bearings = expected_bearings(beacons, (robot_x, 0.0, 0.0))
        on_line = triangulate(beacons, bearings)
        assert not on_line.ok
        assert on_line.reason == REASON_CRITICAL
        assert not triangulate_many(beacons, bearings[None, :]).ok[0]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_bearing_gives_no_fix_with_the_reason(bad):
    fix = triangulate(THESIS_BEACONS, [0.1, bad, 2.0])
    assert not fix.ok
    assert fix.reason == REASON_NON_FINITE
    assert not triangulate_many(THESIS_BEACONS, [[0.1, bad, 2.0]]).ok[0]


def test_bearings_shifted_by_full_turns_give_the_same_fix():
    bearings = expected_bearings(THESIS_BEACONS, (1.3, -0.4, 0.9))
    a = triangulate(THESIS_BEACONS, bearings)
    b = triangulate(THESIS_BEACONS, bearings + np.array([2 * np.pi, -2 * np.pi, 4 * np.pi]))
    assert (a.x, a.y) == pytest.approx((b.x, b.y), abs=1e-12)
    assert wrap_to_pi(a.heading - b.heading) == pytest.approx(0.0, abs=1e-12)


def test_inverse_abs_d_grows_towards_the_critical_circle():
    radii = np.array([0.2, 0.6, 0.9, 0.99, 0.999])
    poses = (radii * math.cos(0.4), radii * math.sin(0.4), np.zeros_like(radii))
    batch = triangulate_many(THESIS_BEACONS, expected_bearings(THESIS_BEACONS, poses))
    assert np.all(np.diff(batch.inverse_abs_d[1:]) > 0)
    assert batch.inverse_abs_d[-1] > 100 * batch.inverse_abs_d[1]


def test_rejects_badly_shaped_input():
    with pytest.raises(ValueError, match="expected bearings"):
        triangulate_many(THESIS_BEACONS, np.zeros((4, 2)))
