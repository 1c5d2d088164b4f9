"""The wheel odometry's increment as an arc, and its systematic errors as filter states.

A differential-drive robot's odometry step is an arc: the robot travels s along it and turns by Delta,
so its robot-frame increment is

    g(s, Delta) = (s sin(Delta)/Delta, s (1 - cos(Delta))/Delta, Delta).

Wheel-radius and wheel-base errors are not white noise: they scale every step the same way. Three
constants describe them to first order (`OdometryErrorStates`), the true motion being

    s_true = k_s s,    Delta_true = k_theta Delta + h s

(k_s: the mean wheel scale, slip included; k_theta: nominal / true wheel base; h (rad/m): the unequal
wheel radii turn the robot while it drives straight). With them as states, the process noise left is
the wheels' random noise, per step.
"""

from collections.abc import Mapping
from dataclasses import dataclass
from math import cos, hypot, sin
from typing import Any

import numpy as np

from beams_common.config.parameters import ParameterSpec, ParameterTable
from beams_common.geometry.pose2d import Pose2D
from beams_ekf.state_blocks import StateBlock

# below this turn (rad) the arc functions use their Taylor series (the closed forms lose precision)
_SMALL_TURN_RAD = 1e-4


def _arc_terms(d: float) -> tuple[float, float, float, float]:
    """a = sin(Delta)/Delta, b = (1 - cos(Delta))/Delta and their derivatives in Delta."""
    if abs(d) < _SMALL_TURN_RAD:
        return 1.0 - d * d / 6.0, 0.5 * d - d**3 / 24.0, -d / 3.0, 0.5 - d * d / 8.0
    sin_d, cos_d = sin(d), cos(d)
    return sin_d / d, (1.0 - cos_d) / d, (d * cos_d - sin_d) / (d * d), (d * sin_d - (1.0 - cos_d)) / (d * d)


def arc_increment(s_m: float, turn_rad: float) -> tuple[Pose2D, np.ndarray]:
    """g(s, Delta) and its 3x2 Jacobian d g / d (s, Delta)."""
    a, b, da, db = _arc_terms(turn_rad)
    return (s_m * a, s_m * b, turn_rad), np.array([[a, s_m * da], [b, s_m * db], [0.0, 1.0]])


def arc_of_increment(increment: Pose2D) -> tuple[float, float]:
    """(s, Delta) of an odometry increment (dx, dy, dtheta): the arc through it (least squares on the
    chord, exact for an increment that is an arc)."""
    a, b, _, _ = _arc_terms(increment[2])
    return (increment[0] * a + increment[1] * b) / (a * a + b * b), increment[2]


# The priors: a few percent of scale and of wheel base (what sim_world's OdometryDrift gives a roughly
# calibrated robot: 1 % wheel radii, 0.4 % mean slip, 1 % wheel base), a heading drift of 0.03 rad/m (a
# 0.5 % radius difference over a 0.3 m wheel base is 0.017 rad/m).
_SIGMA_RANGE = {"minimum": 1e-6, "maximum": 1.0}
ODOMETRY_ERROR_SPECS = ParameterTable(
    "ekf_node",
    (
        ParameterSpec(
            "odometry_error_states",
            True,
            "Estimate the odometry's systematic errors (distance scale, rotation scale, "
            "heading drift per metre) as filter states.",
        ),
        ParameterSpec(
            "odometry_scale_sigma",
            0.02,
            "Prior standard deviation of the odometry's distance scale.",
            **_SIGMA_RANGE,
        ),
        ParameterSpec(
            "odometry_rotation_scale_sigma",
            0.02,
            "Prior standard deviation of the odometry's rotation scale (wheel base).",
            **_SIGMA_RANGE,
        ),
        ParameterSpec(
            "odometry_heading_drift_sigma_rad_per_m",
            0.03,
            "Prior standard deviation of the heading drift per metre driven (unequal wheel radii, rad/m).",
            **_SIGMA_RANGE,
        ),
    ),
)
_SIGMAS = ("odometry_scale_sigma", "odometry_rotation_scale_sigma", "odometry_heading_drift_sigma_rad_per_m")


@dataclass(frozen=True)
class OdometryErrorStates(StateBlock):
    """Filter states (k_s, k_theta, h) for the odometry's systematic errors, with their prior: each
    prediction applies the increment they correct (`corrected_increment`), and the bearings estimate
    them through the pose's cross-covariance with them."""

    scale_sigma: float = ODOMETRY_ERROR_SPECS.default(_SIGMAS[0])
    rotation_scale_sigma: float = ODOMETRY_ERROR_SPECS.default(_SIGMAS[1])
    heading_drift_sigma_rad_per_m: float = ODOMETRY_ERROR_SPECS.default(_SIGMAS[2])
    # random walk of the three states per metre travelled (0: constants, as in the simulator)
    walk_variance_per_m: float = 0.0
    size = 3

    @property
    def prior_mean(self) -> np.ndarray:
        """(k_s, k_theta, h) of a perfect odometry."""
        return np.array([1.0, 1.0, 0.0])

    @property
    def prior_covariance(self) -> np.ndarray:
        """3x3 diagonal prior covariance of (k_s, k_theta, h)."""
        sigmas = (self.scale_sigma, self.rotation_scale_sigma, self.heading_drift_sigma_rad_per_m)
        return np.diag(np.square(sigmas))

    def corrected_increment(self, increment: Pose2D, mean: np.ndarray) -> tuple[Pose2D, np.ndarray]:
        moved, d_errors, _ = corrected_increment(increment, mean)
        return moved, d_errors

    def process_noise(self, increment: Pose2D, mean: np.ndarray) -> np.ndarray | None:
        if not self.walk_variance_per_m:
            return None  # constants
        return self.walk_variance_per_m * hypot(increment[0], increment[1]) * np.eye(self.size)


def odometry_error_states_of(values: Mapping[str, Any]) -> OdometryErrorStates | None:
    """The states of ekf_node's validated parameter values; None when odometry_error_states is false."""
    on = values["odometry_error_states"]
    return OdometryErrorStates(*(float(values[name]) for name in _SIGMAS)) if on else None


def corrected_increment(increment: Pose2D, errors: np.ndarray) -> tuple[Pose2D, np.ndarray, np.ndarray]:
    """The true-motion increment from a reported one and the error states (k_s, k_theta, h).

    Returns the increment, its 3x3 Jacobian with respect to the error states and its 3x2 Jacobian
    with respect to the reported arc (s, Delta) (through which the wheels' random noise enters).
    """
    k_s, k_theta, h = errors.tolist()
    s, turn = arc_of_increment(increment)
    true_s, true_turn = k_s * s, k_theta * turn + h * s
    a, b, da, db = _arc_terms(true_turn)
    # d g / d (s, Delta) of the true arc: columns (a, b, 0) and (p, q, 1), (p, q) = true_s (da, db)
    p, q = true_s * da, true_s * db
    d_errors = np.array([[a * s, p * turn, p * s], [b * s, q * turn, q * s], [0.0, turn, s]])
    d_reported = np.array([[a * k_s + p * h, p * k_theta], [b * k_s + q * h, q * k_theta], [h, k_theta]])
    return (true_s * a, true_s * b, true_turn), d_errors, d_reported
