"""Algorithm 7.1 of the thesis: the global calibration of BeAMS from reference configurations.

Bearings corrected by the power (eq. 7.18, 7.19) and rotation (eq. 7.24, 7.25) biases give ToTal's poses
(eq. 7.8, 7.9, 7.26); err_RMS (eq. 7.12) is minimised group by group by least squares until
(e_b - e_r) / e_b < t, then on all parameters (eq. 7.29). Parameters are scaled to mm and mrad, the power
bias on windows normalised to [-1, 1]: raw windows' monomials differ by orders and stall the solver.
"""

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.polynomial import Polynomial
from scipy.optimize import least_squares

from beams_calibration.dataset import CalibrationArrays, Dataset, to_arrays
from beams_calibration.parameters import CALIBRATION_PARAMETERS
from beams_common.calibration.bearing_correction import BearingCorrection
from beams_common.calibration.calibration_file import RmsFigures, SensorCalibration, node_refusal
from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import BeaconMap
from beams_triangulation.total import triangulate_many

Progress = Callable[[str], None]

MM = 1e-3  # scaled unit of positions (m)
MRAD = 1e-3  # scaled unit of angles (rad)
GROUPS: dict[str, slice] = {
    "beacons": slice(0, 6),
    "power": slice(6, 10),
    "rotation": slice(10, 14),
    "turret": slice(14, 16),
}
PARAMETER_COUNT = 16
# A configuration ToTal cannot solve (critical circle) counts as this error (m) instead of NaN.
UNSOLVABLE_ERROR_M = 1.0

# err_RMS (m) below which Algorithm 7.1's loop stops whatever its relative criterion says.
NEGLIGIBLE_ERROR_M = 1e-6
DEFAULT_ETA_M_PER_RAD = CALIBRATION_PARAMETERS.default("eta_m_per_rad")
DEFAULT_THRESHOLD = CALIBRATION_PARAMETERS.default("threshold")
DEFAULT_MAX_ITERATIONS = CALIBRATION_PARAMETERS.default("max_iterations")


class CalibrationRefusedError(ValueError):
    """The dataset cannot support a calibration; the message says what is missing."""


@dataclass(frozen=True)
class CoverageRequirements:
    """What a dataset must cover before Algorithm 7.1 runs (section 7.3.6: windows, angles, positions)."""

    min_configurations: int = CALIBRATION_PARAMETERS.default("min_configurations")
    min_positions: int = 4
    min_window_span_rad: float = math.radians(1.0)
    angle_sectors: int = 8  # every sector of the turret circle needs a bearing


@dataclass(frozen=True)
class Plausibility:
    """Limits beyond which a fitted parameter is reported as implausible (section 7.3.6)."""

    max_beacon_shift_m: float = 0.02
    max_power_bias_rad: float = math.radians(3.0)
    max_rotation_bias_rad: float = math.radians(0.5)
    max_turret_offset_m: float = 0.01
    max_leave_one_out_ratio: float = 1.5


@dataclass(frozen=True)
class WindowScale:
    """Normalisation u = (w - centre) / half_span of the windows, for the power-bias parameters."""

    centre_rad: float
    half_span_rad: float

    @classmethod
    def of(cls, windows_rad: np.ndarray) -> "WindowScale":
        low, high = float(np.min(windows_rad)), float(np.max(windows_rad))
        return cls(0.5 * (low + high), max(0.5 * (high - low), 1e-6))

    @property
    def window_range_rad(self) -> tuple[float, float]:
        return (self.centre_rad - self.half_span_rad, self.centre_rad + self.half_span_rad)

    def to_window(self) -> Polynomial:
        """u as a polynomial of w."""
        return Polynomial([-self.centre_rad / self.half_span_rad, 1.0 / self.half_span_rad])


@dataclass(frozen=True)
class Model:
    """A point of the parameter space in physical units."""

    beacons_xy: np.ndarray
    correction: BearingCorrection
    turret_offset_m: tuple[float, float]


