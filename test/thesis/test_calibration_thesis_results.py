"""Table 7.5 (lines 2-10), figure 7.7 and figure 7.10 of the thesis, reproduced on the simulated setup.

The recordings stand in for the thesis's: `thesis_setup.thesis_dataset`, the thesis-hardware receiver
(sections 5.5-5.6) with the power bias of figure 7.11, the rotation bias of figure 7.12, the turret offset
of section 7.3.3, the beacons where table 7.3 found them, the map of table 7.1, 100 revolutions per pose,
and the placement error that the thesis's final residual (table 7.5, line 11) leaves unexplained. The
simulated sensor is not the thesis's prototype: the bands below are for the ordering and the size of
each stage's improvement, and were checked over seeds 1-12 (the range seen is quoted with each band).
"""

import math

import numpy as np
import pytest
from scipy.stats import spearmanr

from beams_calibration.calibrate import (
    PARAMETER_COUNT,
    Model,
    Problem,
    calibrate,
    optimise_groups,
    pose_errors,
    rms_figures,
)
from beams_calibration.dataset import to_arrays
from beams_common.calibration.bearing_correction import THESIS_ROTATION_BIAS_COEFFICIENTS, BearingCorrection
from beams_common.geometry.angles import wrap_to_pi
from beams_thesis import thesis_figures, thesis_setup
from beams_triangulation.error_map import grid, monte_carlo_maps
from beams_triangulation.total import expected_bearings, triangulate_many

SEED = 3
MM = 1e-3
# Figure 7.9: the rotation bias fitted alone (table 7.5, line 3), A, B, C, D in rad.
FIGURE_7_9_COEFFICIENTS = (8.79e-4, -1.01e-3, -1.03e-3, -1.74e-3)


def _function_rms_rad(coefficients) -> float:
    """RMS over the turret circle of A cos + B sin + C cos 2 + D sin 2 (eq. 7.25)."""
    return math.sqrt(sum(c * c for c in coefficients) / 2.0)


@pytest.fixture(scope="module")
def recordings():
    return thesis_setup.thesis_dataset(SEED)


@pytest.fixture(scope="module")
def table(recordings):
    result = calibrate(recordings, leave_one_out=False, with_table_7_5=True)
    position = np.array([row.position_rms_m for row in result.table_7_5]) / MM
    orientation = np.degrees([row.orientation_rms_rad for row in result.table_7_5])
    return position, orientation


# --- table 7.5 ----------------------------------------------------------------------------------

THESIS_POSITION = np.array([p for p, _ in thesis_setup.THESIS_TABLE_7_5])
THESIS_ORIENTATION = np.array([o for _, o in thesis_setup.THESIS_TABLE_7_5])


@pytest.mark.parametrize("line", range(2, 11))
def test_table_7_5_each_line_improves_line_1_by_the_thesis_fraction(table, line):
    """Position RMS of line `line` as a fraction of line 1 (no calibration), against the thesis's.

    Lines 2-6 (one method, or power bias + beacons): thesis 0.71-0.77, band +-0.10 (seen 0.68-0.85).
    Lines 7-10 (the rotation bias with another method, the global calibration): thesis 0.27-0.34, band
    +-0.15 (seen 0.19-0.48: the simulator's leftovers are white placement noise, the thesis's were not).
    """
    position, _ = table
    fraction = position[line - 1] / position[0]
    thesis = THESIS_POSITION[line - 1] / THESIS_POSITION[0]
    band = 0.10 if line <= 6 else 0.15
    assert abs(fraction - thesis) <= band, (line, fraction, thesis)
    # Every calibration also helps the orientation (table 7.5: 0.17-0.40 deg from 0.43 deg).
    _, orientation = table
    assert orientation[line - 1] < orientation[0]


