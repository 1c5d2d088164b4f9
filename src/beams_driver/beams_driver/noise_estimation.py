"""A sensor's natural variance from a still robot's bearings, and a check of the published variances (thesis
sections 5.5-5.8): a bearing's variance is the code's artificial variance at its window (chapter 4,
`variance.VarianceModel`) plus the receiver edges' natural variance, which is what the bearings' observed
spread leaves once the code's exact variance is taken away; on the thesis's hardware it grows with the window
(fig. 5.3). `beacon_spread` measures one beacon from one still pose, `fit_natural_variance` fits the natural
variance, `variance_check` holds a model's variance to the spread."""

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from beams_common.geometry.angles import wrap_to_pi
from beams_driver.variance import VarianceModel

DEG = math.radians(1.0)
# Published / actual variance ratios a filter tolerates (NEES within 25%).
TOLERATED_RATIO = (0.8, 1.25)
CONFIDENCE = 0.95
# A still robot's bearings: std at most 0.3 deg (calibration_node's max_spread_deg), and the means of
# the recording's two halves within 0.1 deg (the standard error of that difference is ~0.005 deg).
MAX_STD_RAD = 0.3 * DEG
MAX_DRIFT_RAD = 0.1 * DEG
MIN_SAMPLES = 50
# |slope| / its standard error beyond which the natural variance is taken as linear in the window.
SLOPE_Z_THRESHOLD = 3.0
# The driver parameters the fit sets (parameters.py).
NATURAL_VARIANCE = "natural_variance_rad2"
NATURAL_SLOPE = "natural_variance_slope_rad2_per_rad"
NATURAL_REFERENCE_WINDOW = "natural_variance_reference_window_rad"


class NoiseEstimationError(ValueError):
    """A recording the estimation cannot use; the message is the one-line reason."""


@dataclass(frozen=True)
class StaticRecording:
    """One beacon's bearings from one still pose: bearing (rad), published variance (rad^2), angular window
    (rad) of each revolution that decoded it, in time order."""

    label: str
    beacon_id: int
    bearings_rad: np.ndarray
    published_variances_rad2: np.ndarray
    windows_rad: np.ndarray


@dataclass(frozen=True)
class BeaconSpread:
    """What one StaticRecording shows: sample variance (ddof 1), mean window, mean published variance."""

    label: str
    beacon_id: int
    samples: int
    mean_window_rad: float
    observed_variance_rad2: float
    mean_published_variance_rad2: float
    drift_rad: float
    windows_rad: np.ndarray

    @property
    def variance_standard_error_rad2(self) -> float:
        """Standard error of the sample variance, sqrt(2 / (n - 1)) s^2 (Gaussian bearings)."""
        return self.observed_variance_rad2 * math.sqrt(2.0 / (self.samples - 1))


@dataclass(frozen=True)
class VarianceCheck:
    """s^2 / mean predicted variance, its confidence band, and the verdict against TOLERATED_RATIO."""

    ratio: float
    band: tuple[float, float]

    @property
    def verdict(self) -> str:
        """'ok' when the band reaches into the tolerated ratios, else which way the model is wrong."""
        if self.band[0] > TOLERATED_RATIO[1]:
            return "understated"
        if self.band[1] < TOLERATED_RATIO[0]:
            return "overstated"
        return "ok"


@dataclass(frozen=True)
class NaturalVarianceFit:
    """The natural variance (rad^2) at the reference window and its slope in the window (rad^2/rad)."""

    natural_variance_rad2: float
    slope_rad2_per_rad: float
    reference_window_rad: float
    natural_standard_error_rad2: float
    slope_standard_error: float
    # |slope| / standard error of the linear fit (0 with fewer than three windows)
    slope_z: float
    window_dependent: bool
    # per (pose, beacon): s^2 - the code's exact variance at the mean window
    estimates_rad2: np.ndarray
    estimate_errors_rad2: np.ndarray
    windows_rad: np.ndarray

    def at(self, window_rad: np.ndarray | float) -> np.ndarray | float:
        """The fitted natural variance at angular window(s) (rad), as VarianceModel evaluates it."""
        return VarianceModel((), "constant", **self.parameters()).natural_variance(window_rad)

    def parameters(self) -> dict[str, float]:
        """The fit as the driver's parameters (and VarianceModel's arguments) of the same names."""
        return {
            NATURAL_VARIANCE: self.natural_variance_rad2,
            NATURAL_SLOPE: self.slope_rad2_per_rad,
            NATURAL_REFERENCE_WINDOW: self.reference_window_rad,
        }


