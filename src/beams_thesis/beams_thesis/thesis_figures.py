"""Two figures of chapter 7 as numbers: the rotation experiment (figure 7.7, section 7.3.3: 24 orientations at
P_9, eq. 7.23, before and after fitting {A, B, C, D, dx, dy} of eq. 7.27) and the sensitivity of the position
to the beacon coordinates (figure 7.10, section 7.3.4: beacon noise of 1 cm looks like bearing noise of 0.1
deg, since moving beacon i by delta turns its bearing by delta_perp / d_i)."""

from dataclasses import dataclass

import numpy as np

from beams_calibration.calibrate import PARAMETER_COUNT, Model, Problem, optimise_groups, rms_figures
from beams_calibration.dataset import CalibrationArrays, Dataset, to_arrays
from beams_common.calibration.calibration_file import RmsFigures
from beams_common.geometry.angles import wrap_to_pi
from beams_triangulation.error_map import ErrorMaps
from beams_triangulation.pose_covariance import distance_error_std_m, pose_covariance_many
from beams_triangulation.total import expected_bearings, triangulate_many

# Section 6.4.1: a regular triangle of beacons 1 m from the origin, a 4 m x 4 m grid, heading 0.
SECTION_6_4_1_BEACONS = np.array([(0.0, 1.0), (-0.866, -0.5), (0.866, -0.5)])
SECTION_6_4_1_AREA = (-2.0, 2.0, -2.0, 2.0)
# Figure 7.10: beacon coordinates with sigma = 1 cm (left), bearings with sigma = 0.1 deg (right).
FIGURE_7_10_BEACON_SIGMA_M = 0.01
FIGURE_7_10_ANGLE_SIGMA_RAD = float(np.radians(0.1))
# Rows of ToTal per vectorised call in the Monte Carlo (bounded memory).
_ROWS_PER_CALL = 400_000


# --- figure 7.7 --------------------------------------------------------------------------------


def periodic_amplitudes(angles_rad: np.ndarray, values: np.ndarray, harmonics: int = 2) -> np.ndarray:
    """Amplitudes sqrt(a_k^2 + b_k^2), k = 1..harmonics, of the least-squares Fourier fit
    c + sum_k a_k cos(k angle) + b_k sin(k angle) of values sampled at angles (the form of eq. 7.25)."""
    columns = [np.ones_like(angles_rad)]
    for k in range(1, harmonics + 1):
        columns += [np.cos(k * angles_rad), np.sin(k * angles_rad)]
    coefficients, *_ = np.linalg.lstsq(np.column_stack(columns), values, rcond=None)
    return np.hypot(coefficients[1::2], coefficients[2::2])


def turret_circle_radius_m(orientations_rad: np.ndarray, errors: np.ndarray) -> float:
    """Radius of the circle the computed positions describe as the robot turns (figure 7.8): the first
    harmonic (dx + i dy) e^{i theta} of the turret centre p + R(theta) (dx, dy) (eq. 7.26)."""
    offsets = -(errors[:, 0] + 1j * errors[:, 1])  # error = truth - estimate
    basis = np.column_stack([np.ones_like(orientations_rad), np.exp(1j * orientations_rad)])
    coefficients, *_ = np.linalg.lstsq(basis.astype(complex), offsets, rcond=None)
    return float(abs(coefficients[1]))


@dataclass(frozen=True)
class RotationExperiment:
    """The rotation experiment (figure 7.7) of one dataset, before and after the correction."""

    orientations_rad: np.ndarray  # (n,) true robot orientations
    errors_before: np.ndarray  # (n, 3) pose errors, a-priori map, no correction (eq. 7.10, 7.11)
    errors_after: np.ndarray  # (n, 3) with the rotation bias and turret offset of `model`
    model: Model  # the correction: A, B, C, D and (dx, dy) only (eq. 7.27)
    turret_angles_rad: np.ndarray  # (n, 3) measured bearings
    residuals_before: np.ndarray  # (n, 3) bearing errors against the true pose, uncorrected (rad)
    residuals_after: np.ndarray  # (n, 3) the same with the corrected bearings and the model's offset

    @property
    def before(self) -> RmsFigures:
        return rms_figures("rotation experiment, before", self.errors_before)

    @property
    def after(self) -> RmsFigures:
        return rms_figures("rotation experiment, after", self.errors_after)

    def bearing_harmonics_rad(self, residuals: np.ndarray) -> float:
        """RMS of the periodic part (harmonics 1 and 2, eq. 7.25) of bearing residuals (n, 3) against
        the turret angle, each beacon with its own constant (its power bias at this position)."""
        squares = [
            np.sum(periodic_amplitudes(self.turret_angles_rad[:, i], residuals[:, i]) ** 2) / 2.0
            for i in range(residuals.shape[1])
        ]
        return float(np.sqrt(np.mean(squares)))

    def position_spread_m(self, errors: np.ndarray) -> float:
        """RMS distance of the computed positions from their own mean: the scatter of figure 7.7."""
        centred = errors[:, :2] - errors[:, :2].mean(axis=0)
        return float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))