def test_table_7_5_ordering_of_the_methods(table):
    """Section 7.3.6, with numbers.

    - Uncalibrated: thesis 8.75 mm, 0.43 deg; band 7-12 mm, 0.3-0.7 deg (seen 9.8-10.6 mm, 0.48-0.61).
    - A pair with the rotation bias (lines 7, 8) is less than half of any single method or of power
      bias + beacons (lines 2-6), band < 0.7: thesis 2.95 / 6.21 = 0.48 (0.58 for seed 3, 0.61 for seed 1).
    - Without the turret offset the rotation bias alone is a little worse (line 4 vs 3): thesis +0.9%,
      band 0-5% (seen 1-2.5%).
    - The global calibration beats every pair (line 11 < lines 7, 8), the final optimisation adds a gain
      (line 10 >= line 11: thesis 7.7%), and so does the turret offset (line 9 > line 11: thesis 13.3%,
      band 5-40%, seen 15-25%).
    - Line 11: thesis 2.16 mm, 0.18 deg; band +-25% and +-30% (seen 1.8-2.2 mm, 0.13-0.19 deg): the
      placement error is sized from it, so this checks that sizing, not the calibration.
    """
    position, orientation = table
    assert 7.0 < position[0] < 12.0 and 0.3 < orientation[0] < 0.7
    assert max(position[6], position[7]) < 0.7 * min(position[1:6])
    assert 0.0 <= position[3] / position[2] - 1.0 <= 0.05
    assert position[10] < min(position[6], position[7])
    assert position[9] >= position[10]
    assert 0.05 <= position[8] / position[10] - 1.0 <= 0.40
    assert abs(position[10] / THESIS_POSITION[10] - 1.0) <= 0.25
    assert abs(orientation[10] / THESIS_ORIENTATION[10] - 1.0) <= 0.30


# --- figure 7.7 ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rotation(recordings):
    """The rotation experiment at P_9 (24 orientations, eq. 7.23), corrected by the rotation bias and
    turret offset fitted alone on the 48 configurations (table 7.5, line 3: figure 7.9 and the
    (-1, -1.1) mm of section 7.3.3 come from that fit)."""
    problem = Problem.of(to_arrays(recordings))
    vector, _ = optimise_groups(problem, np.zeros(PARAMETER_COUNT), ["rotation", "turret"])
    line_3 = problem.model(vector)
    dataset = thesis_setup.thesis_dataset(
        SEED + 100,
        thesis_setup.rotation_experiment_poses(),
        placement_sigma=thesis_setup.ROTATION_PLACEMENT_SIGMA,
    )
    return thesis_figures.rotation_experiment(dataset, line_3), line_3


def test_figure_7_7_positions_scatter_then_gather_around_p9(rotation):
    """Figure 7.7: position RMS over the 24 poses, 1.8 mm before and 1.0 mm after (44% better).

    Before: the injected figure 7.12 bias and (-1, -1.1) mm offset make 2.55 mm at P_9 by geometry alone,
    so the band is 1.8-3.2 mm (seen 2.6-2.8). After: band 0.6-1.5 mm (seen 0.8-1.3). The improvement at
    least the thesis's 44% (seen 52-69%). The periodic scatter (distance from the positions' own mean)
    falls below 45% of its value (seen 19-37%): the circle of the turret (figure 7.8) and the rotation
    bias are what the correction removes; the constant error of the a-priori beacons stays.
    """
    experiment, _ = rotation
    before_mm, after_mm = (f.position_rms_m / MM for f in (experiment.before, experiment.after))
    thesis_before, thesis_after = thesis_setup.THESIS_ROTATION_EXPERIMENT_RMS_MM
    assert thesis_before <= before_mm <= 3.2
    assert 0.6 <= after_mm <= 1.5
    assert after_mm / before_mm <= thesis_after / thesis_before
    spread_before = experiment.position_spread_m(experiment.errors_before)
    spread_after = experiment.position_spread_m(experiment.errors_after)
    assert spread_after < 0.45 * spread_before
    # The computed positions describe a circle of the turret offset's radius (1.49 mm, figure 7.8),
    # widened by the rotation bias's first harmonic (2.18 mm noise-free).
    radius_mm = (
        thesis_figures.turret_circle_radius_m(experiment.orientations_rad, experiment.errors_before) / MM
    )
    assert 1.5 <= radius_mm <= 3.0