def recordings_from_bearings(
    label: str, bearings: Sequence[tuple[int, float, float, float]], min_samples: int = MIN_SAMPLES
) -> list[StaticRecording]:
    """Per beacon of min_samples bearings or more, from (beacon id, bearing, published variance, window) in
    time order; NoiseEstimationError when none is left or the windows are all 0 (not published)."""
    if not bearings:
        raise NoiseEstimationError(f"{label}: no bearings")
    rows = np.asarray(bearings, dtype=float)
    if not np.all(np.isfinite(rows)):
        raise NoiseEstimationError(f"{label}: non-finite bearing, variance or window")
    recordings = []
    for beacon_id in np.unique(rows[:, 0]).astype(int):
        mine = rows[rows[:, 0] == beacon_id]
        if len(mine) < min_samples:
            continue
        if not np.all(mine[:, 3] > 0.0):
            raise NoiseEstimationError(f"{label}: beacon {beacon_id}: bearings without an angular window")
        recordings.append(StaticRecording(label, int(beacon_id), mine[:, 1], mine[:, 2], mine[:, 3]))
    if not recordings:
        counts = {int(k): int(np.sum(rows[:, 0] == k)) for k in np.unique(rows[:, 0])}
        raise NoiseEstimationError(
            f"{label}: no beacon with {min_samples} bearings (got {counts}); record longer"
        )
    return recordings


def beacon_spread(
    recording: StaticRecording, max_std_rad: float = MAX_STD_RAD, max_drift_rad: float = MAX_DRIFT_RAD
) -> BeaconSpread:
    """The spread of one beacon's bearings from a still pose; NoiseEstimationError when the robot moved."""
    n = recording.bearings_rad.size
    if n < 3:
        raise NoiseEstimationError(f"{recording.label}: beacon {recording.beacon_id}: {n} bearings")
    # deviations from the circular mean: a beacon behind the robot stays one cluster across +-pi
    centre = math.atan2(np.mean(np.sin(recording.bearings_rad)), np.mean(np.cos(recording.bearings_rad)))
    deviations = np.asarray(wrap_to_pi(recording.bearings_rad - centre))
    variance = float(np.var(deviations, ddof=1))
    half = n // 2
    drift = float(np.mean(deviations[half:]) - np.mean(deviations[:half]))
    where = f"{recording.label}: beacon {recording.beacon_id}"
    if math.sqrt(variance) > max_std_rad:
        raise NoiseEstimationError(
            f"{where}: bearings spread by {math.degrees(math.sqrt(variance)):.3f} deg (std, limit "
            f"{math.degrees(max_std_rad):.3f}): the robot moved; record a still robot"
        )
    if abs(drift) > max_drift_rad:
        raise NoiseEstimationError(
            f"{where}: bearings drifted by {math.degrees(drift):.3f} deg between the recording's halves "
            f"(limit {math.degrees(max_drift_rad):.3f}): the robot moved; record a still robot"
        )
    return BeaconSpread(
        label=recording.label,
        beacon_id=recording.beacon_id,
        samples=n,
        mean_window_rad=float(np.mean(recording.windows_rad)),
        observed_variance_rad2=variance,
        mean_published_variance_rad2=float(np.mean(recording.published_variances_rad2)),
        drift_rad=drift,
        windows_rad=recording.windows_rad,
    )


def variance_check(
    spread: BeaconSpread, predicted_variance_rad2: float, confidence: float = CONFIDENCE
) -> VarianceCheck:
    """s^2 / predicted, and its band: (n - 1) s^2 / sigma^2 ~ chi2(n - 1) bounds sigma^2 / predicted."""
    dof = spread.samples - 1
    ratio = spread.observed_variance_rad2 / predicted_variance_rad2
    tail = 0.5 * (1.0 - confidence)
    low, high = stats.chi2.ppf([1.0 - tail, tail], dof)
    return VarianceCheck(ratio, (float(ratio * dof / low), float(ratio * dof / high)))