@dataclass(frozen=True)
class Problem:
    """The dataset arrays, the a-priori beacons and the scalings: maps scaled vectors to models.

    Both biases are linear in their coefficients: their bases at the dataset's windows and bearings are
    precomputed, so the objective costs one matrix product and one ToTal call.
    """

    arrays: CalibrationArrays
    scale: WindowScale
    eta_m_per_rad: float
    u_to_w: np.ndarray  # (4, 4): power-bias coefficients (a, b, c, d) of each unit u-monomial
    power_basis: np.ndarray  # (n, 3, 4): bias of each unit u-monomial at the dataset's windows (rad)
    rotation_basis: np.ndarray  # (n, 3, 4): bias of each unit Fourier coefficient at the bearings (rad)

    @classmethod
    def of(cls, arrays: CalibrationArrays, eta_m_per_rad: float = DEFAULT_ETA_M_PER_RAD) -> "Problem":
        scale = WindowScale.of(arrays.windows_rad)
        u_to_w = np.zeros((4, 4))
        for degree in range(4):
            in_w = Polynomial.basis(degree)(scale.to_window()).coef
            u_to_w[3 - degree :, degree] = in_w[::-1]  # highest power first, as (a, b, c, d)
        unit = np.eye(4)
        power_basis = np.stack(
            [BearingCorrection(tuple(u_to_w[:, k])).power_bias(arrays.windows_rad) for k in range(4)], axis=-1
        )
        rotation_basis = np.stack(
            [
                BearingCorrection(rotation_bias_coefficients=unit[k]).rotation_bias(arrays.bearings_rad)
                for k in range(4)
            ],
            axis=-1,
        )
        return cls(arrays, scale, eta_m_per_rad, u_to_w, power_basis, rotation_basis)

    def model(self, vector: np.ndarray) -> Model:
        """Physical parameters of a scaled vector (see the module docstring)."""
        beacons = self.arrays.beacons_xy + vector[GROUPS["beacons"]].reshape(3, 2) * MM
        power = vector[GROUPS["power"]] * MRAD
        correction = BearingCorrection(
            power_bias_coefficients=tuple(self.u_to_w @ power),
            rotation_bias_coefficients=tuple(vector[GROUPS["rotation"]] * MRAD),
            window_range_rad=self.scale.window_range_rad if np.any(power) else None,
        )
        offset = vector[GROUPS["turret"]] * MM
        return Model(beacons, correction, (float(offset[0]), float(offset[1])))

    def vector(self, model: Model) -> np.ndarray:
        """Scaled vector of a model (inverse of model())."""
        vector = np.zeros(PARAMETER_COUNT)
        vector[GROUPS["beacons"]] = ((model.beacons_xy - self.arrays.beacons_xy) / MM).ravel()
        power = np.linalg.solve(self.u_to_w, np.asarray(model.correction.power_bias_coefficients))
        vector[GROUPS["power"]] = power / MRAD
        vector[GROUPS["rotation"]] = np.asarray(model.correction.rotation_bias_coefficients) / MRAD
        vector[GROUPS["turret"]] = np.asarray(model.turret_offset_m) / MM
        return vector

    def errors(self, vector: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Pose errors (n, 3), as pose_errors(arrays, model(vector)) but from the precomputed bases."""
        bias = self.power_basis[rows] @ (vector[GROUPS["power"]] * MRAD) + self.rotation_basis[rows] @ (
            vector[GROUPS["rotation"]] * MRAD
        )
        beacons = self.arrays.beacons_xy + vector[GROUPS["beacons"]].reshape(3, 2) * MM
        offset = vector[GROUPS["turret"]] * MM
        return _errors(self.arrays.poses[rows], beacons, self.arrays.bearings_rad[rows] - bias, offset)

    def objective(self, vector: np.ndarray, rows: np.ndarray | slice = slice(None)) -> float:
        """err_RMS of eq. 7.12 (m)."""
        return configuration_rms(self.errors(vector, rows), self.eta_m_per_rad)


def pose_errors(
    arrays: CalibrationArrays, model: Model, rows: np.ndarray | slice = slice(None)
) -> np.ndarray:
    """Errors (n, 3) of a model's poses against the true poses (eq. 7.8-7.11; the heading from the three
    beacons where eq. 7.9 uses beacon 1: section 7.3.6 found no difference)."""
    corrected = model.correction.correct(arrays.bearings_rad[rows], arrays.windows_rad[rows])
    return _errors(arrays.poses[rows], model.beacons_xy, corrected, model.turret_offset_m)


def _errors(truth: np.ndarray, beacons_xy: np.ndarray, corrected: np.ndarray, offset_m) -> np.ndarray:
    fixes = triangulate_many(beacons_xy, corrected, offset_m)
    errors = np.column_stack(
        [truth[:, 0] - fixes.x, truth[:, 1] - fixes.y, np.asarray(wrap_to_pi(truth[:, 2] - fixes.heading))]
    )
    errors[~(fixes.ok & np.all(np.isfinite(errors), axis=1))] = UNSOLVABLE_ERROR_M
    return errors


def configuration_residuals(errors: np.ndarray, eta_m_per_rad: float) -> np.ndarray:
    """Each configuration's term of err_RMS (eq. 7.12): sqrt(dx^2 + dy^2 + (eta dtheta)^2) (m)."""
    return np.sqrt(errors[:, 0] ** 2 + errors[:, 1] ** 2 + (eta_m_per_rad * errors[:, 2]) ** 2)


