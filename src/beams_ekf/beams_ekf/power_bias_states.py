"""The power bias of an uncalibrated sensor (thesis eq. 7.17-7.19) in the EKF: estimated or considered.

An uncalibrated BeAMS bearing is phi_real + f(w) + noise, f the power bias, a smooth function of the angular
window w that fluctuates within 0.23 deg over the working windows (section 5.7, fig. 5.6; eq. 7.19 fits a
cubic). Treated as white noise it makes the filter overconfident (mean NEES ~40 on a match): the
same bias comes back bearing after bearing. Here f is written on the Chebyshev polynomials of the window
mapped onto [-1, 1] over `window_range_rad` (clamped outside it, as the chapter-7 correction clamps):

    f(w) = sum_k beta_k T_k(x(w)),  k = 0..3,  x(w) = (2 w - lo - hi) / (hi - lo)

which spans the same cubics as eq. 7.19. The constant beta_0 is kept although a constant bias turns every
bearing alike and the heading largely absorbs it (section 7.3.2): without it the filter was overconfident
(NEES 25), and the odometry observes it in part (docs/self_calibration.md). Each |T_k| <= 1 on the range, so a
prior standard deviation of half the thesis's 0.23 deg on each beta_k keeps the prior curve within the
measured fluctuation. The coefficients are filter states: `estimate` learns them from the bearings and the
odometry (self-calibration), `consider` keeps them at their prior (Schmidt-Kalman "consider" parameters:
the filter's covariance carries their uncertainty and its correlation, their estimate never moves).
"""

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from math import hypot, log, radians, sqrt
from typing import Any

import numpy as np

from beams_common.calibration.bearing_correction import BearingCorrection
from beams_common.config.parameters import ParameterSpec, ParameterTable
from beams_common.geometry.pose2d import compose
from beams_ekf.state_blocks import BearingPart, Sighting, StateBlock

# Section 5.7: the bias fluctuates with the received power within 0.23 deg.
THESIS_POWER_BIAS_RANGE_RAD = radians(0.23)
# The angular windows (rad) of the section-5.3 experiment, 6 m and 1 m from a beacon, with the beam of the
# simulated thesis sensor (beams_sim.sensor_sim, checked by test_power_bias_states): where the thesis
# measured the power bias, and where the chapter-7 correction holds it.
THESIS_EXPERIMENT_WINDOWS_RAD = (0.038048, 0.139573)
POWER_BIAS_MODES = ("estimate", "consider", "off")
BASIS_SIZE = 4


POWER_BIAS_SPECS = ParameterTable(
    "ekf_node",
    (
        ParameterSpec(
            "power_bias_states",
            "estimate",
            "The power bias (thesis eq. 7.19) of bearings no calibration corrected "
            "(beams/bearings 'calibrated' false): 'estimate' learns it while driving (self-calibration), "
            "'consider' keeps it at its prior and carries its uncertainty (Schmidt-Kalman), 'off' treats "
            "it as white noise (overconfident).",
            choices=POWER_BIAS_MODES,
        ),
        ParameterSpec(
            "power_bias_sigma_rad",
            0.5 * THESIS_POWER_BIAS_RANGE_RAD,
            "Prior standard deviation (rad) of each Chebyshev coefficient of the power bias: half the "
            "0.23 deg range the thesis measured (section 5.7).",
            minimum=1e-7,
            maximum=0.1,
        ),
        ParameterSpec(
            "power_bias_window_range_rad",
            list(THESIS_EXPERIMENT_WINDOWS_RAD),
            "Angular windows [low, high] (rad) over which the power bias varies (held constant outside): "
            "the thesis experiment's, 6 m to 1 m.",
            minimum=0.0,
            maximum=1.0,
            length=2,
        ),
        ParameterSpec(
            "self_calibration_file",
            "self_calibration.yaml",
            "Where the ~/save_calibration service writes the power bias learnt while driving (a chapter-7 "
            "calibration file for driver_node's calibration_file; the previous one kept as .bak).",
        ),
    ),
)