def fit_natural_variance(
    spreads: Sequence[BeaconSpread],
    model: VarianceModel,
    slope_z_threshold: float = SLOPE_Z_THRESHOLD,
) -> NaturalVarianceFit:
    """Natural variance, constant or linear in the window (thesis sections 5.5-5.8), from still spreads:
    natural_g = s_g^2 - sigma_exact^2(code, window_g), standard error sqrt(2 / (n_g - 1)) s_g^2, by weighted
    least squares (errors scaled by sqrt(chi2 / dof) when they scatter more); the slope kept when its z
    reaches slope_z_threshold over three windows or more, else the mean; a negative one reported as 0."""
    if not spreads:
        raise NoiseEstimationError("no beacon to estimate the noise from")
    windows = np.array([s.mean_window_rad for s in spreads])
    estimates = np.array(
        [
            s.observed_variance_rad2 - float(model.artificial_variance_rad2(s.beacon_id, s.mean_window_rad))
            for s in spreads
        ]
    )
    errors = np.array([s.variance_standard_error_rad2 for s in spreads])
    weights = 1.0 / errors**2
    reference = float(np.sum(weights * windows) / np.sum(weights))
    constant, constant_error = _weighted_fit(estimates, errors, windows - reference, degree=0)
    slope, slope_error, slope_z = 0.0, math.inf, 0.0
    phi0_rad = min(model.code(s.beacon_id).bit_time_s for s in spreads) * model.turret_speed_rad_s
    if len(spreads) >= 3 and np.ptp(windows) > phi0_rad:
        (intercept, slope), (intercept_error, slope_error) = _weighted_fit(
            estimates, errors, windows - reference, degree=1
        )
        slope_z = abs(slope) / slope_error
    window_dependent = slope_z >= slope_z_threshold
    if window_dependent:
        constant, constant_error = intercept, intercept_error
    else:
        slope = 0.0
    return NaturalVarianceFit(
        natural_variance_rad2=max(float(constant), 0.0),
        slope_rad2_per_rad=float(slope),
        reference_window_rad=reference,
        natural_standard_error_rad2=float(constant_error),
        slope_standard_error=float(slope_error),
        slope_z=float(slope_z),
        window_dependent=bool(window_dependent),
        estimates_rad2=estimates,
        estimate_errors_rad2=errors,
        windows_rad=windows,
    )


def _weighted_fit(
    values: np.ndarray, errors: np.ndarray, x: np.ndarray, degree: int
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares of values = sum_k c_k x^k (k <= degree): (c, standard errors), the errors
    scaled by sqrt(reduced chi2) when it exceeds 1 (more scatter than the sampling explains)."""
    design = np.vander(x, degree + 1, increasing=True) / errors[:, None]
    target = values / errors
    coefficients, *_ = np.linalg.lstsq(design, target, rcond=None)
    covariance = np.linalg.inv(design.T @ design)
    dof = values.size - (degree + 1)
    if dof > 0:
        reduced_chi2 = float(np.sum((target - design @ coefficients) ** 2)) / dof
        covariance = covariance * max(reduced_chi2, 1.0)
    standard_errors = np.sqrt(np.diag(covariance))
    if degree == 0:
        return coefficients[0], standard_errors[0]
    return coefficients, standard_errors


def predicted_variance_rad2(model: VarianceModel, spread: BeaconSpread) -> float:
    """The mean variance the model gives the spread's bearings at their own windows (the driver's)."""
    return float(np.mean(model.variance(spread.beacon_id, spread.windows_rad)))


def parameter_file_text(fit: NaturalVarianceFit, comment_lines: Sequence[str] = ()) -> str:
    """A ROS parameter file setting the driver's natural variance to the fit (`--params-file`)."""
    values: Mapping[str, float] = fit.parameters()
    lines = [f"# {line}" for line in comment_lines]
    lines += ["/**/driver_node:", "  ros__parameters:"]
    lines += [f"    {name}: {value:.6e}" for name, value in values.items()]
    return "\n".join(lines) + "\n"