def configuration_rms(errors: np.ndarray, eta_m_per_rad: float) -> float:
    """err_RMS, eq. 7.12."""
    return float(np.sqrt(np.mean(configuration_residuals(errors, eta_m_per_rad) ** 2)))


def rms_figures(stage: str, errors: np.ndarray) -> RmsFigures:
    """Position (eq. 7.10) and orientation (eq. 7.11) RMS errors."""
    position = float(np.sqrt(np.mean(errors[:, 0] ** 2 + errors[:, 1] ** 2)))
    orientation = float(np.sqrt(np.mean(errors[:, 2] ** 2)))
    return RmsFigures(stage, position, orientation)


# --- least squares on a group of parameters ---------------------------------------------------


def optimise_groups(
    problem: Problem, vector: np.ndarray, groups: Sequence[str], rows: np.ndarray | slice = slice(None)
) -> tuple[np.ndarray, float]:
    """Minimise err_RMS over the parameters of `groups`, the others fixed (eq. 7.20, 7.27, 7.28, 7.29).
    err_RMS^2 is a sum of squares (eq. 7.12): Levenberg-Marquardt (MINPACK) reaches the minimum that the
    thesis's Nelder-Mead simplex approaches, in twenty times fewer evaluations; never worse than `vector`."""
    indices = np.concatenate([np.arange(PARAMETER_COUNT)[GROUPS[g]] for g in groups])
    weights = np.array([1.0, 1.0, problem.eta_m_per_rad])

    def with_group(sub: np.ndarray) -> np.ndarray:
        trial = vector.copy()
        trial[indices] = sub
        return trial

    def residuals(sub: np.ndarray) -> np.ndarray:
        errors = problem.errors(with_group(sub), rows)
        return (errors * weights).ravel() / math.sqrt(len(errors))

    fitted = with_group(least_squares(residuals, vector[indices], method="lm").x)
    return min(((v, problem.objective(v, rows)) for v in (fitted, vector.copy())), key=lambda pair: pair[1])


# --- Algorithm 7.1 -----------------------------------------------------------------------------


@dataclass(frozen=True)
class CalibrationResult:
    """What Algorithm 7.1 found, how well, and what looks wrong."""

    beacon_map: BeaconMap
    correction: BearingCorrection
    turret_offset_m: tuple[float, float]
    stages: tuple[RmsFigures, ...]
    iterations: int
    errors_before: np.ndarray  # (n, 3) pose errors of each configuration, uncalibrated
    errors_after: np.ndarray  # (n, 3) after calibration
    poses: np.ndarray  # (n, 3) true poses
    windows_rad: np.ndarray  # (n, 3) windows (for the plots)
    bearings_rad: np.ndarray  # (n, 3) measured bearings (for the plots)
    leave_one_out: RmsFigures | None = None
    warnings: tuple[str, ...] = field(default=())
    table_7_5: tuple[RmsFigures, ...] = field(default=())  # empty unless asked for

    @property
    def before(self) -> RmsFigures:
        return self.stages[0]

    @property
    def after(self) -> RmsFigures:
        return self.stages[-1]

    def to_sensor_calibration(self) -> SensorCalibration:
        return SensorCalibration(
            beacon_map=self.beacon_map,
            bearing_correction=self.correction,
            turret_offset_m=self.turret_offset_m,
            rms=(*self.stages, *self.table_7_5),
            leave_one_out=self.leave_one_out,
            warnings=self.warnings,
            created_utc=SensorCalibration.now_utc(),
        )