@dataclass(frozen=True)
class PowerBiasStates(StateBlock):
    """The power bias's Chebyshev coefficients (beta_0 .. beta_3) (rad) as EKF states: a bearing the
    driver did not correct is predicted as h(x) + f(w).

    estimate: False makes them Schmidt-Kalman consider parameters (never updated). An uncalibrated
    bearing whose bias cannot be modelled yet (the window fit not ready, `WindowFit`) updates the pose
    alone: it carries an unknown bias, and letting it teach the learnt blocks (odometry errors, turret
    offset, beacons) baked that bias into them, overconfidently (mean NEES over the first 10 s up to 10.5
    on one seed of ten, 4.0 at most without).
    """

    window_range_rad: tuple[float, float] = tuple(POWER_BIAS_SPECS.default("power_bias_window_range_rad"))
    prior_sigma_rad: float = POWER_BIAS_SPECS.default("power_bias_sigma_rad")
    estimate: bool = True
    size = BASIS_SIZE

    def __post_init__(self) -> None:
        low, high = (float(v) for v in self.window_range_rad)
        if not low < high:
            raise ValueError(f"power bias window range: need low < high, got {self.window_range_rad}")
        object.__setattr__(self, "window_range_rad", (low, high))

    @property
    def prior_covariance(self) -> np.ndarray:
        return self.prior_sigma_rad**2 * np.eye(BASIS_SIZE)

    def new_memory(self) -> "WindowFit":
        return WindowFit()

    def bearing(self, mean: np.ndarray, sighting: Sighting, memory: "WindowFit") -> BearingPart:
        """f(w) at the fitted window (until the fit is ready, the measured one: the bias's uncertainty)."""
        if sighting.window_rad <= 0.0:
            return BearingPart(np.zeros(BASIS_SIZE), learns=False)
        turret = compose(sighting.pose, sighting.lever)
        distance_m = hypot(sighting.beacon_xy[0] - turret[0], sighting.beacon_xy[1] - turret[1])
        window = memory.window_rad(sighting.beacon_id, distance_m, sighting.window_rad)
        sighting.pose_only = sighting.pose_only or window is None
        basis = self.basis(sighting.window_rad if window is None else window)
        return BearingPart(basis, float(basis @ mean), window is not None and self.estimate)

    def basis(self, window_rad: float) -> np.ndarray:
        """(T_1, T_2, T_3) at the window mapped onto [-1, 1] (clamped): d f / d beta."""
        low, high = self.window_range_rad
        x = min(max((2.0 * window_rad - low - high) / (high - low), -1.0), 1.0)
        return np.array([1.0, x, 2.0 * x * x - 1.0, (4.0 * x * x - 3.0) * x])

    def bias_rad(self, coefficients: np.ndarray, window_rad: float) -> float:
        """f(w) (rad) for the coefficients."""
        return float(self.basis(window_rad) @ np.asarray(coefficients, dtype=float).reshape(-1))

    def correction(self, coefficients: np.ndarray) -> BearingCorrection:
        """The chapter-7 correction (eq. 7.19's a, b, c, d, window range) that removes f: what a
        calibration file holds (beams_common.calibration.calibration_file), no rotation bias."""
        chebyshev = np.polynomial.Chebyshev(
            np.asarray(coefficients, dtype=float).reshape(-1),
            domain=list(self.window_range_rad),
        )
        ascending = np.zeros(4)
        power = chebyshev.convert(kind=np.polynomial.Polynomial).coef
        ascending[: len(power)] = power
        return BearingCorrection(tuple(ascending[::-1]), window_range_rad=self.window_range_rad)


class WindowFit:
    """Each beacon's angular window against the turret's distance to it, fitted on the decoded windows:
    w^2 = A + B ln d (a Gaussian beam whose received power falls as 1/d^2, eq. 2.7 and 2.2-2.4).

    The power bias is a function of the true window; a decoded window's error (the edges' noise, ~3 mrad)
    is correlated with its bearing's error (both come from the first rising and last falling edges), so
    regressing the bearing on it learns a wrong curve. The fitted window at the filter's distance has
    neither the noise nor the correlation. A bearing the Localiser applies again (late bearings) is not
    counted twice: the last windows of each beacon are remembered.
    """

    # ready after 10 s of a beacon's windows over distances spread by +-14% (std of ln d 0.14): with 30
    # windows and no spread required, the first fits' slopes teach the curve wrongly on some matches
    # (the first 30 s's mean NEES in bench_self_calibration shows it)
    MIN_SAMPLES = 100
    MIN_LOG_DISTANCE_VARIANCE = 0.02
    _REMEMBERED = 16

    def __init__(self) -> None:
        self._sums: dict[int, np.ndarray] = {}
        self._recent: dict[int, deque[float]] = {}

    def window_rad(self, beacon_id: int, distance_m: float, measured_window_rad: float) -> float | None:
        """The window to evaluate the bias at: the fit at distance_m once it holds MIN_SAMPLES windows
        whose ln-distances vary by MIN_LOG_DISTANCE_VARIANCE, else None (the fit is not ready); the
        measured one joins the fit."""
        recent = self._recent.setdefault(beacon_id, deque(maxlen=self._REMEMBERED))
        log_distance = log(max(distance_m, 1e-3))
        sums = self._sums.setdefault(beacon_id, np.zeros(6))
        if measured_window_rad not in recent:
            recent.append(measured_window_rad)
            w2 = measured_window_rad * measured_window_rad
            sums += (1.0, log_distance, log_distance * log_distance, w2, w2 * log_distance, 0.0)
        count, sx, sxx, sy, sxy, _ = sums
        spread = sxx * count - sx * sx
        if count < self.MIN_SAMPLES or spread < self.MIN_LOG_DISTANCE_VARIANCE * count * count:
            return None
        slope = (sxy * count - sx * sy) / spread
        fitted = (sy - slope * sx) / count + slope * log_distance
        return sqrt(fitted) if fitted > 0.0 else None


def power_bias_states_of(values: Mapping[str, Any]) -> PowerBiasStates | None:
    """The states of ekf_node's validated parameter values; None when 'off'. ValueError for a window
    range that is not increasing."""
    mode, sigma = values["power_bias_states"], float(values["power_bias_sigma_rad"])
    window = tuple(values["power_bias_window_range_rad"])
    return None if mode == "off" else PowerBiasStates(window, sigma, estimate=mode == "estimate")