def test_figure_7_7_the_bearings_periodic_error_against_the_turret_angle(rotation):
    """Eq. 7.22: the bearing error at the true pose (the orientation eq. 7.9 gives from each beacon)
    against the turret angle. Its periodic part (harmonics 1-2, RMS) is what the thesis's figure 7.12
    function (0.117 deg RMS) and the turret offset give by geometry: 0.171 deg, band +-15% (seen
    0.167-0.181). After the line-3 correction at most 45% of it is left (seen 15-35%). The function fitted
    on the 48 configurations is the size of the thesis's figure 7.9 (0.098 deg RMS), band +-35% (seen
    0.103-0.126 deg).
    """
    experiment, line_3 = rotation
    geometric = thesis_setup.geometric_dataset(
        thesis_setup.rotation_experiment_poses(),
        correction=BearingCorrection(rotation_bias_coefficients=THESIS_ROTATION_BIAS_COEFFICIENTS),
        turret_offset_m=thesis_setup.THESIS_TURRET_OFFSET_M,
    )
    noise_free = thesis_figures.rotation_experiment(
        geometric, Model(thesis_setup.TRUE_BEACONS.xy, BearingCorrection(), (0.0, 0.0))
    )
    predicted = noise_free.bearing_harmonics_rad(noise_free.residuals_before)
    assert math.degrees(predicted) == pytest.approx(0.171, abs=0.005)
    before = experiment.bearing_harmonics_rad(experiment.residuals_before)
    after = experiment.bearing_harmonics_rad(experiment.residuals_after)
    assert abs(before / predicted - 1.0) <= 0.15
    assert after <= 0.45 * before
    fitted = _function_rms_rad(line_3.correction.rotation_bias_coefficients)
    assert abs(fitted / _function_rms_rad(FIGURE_7_9_COEFFICIENTS) - 1.0) <= 0.35


# --- figure 7.10 --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sensitivity_maps():
    beacons = thesis_figures.SECTION_6_4_1_BEACONS
    x, y = grid(thesis_figures.SECTION_6_4_1_AREA, 0.1)
    beacon_noise = thesis_figures.beacon_noise_maps(
        beacons, x, y, thesis_figures.FIGURE_7_10_BEACON_SIGMA_M, 400, np.random.default_rng(1)
    )
    angle_noise = monte_carlo_maps(
        beacons, x, y, thesis_figures.FIGURE_7_10_ANGLE_SIGMA_RAD, 400, np.random.default_rng(2)
    )
    equivalent = thesis_figures.equivalent_angle_maps(
        beacons, x, y, thesis_figures.FIGURE_7_10_BEACON_SIGMA_M
    )
    radius = np.hypot(x, y)
    nearest_beacon = np.min(np.hypot(x[..., None] - beacons[:, 0], y[..., None] - beacons[:, 1]), axis=-1)
    return beacon_noise, angle_noise, equivalent, radius, nearest_beacon


def test_figure_7_10_beacon_noise_is_an_equivalent_angle_noise(sensitivity_maps):
    """Section 7.3.4: "an error in one beacon position can be converted to an equivalent error on the
    measured angle", sigma_B / d_i. The Monte Carlo (1 cm, 400 draws per point, section 6.4.1's layout)
    agrees with that first-order prediction: median ratio 1 +-3%, 98% of the points within +-12% (400
    draws give a 3.5% sampling error), away from the critical circle and the beacons."""
    beacon_noise, _, equivalent, radius, nearest_beacon = sensitivity_maps
    regular = (np.abs(radius - 1.0) > 0.2) & (nearest_beacon > 0.2)
    for field in ("position_std_m", "heading_std_rad"):
        ratio = getattr(beacon_noise, field)[regular] / getattr(equivalent, field)[regular]
        assert abs(np.median(ratio) - 1.0) <= 0.03, field
        low, high = np.percentile(ratio, [1, 99])
        assert low >= 0.88 and high <= 1.12, (field, low, high)