def check_coverage(
    arrays: CalibrationArrays, requirements: CoverageRequirements = CoverageRequirements()
) -> None:
    """Refuse a dataset too small, or not covering the windows and turret angles (section 7.3.6)."""
    problems = []
    if arrays.count < requirements.min_configurations:
        problems.append(
            f"{arrays.count} usable configurations (all three beacons seen), "
            f"at least {requirements.min_configurations} needed"
        )
    positions = len(position_groups(arrays.poses))
    if positions < requirements.min_positions:
        problems.append(f"{positions} distinct positions, at least {requirements.min_positions} needed")
    if arrays.count:
        span = float(np.ptp(arrays.windows_rad))
        if span < requirements.min_window_span_rad:
            problems.append(
                f"angular windows span {math.degrees(span):.2f} deg, at least "
                f"{math.degrees(requirements.min_window_span_rad):.2f} deg needed: add positions nearer "
                "to and farther from the beacons"
            )
        sectors = np.floor(np.mod(arrays.bearings_rad, 2 * np.pi) / (2 * np.pi / requirements.angle_sectors))
        missing = requirements.angle_sectors - np.unique(sectors).size
        if missing > 0:
            problems.append(
                f"{missing} of {requirements.angle_sectors} turret-angle sectors have no bearing: "
                "add orientations"
            )
    if problems:
        raise CalibrationRefusedError("calibration refused: " + "; ".join(problems))


def position_groups(poses: np.ndarray, tolerance_m: float = 1e-3) -> list[np.ndarray]:
    """Row indices of the configurations sharing one reference position (to the millimetre)."""
    keys = np.round(poses[:, :2] / tolerance_m).astype(np.int64)
    _, labels = np.unique(keys, axis=0, return_inverse=True)
    labels = labels.ravel()
    return [np.flatnonzero(labels == label) for label in range(labels.max() + 1)] if labels.size else []


def _report(problem: Problem, vector: np.ndarray, stage: str, progress: Progress | None) -> RmsFigures:
    figures = rms_figures(stage, problem.errors(vector))
    if progress is not None:
        progress(
            f"{stage}: err_RMS {problem.objective(vector) / MM:.3f} mm "
            f"(position {figures.position_rms_m / MM:.3f} mm, "
            f"orientation {math.degrees(figures.orientation_rms_rad):.4f} deg)"
        )
    return figures


def run_algorithm_7_1(
    problem: Problem,
    *,
    threshold: float = DEFAULT_THRESHOLD,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    initial: np.ndarray | None = None,
    progress: Progress | None = None,
    with_turret: bool = True,
) -> tuple[np.ndarray, list[RmsFigures], int]:
    """Algorithm 7.1, steps 2-6 then 7: the scaled vector, each stage's RMS and the loop count.
    with_turret False keeps the turret offset at zero (table 7.5, line 9)."""
    rotation_groups = ["rotation", "turret"] if with_turret else ["rotation"]
    all_groups = [g for g in GROUPS if with_turret or g != "turret"]
    vector = np.zeros(PARAMETER_COUNT) if initial is None else initial.copy()
    stages = [_report(problem, vector, "no calibration", progress)]
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        vector, e_b = optimise_groups(problem, vector, ["beacons"])
        stages.append(_report(problem, vector, f"iteration {iterations}: beacons", progress))
        vector, _ = optimise_groups(problem, vector, ["power"])
        stages.append(_report(problem, vector, f"iteration {iterations}: power bias", progress))
        vector, e_r = optimise_groups(problem, vector, rotation_groups)
        stages.append(_report(problem, vector, f"iteration {iterations}: rotation bias and turret", progress))
        # Step 6; an error already below a micrometre leaves nothing to iterate on.
        if e_r < NEGLIGIBLE_ERROR_M or (e_b - e_r) / e_b < threshold:
            break
    vector, _ = optimise_groups(problem, vector, all_groups)
    stages.append(_report(problem, vector, "global optimisation", progress))
    return vector, stages, iterations