def rotation_experiment(dataset: Dataset, model: Model | None = None) -> RotationExperiment:
    """Figure 7.7 for a dataset of one position at several orientations: model None fits {A, B, C, D, dx, dy}
    on the dataset by minimising err_RMS (eq. 7.27, a-priori beacons, no power bias), as section 7.3.3 does.
    """
    arrays = to_arrays(dataset)
    problem = Problem.of(arrays)
    start = np.zeros(PARAMETER_COUNT)
    if model is None:
        vector, _ = optimise_groups(problem, start, ["rotation", "turret"])
    else:
        vector = problem.vector(model)
    fitted = problem.model(vector)
    return RotationExperiment(
        orientations_rad=arrays.poses[:, 2].copy(),
        errors_before=problem.errors(start),
        errors_after=problem.errors(vector),
        model=fitted,
        turret_angles_rad=arrays.bearings_rad.copy(),
        residuals_before=bearing_residuals(arrays, problem.model(start)),
        residuals_after=bearing_residuals(arrays, fitted),
    )


def bearing_residuals(arrays: CalibrationArrays, model: Model) -> np.ndarray:
    """(n, 3) corrected bearing minus the bearing the true pose gives with the model's beacons and
    turret offset: the error of the orientation eq. 7.9 computes from each beacon at the true position
    (section 7.3.3, eq. 7.22: what the turret's rotation does to the measured angles)."""
    corrected = model.correction.correct(arrays.bearings_rad, arrays.windows_rad)
    poses = arrays.poses
    expected = expected_bearings(
        model.beacons_xy, (poses[:, 0], poses[:, 1], poses[:, 2]), model.turret_offset_m
    )
    return np.asarray(wrap_to_pi(corrected - expected))


# --- figure 7.10 -------------------------------------------------------------------------------


def _map_points(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return x.ravel(), y.ravel(), np.zeros(x.size)


def beacon_noise_maps(
    beacons_xy: np.ndarray, x: np.ndarray, y: np.ndarray, sigma_m: float, draws: int, rng: np.random.Generator
) -> ErrorMaps:
    """Figure 7.10, left: exact bearings, beacon coordinates given to ToTal with Gaussian noise sigma_m
    on each coordinate; standard deviations of the position (eq. 6.25) and orientation (eq. 6.26)
    errors over `draws` maps per point, heading 0 as in section 6.4.1. The last field is the mean 1/|D|."""
    beacons = np.asarray(beacons_xy, dtype=float)
    px, py, heading = _map_points(x, y)
    exact = expected_bearings(beacons, (px, py, heading))
    position_std, heading_std, inverse_d = (np.empty(px.size) for _ in range(3))
    per_call = max(1, _ROWS_PER_CALL // draws)
    for start in range(0, px.size, per_call):
        rows = slice(start, start + per_call)
        count = exact[rows].shape[0]
        noisy_maps = beacons + rng.normal(0.0, sigma_m, (count, draws, 3, 2))
        bearings = np.broadcast_to(exact[rows, None, :], (count, draws, 3)).reshape(-1, 3)
        fixes = triangulate_many(noisy_maps.reshape(-1, 3, 2), bearings)
        distance = np.hypot(
            fixes.x.reshape(count, draws) - px[rows, None], fixes.y.reshape(count, draws) - py[rows, None]
        )
        position_std[rows] = distance.std(axis=1)
        heading_std[rows] = np.asarray(wrap_to_pi(fixes.heading.reshape(count, draws))).std(axis=1)
        inverse_d[rows] = fixes.inverse_abs_d.reshape(count, draws).mean(axis=1)
    return ErrorMaps(x, y, *(v.reshape(x.shape) for v in (position_std, heading_std, inverse_d)))


def equivalent_angle_sigma_rad(
    beacons_xy: np.ndarray, x: np.ndarray, y: np.ndarray, sigma_m: float
) -> np.ndarray:
    """(n, 3) standard deviation of the bearing error equivalent to beacon noise sigma_m: moving beacon
    i by delta turns its bearing by delta_perp / d_i (section 7.3.4: "an error in one beacon position can
    be converted to an equivalent error on the measured angle")."""
    beacons = np.asarray(beacons_xy, dtype=float)
    points = np.column_stack([x.ravel(), y.ravel()])
    distances = np.linalg.norm(beacons[None, :, :] - points[:, None, :], axis=2)
    return sigma_m / distances


def equivalent_bearing_shift_rad(
    beacons_xy: np.ndarray, positions: np.ndarray, beacon_index: int, delta_m: tuple[float, float]
) -> np.ndarray:
    """(n, 3) bearing changes, to first order, when beacon `beacon_index` moves by delta_m: the
    component of delta perpendicular to the line of sight over the distance (section 7.3.4)."""
    beacon = np.asarray(beacons_xy, dtype=float)[beacon_index]
    sight = beacon - np.asarray(positions, dtype=float)[:, :2]
    distance2 = np.sum(sight**2, axis=1)
    shift = np.zeros((len(sight), 3))
    shift[:, beacon_index] = (sight[:, 0] * delta_m[1] - sight[:, 1] * delta_m[0]) / distance2
    return shift


def equivalent_angle_maps(beacons_xy: np.ndarray, x: np.ndarray, y: np.ndarray, sigma_m: float) -> ErrorMaps:
    """Figure 7.10, left, to first order without drawing: the bearing covariance propagation of
    appendix B.3 (`pose_covariance_many`) with each bearing's variance (sigma_m / d_i)^2."""
    px, py, heading = _map_points(x, y)
    sigma = equivalent_angle_sigma_rad(beacons_xy, x, y, sigma_m)
    covariance = pose_covariance_many(beacons_xy, (px, py, heading), sigma**2)
    fixes = triangulate_many(beacons_xy, expected_bearings(beacons_xy, (px, py, heading)))
    position_std, heading_std = np.asarray(distance_error_std_m(covariance)), np.sqrt(covariance[:, 2, 2])
    return ErrorMaps(x, y, *(v.reshape(x.shape) for v in (position_std, heading_std, fixes.inverse_abs_d)))