def test_figure_7_10_both_maps_look_alike_near_the_critical_circle(sensitivity_maps):
    """Figure 7.10 compares histogram-equalised maps, i.e. their ranks: near the critical circle (within
    0.3 m of it) the beacon-noise map (sigma 1 cm) and the angle-noise map (sigma 0.1 deg) rank the points
    alike (Spearman >= 0.95; 0.99 seen), and less so elsewhere (>= 0.7; 0.82 seen): far from the beacons
    1/d_i shrinks the equivalent angle. At the circle's centre, 1 m from every beacon, 1 cm is 0.573 deg:
    the beacon map is 5.73 times the angle map (+-8%). A constant beacon error does not make a constant
    position error: its 5th-95th percentiles (0.2 m away from the beacons) differ by more than a factor 5
    (7 and 74 mm seen)."""
    beacon_noise, angle_noise, _, radius, nearest_beacon = sensitivity_maps
    away = nearest_beacon > 0.2
    near = (np.abs(radius - 1.0) < 0.3) & away
    correlation_near = spearmanr(
        beacon_noise.position_std_m[near], angle_noise.position_std_m[near]
    ).statistic
    correlation_all = spearmanr(beacon_noise.position_std_m[away], angle_noise.position_std_m[away]).statistic
    assert correlation_near >= 0.95
    assert correlation_all >= 0.7
    centre = np.unravel_index(np.argmin(radius), radius.shape)
    expected_ratio = thesis_figures.FIGURE_7_10_BEACON_SIGMA_M / thesis_figures.FIGURE_7_10_ANGLE_SIGMA_RAD
    ratio = beacon_noise.position_std_m[centre] / angle_noise.position_std_m[centre]
    assert abs(ratio / expected_ratio - 1.0) <= 0.08
    low, high = np.percentile(beacon_noise.position_std_m[away], [5, 95])
    assert high / low > 5.0


@pytest.mark.parametrize("beacon_index", range(3))
def test_figure_7_10_a_beacon_moved_by_1_and_2_cm_on_the_thesis_grid(beacon_index):
    """On the 48 configurations of section 7.3.1, moving one beacon by 1 cm gives the pose errors of
    the equivalent bearing errors delta_perp / d_i (the two fixes differ by at most 6% of the error's
    RMS; 1.5-5.7% seen), the errors are linear in the shift (2 cm gives 2.00 +-0.05 times the RMS of
    1 cm; 1.99-2.00 seen) and what differs is second order (4 +-0.5 times larger at 2 cm; 4.1-4.4)."""
    poses = thesis_setup.reference_poses()
    beacons = thesis_setup.TRUE_BEACONS.xy
    exact = expected_bearings(beacons, (poses[:, 0], poses[:, 1], poses[:, 2]))
    figures, differences = [], []
    for shift_m in (0.01, 0.02):
        delta = (shift_m * math.cos(0.7), shift_m * math.sin(0.7))
        moved = beacons.copy()
        moved[beacon_index] += delta
        by_beacon = _pose_errors(poses, triangulate_many(moved, exact))
        shifted = exact - thesis_figures.equivalent_bearing_shift_rad(beacons, poses, beacon_index, delta)
        by_angle = _pose_errors(poses, triangulate_many(beacons, shifted))
        figures.append(rms_figures("moved", by_beacon).position_rms_m)
        differences.append(np.sqrt(np.mean(np.sum((by_beacon[:, :2] - by_angle[:, :2]) ** 2, axis=1))))
    assert differences[0] <= 0.06 * figures[0]
    assert figures[1] / figures[0] == pytest.approx(2.0, abs=0.05)
    assert differences[1] / differences[0] == pytest.approx(4.0, abs=0.5)


def test_table_7_3_shifts_explain_the_beacon_calibrations_gain():
    """Table 7.3 moved the beacons by up to 4.5 mm; alone (noise-free), those shifts make 4.9 mm of
    position RMS over the 48 configurations. The beacon calibration alone (table 7.5, line 5) took
    8.75 mm to 6.78 mm: sqrt(8.75^2 - 6.78^2) = 5.5 mm removed, if independent; band +-20%."""
    poses = thesis_setup.reference_poses()
    arrays = to_arrays(thesis_setup.geometric_dataset(poses, prior_map=thesis_setup.PRIOR_BEACONS))
    errors = pose_errors(arrays, Model(arrays.beacons_xy, BearingCorrection(), (0.0, 0.0)))
    removed_mm = math.sqrt(THESIS_POSITION[0] ** 2 - THESIS_POSITION[4] ** 2)
    assert abs(rms_figures("table 7.3", errors).position_rms_m / MM / removed_mm - 1.0) <= 0.20


def _pose_errors(poses: np.ndarray, fixes) -> np.ndarray:
    assert np.all(fixes.ok)
    return np.column_stack(
        [fixes.x - poses[:, 0], fixes.y - poses[:, 1], np.asarray(wrap_to_pi(fixes.heading - poses[:, 2]))]
    )