# Table 7.5, lines 2-8: each method, and pairs of them, fitted alone from zero (the rotation-bias
# method includes the turret offset, except on line 4).
TABLE_7_5_SUBSETS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("power bias only", ("power",)),
    ("rotation bias only", ("rotation", "turret")),
    ("rotation bias only, no turret offset", ("rotation",)),
    ("beacons only", ("beacons",)),
    ("power bias + beacons", ("power", "beacons")),
    ("power bias + rotation bias", ("power", "rotation", "turret")),
    ("rotation bias + beacons", ("rotation", "turret", "beacons")),
)


# Table 7.5: position RMS (mm) and orientation RMS (deg) of lines 1-11 in the thesis's experiment.
THESIS_TABLE_7_5 = tuple(
    zip(
        (8.75, 6.67, 6.21, 6.27, 6.78, 6.40, 2.95, 2.79, 2.49, 2.34, 2.16),
        (0.4297, 0.3316, 0.3157, 0.3175, 0.3984, 0.3345, 0.1741, 0.2715, 0.1788, 0.1756, 0.1806),
        strict=True,
    )
)


def table_7_5(
    problem: Problem,
    stages: Sequence[RmsFigures],
    *,
    threshold: float = DEFAULT_THRESHOLD,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    progress: Progress | None = None,
) -> list[RmsFigures]:
    """The eleven lines of table 7.5 for this dataset; `stages` are those of the full Algorithm 7.1."""

    def line_of(number: int, label: str, figures: RmsFigures) -> RmsFigures:
        name = f"table 7.5 line {number}: {label}"
        return RmsFigures(name, figures.position_rms_m, figures.orientation_rms_rad)

    rows = [line_of(1, stages[0].stage, stages[0])]
    for line, (label, groups) in enumerate(TABLE_7_5_SUBSETS, start=2):
        vector, _ = optimise_groups(problem, np.zeros(PARAMETER_COUNT), groups)
        rows.append(_report(problem, vector, f"table 7.5 line {line}: {label}", progress))
    _, no_turret, _ = run_algorithm_7_1(
        problem, threshold=threshold, max_iterations=max_iterations, with_turret=False
    )
    return [
        *rows,
        line_of(9, "global calibration, no turret offset", no_turret[-1]),
        line_of(10, "global calibration, no final optimisation", stages[-2]),
        line_of(11, "global calibration", stages[-1]),
    ]


def leave_one_position_out(
    problem: Problem,
    fitted: np.ndarray,
    progress: Progress | None = None,
) -> RmsFigures:
    """RMS error of each reference position left out of a refit (step 7, from the full fit)."""
    groups = position_groups(problem.arrays.poses)
    held_out = np.zeros((problem.arrays.count, 3))
    for number, rows in enumerate(groups, start=1):
        training = np.setdiff1d(np.arange(problem.arrays.count), rows)
        vector, _ = optimise_groups(problem, fitted, list(GROUPS), rows=training)
        held_out[rows] = problem.errors(vector, rows)
        if progress is not None:
            progress(f"leave-one-position-out: fold {number}/{len(groups)}")
    return rms_figures("leave one position out", held_out)


# A blunder's residual (eq. 7.12's term) against the others' fit exceeds BLUNDER_RATIO medians: 5.4 sigma of
# a chi(3) residual, by chance once in 5000 datasets of 48 (the thesis's grid reaches 2.8). More than
# MAX_BLUNDER_FRACTION say the map or the grid is wrong; BLUNDER_FLOOR_M is section 7.3.1's "about 2 mm".
CANDIDATE_RATIO = 3.0
BLUNDER_RATIO = 3.5
BLUNDER_FLOOR_M = 2e-3
MAX_BLUNDER_FRACTION = 0.1


def exclude_blunders(problem: Problem, fitted: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """The rows to keep and a warning per blunder excluded: the worst beyond CANDIDATE_RATIO medians is
    refitted without (step 7) and excluded when it still is (CalibrationRefusedError past the fraction)."""
    keep = np.arange(problem.arrays.count)
    warnings: list[str] = []

    def residuals(vector: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return configuration_residuals(problem.errors(vector, rows), problem.eta_m_per_rad)

    while True:
        after_fit = residuals(fitted, keep)
        worst = int(np.argmax(after_fit))
        if after_fit[worst] <= max(CANDIDATE_RATIO * np.median(after_fit), BLUNDER_FLOOR_M):
            return keep, warnings
        others = np.delete(keep, worst)
        # from the fit, or from no calibration when the blunder has dragged the fit farther off
        start = min((fitted, np.zeros(PARAMETER_COUNT)), key=lambda v: problem.objective(v, others))
        refitted, _ = optimise_groups(problem, start, list(GROUPS), rows=others)
        scale = float(np.median(residuals(refitted, others)))
        predicted = float(residuals(refitted, keep[worst : worst + 1])[0])
        if predicted <= max(BLUNDER_RATIO * scale, BLUNDER_FLOOR_M):
            return keep, warnings
        warnings.append(
            f"{problem.arrays.names[keep[worst]]} excluded as a blunder: {predicted / MM:.1f} mm (eq. 7.12) "
            f"from the pose the other configurations' calibration gives, {predicted / scale:.1f} times their "
            f"median {scale / MM:.2f} mm: check its pose and that the robot stood still"
        )
        keep, fitted = others, refitted
        if len(warnings) > MAX_BLUNDER_FRACTION * problem.arrays.count:
            raise CalibrationRefusedError(
                f"calibration refused: {len(warnings)} of {problem.arrays.count} configurations disagree "
                f"with the others ({'; '.join(warnings)}): check the a-priori map and the reference poses"
            )


def plausibility_warnings(
    problem: Problem,
    result_model: Model,
    fitted: RmsFigures,
    leave_one_out: RmsFigures | None,
    limits: Plausibility = Plausibility(),
) -> list[str]:
    """Section 7.3.6: beacons close to the manual measurements, a few degrees of power bias at most,
    a few tenths of a degree of rotation bias, and a generalisation error close to the fitted one."""
    warnings = []
    shifts = np.hypot(*(result_model.beacons_xy - problem.arrays.beacons_xy).T)
    for beacon_id, shift in zip(problem.arrays.beacon_ids, shifts, strict=True):
        if shift > limits.max_beacon_shift_m:
            warnings.append(
                f"beacon {beacon_id} moved by {shift * 1e3:.1f} mm from its measured position "
                f"(more than {limits.max_beacon_shift_m * 1e3:.0f} mm): check the map or the dataset"
            )
    windows = np.linspace(*problem.scale.window_range_rad, 50)
    power = float(np.max(np.abs(result_model.correction.power_bias(windows))))
    if power > limits.max_power_bias_rad:
        warnings.append(
            f"power bias reaches {math.degrees(power):.2f} deg (more than "
            f"{math.degrees(limits.max_power_bias_rad):.1f} deg)"
        )
    rotation = float(np.max(np.abs(result_model.correction.rotation_bias(np.linspace(-np.pi, np.pi, 360)))))
    if rotation > limits.max_rotation_bias_rad:
        warnings.append(
            f"rotation bias reaches {math.degrees(rotation):.2f} deg (more than "
            f"{math.degrees(limits.max_rotation_bias_rad):.1f} deg)"
        )
    offset = math.hypot(*result_model.turret_offset_m)
    if offset > limits.max_turret_offset_m:
        warnings.append(f"turret offset {offset * 1e3:.1f} mm from the robot centre is implausibly large")
    if leave_one_out is not None and (
        leave_one_out.position_rms_m > limits.max_leave_one_out_ratio * fitted.position_rms_m
    ):
        warnings.append(
            f"leave-one-position-out position error {leave_one_out.position_rms_m * 1e3:.2f} mm exceeds "
            f"{limits.max_leave_one_out_ratio}x the fitted {fitted.position_rms_m * 1e3:.2f} mm: "
            "over-fitting, record more configurations"
        )
    return warnings


def calibrate(
    dataset: Dataset,
    *,
    eta_m_per_rad: float = DEFAULT_ETA_M_PER_RAD,
    threshold: float = DEFAULT_THRESHOLD,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    leave_one_out: bool = True,
    with_table_7_5: bool = False,
    requirements: CoverageRequirements = CoverageRequirements(),
    limits: Plausibility = Plausibility(),
    beacon_ids: Sequence[int] | None = None,
    progress: Progress | None = None,
) -> CalibrationResult:
    """The whole calibration of a dataset: coverage check, Algorithm 7.1, blunders excluded (and Algorithm
    7.1 again without them), leave-one-out, warnings; CalibrationRefusedError for a dataset that cannot
    support one, or a result a node would refuse (`calibration_file.node_refusal`)."""
    arrays = to_arrays(dataset, beacon_ids)
    check_coverage(arrays, requirements)
    problem = Problem.of(arrays, eta_m_per_rad)

    def algorithm_7_1(problem: Problem) -> tuple[np.ndarray, list[RmsFigures], int]:
        return run_algorithm_7_1(
            problem, threshold=threshold, max_iterations=max_iterations, progress=progress
        )

    vector, stages, iterations = algorithm_7_1(problem)
    keep, blunders = exclude_blunders(problem, vector)
    if blunders:  # Algorithm 7.1 again, from no calibration, on the configurations kept
        for warning in blunders:
            if progress is not None:
                progress(f"warning: {warning}")
        arrays = arrays.subset(keep)
        check_coverage(arrays, requirements)
        problem = Problem.of(arrays, eta_m_per_rad)
        vector, stages, iterations = algorithm_7_1(problem)
    model = problem.model(vector)
    table = []
    if with_table_7_5:
        table = table_7_5(
            problem,
            stages,
            threshold=threshold,
            max_iterations=max_iterations,
            progress=progress,
        )
    generalisation = leave_one_position_out(problem, vector, progress) if leave_one_out else None
    if generalisation is not None and progress is not None:
        progress(
            f"leave-one-position-out: position {generalisation.position_rms_m / MM:.3f} mm, "
            f"orientation {math.degrees(generalisation.orientation_rms_rad):.4f} deg"
        )
    warnings = plausibility_warnings(problem, model, stages[-1], generalisation, limits)
    for warning in warnings:
        if progress is not None:
            progress(f"warning: {warning}")
    beacon_map = _updated_map(dataset.beacon_map, arrays.beacon_ids, model.beacons_xy)
    result = CalibrationResult(
        beacon_map=beacon_map,
        correction=model.correction,
        turret_offset_m=model.turret_offset_m,
        stages=tuple(stages),
        iterations=iterations,
        errors_before=problem.errors(np.zeros(PARAMETER_COUNT)),
        errors_after=problem.errors(vector),
        poses=arrays.poses,
        windows_rad=arrays.windows_rad,
        bearings_rad=arrays.bearings_rad,
        leave_one_out=generalisation,
        warnings=(*blunders, *warnings),
        table_7_5=tuple(table),
    )
    # the nodes start from the dataset's a-priori map and no turret offset, as Algorithm 7.1 does
    refusal = node_refusal(result.to_sensor_calibration(), dataset.beacon_map, (0.0, 0.0))
    if refusal:
        raise CalibrationRefusedError(f"calibration refused, a node would refuse its file: {refusal}")
    return result


def _updated_map(prior: BeaconMap, ids: Sequence[int], fitted_xy: np.ndarray) -> BeaconMap:
    """The a-priori map with the calibrated beacons moved to their fitted coordinates."""
    xy = prior.xy.copy()
    for beacon_id, position in zip(ids, fitted_xy, strict=True):
        xy[prior.ids.index(beacon_id)] = position
    return BeaconMap.from_lists(prior.ids, xy[:, 0], xy[:, 1])
