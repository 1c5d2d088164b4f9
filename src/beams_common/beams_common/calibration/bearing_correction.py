"""The chapter-7 bias models of BeAMS bearings and their correction (eq. 7.18, 7.24), all in radians: the
power bias f_corr1(w) = a w^3 + b w^2 + c w + d of the window (eq. 7.19, phi_biased = phi_real + f_corr1,
eq. 7.17) and the rotation bias f_corr2(phi) = A cos(phi) + B sin(phi) + C cos(2 phi) + D sin(2 phi) (eq.
7.25; E absorbed by d). A cubic extrapolates wildly (-1.2 rad at a 0.04 rad window for one fitted over 5-13
deg), so the power bias is held at its edge value outside the windows it was fitted on (`holds_power_bias`).
"""

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from beams_common.geometry.angles import wrap_to_pi

Coefficients = tuple[float, float, float, float]
_ZERO: Coefficients = (0.0, 0.0, 0.0, 0.0)

# The thesis's global-calibration values (figures 7.11 and 7.12), used as realistic injected biases.
THESIS_POWER_BIAS_COEFFICIENTS: Coefficients = (-90.46, 35.83, -4.59, 0.19)
THESIS_ROTATION_BIAS_COEFFICIENTS: Coefficients = (-6.69e-4, -1.77e-3, -1.09e-3, -1.89e-3)
# The windows where the thesis measured and fitted the power bias (its calibration grid saw 7.4 to 10.3 deg,
# section 7.2, with a margin): the range of a calibration file that does not carry its own.
THESIS_CALIBRATION_WINDOW_RANGE_RAD = (math.radians(5.0), math.radians(13.0))


def _as_output(values: np.ndarray) -> np.ndarray | float:
    """Scalars stay Python floats, arrays stay arrays (the convention of angles.wrap_to_pi)."""
    return float(values) if np.ndim(values) == 0 else values


def _coefficients(values: ArrayLike, name: str) -> Coefficients:
    array = np.asarray(values, dtype=float).reshape(-1)
    if array.shape != (4,) or not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: expected 4 finite numbers, got {values!r}")
    return (float(array[0]), float(array[1]), float(array[2]), float(array[3]))


@dataclass(frozen=True)
class BearingCorrection:
    """Power-bias (a, b, c, d) and rotation-bias (A, B, C, D) coefficients, thesis eq. 7.19 and 7.25 (zero:
    the identity); `window_range_rad` None (the simulations' injected biases) evaluates the cubic everywhere.
    """

    power_bias_coefficients: Coefficients = _ZERO
    rotation_bias_coefficients: Coefficients = _ZERO
    window_range_rad: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        # Normalise lists/arrays to float tuples so the dataclass stays hashable and comparable.
        object.__setattr__(
            self, "power_bias_coefficients", _coefficients(self.power_bias_coefficients, "power bias")
        )
        object.__setattr__(
            self,
            "rotation_bias_coefficients",
            _coefficients(self.rotation_bias_coefficients, "rotation bias"),
        )
        if self.window_range_rad is not None:
            low, high = (float(value) for value in self.window_range_rad)
            if not (np.isfinite(low) and np.isfinite(high) and 0.0 <= low < high):
                raise ValueError(f"window range: expected 0 <= low < high, got {self.window_range_rad!r}")
            object.__setattr__(self, "window_range_rad", (low, high))

    @property
    def is_identity(self) -> bool:
        """True when the correction changes no bearing."""
        return self.power_bias_coefficients == _ZERO and self.rotation_bias_coefficients == _ZERO

    def power_bias(self, window_rad: ArrayLike) -> np.ndarray | float:
        """Power bias f_corr1(w) (rad) for windows w (rad), eq. 7.19; held at its edge value
        outside window_range_rad."""
        a, b, c, d = self.power_bias_coefficients
        w = np.asarray(window_rad, dtype=float)
        if self.window_range_rad is not None:
            w = np.clip(w, *self.window_range_rad)
        return _as_output(((a * w + b) * w + c) * w + d)

    def holds_power_bias(self, window_rad: ArrayLike) -> np.ndarray | bool:
        """True where w is outside window_range_rad, where the power bias is held at its edge value."""
        w = np.asarray(window_rad, dtype=float)
        if self.window_range_rad is None or self.power_bias_coefficients == _ZERO:
            held = np.zeros(w.shape, dtype=bool)
        else:
            held = (w < self.window_range_rad[0]) | (w > self.window_range_rad[1])
        return bool(held) if held.ndim == 0 else held

    def power_bias_slope(self, window_rad: ArrayLike) -> np.ndarray | float:
        """df_corr1/dw (rad/rad) at windows w, eq. 7.19 differentiated; 0 where the bias is held: how
        much a window error moves the corrected bearing."""
        a, b, c, _ = self.power_bias_coefficients
        w = np.asarray(window_rad, dtype=float)
        return _as_output(np.where(self.holds_power_bias(w), 0.0, (3.0 * a * w + 2.0 * b) * w + c))

    def rotation_bias(self, angle_rad: ArrayLike) -> np.ndarray | float:
        """Rotation bias f_corr2(phi) (rad) for turret angles phi (rad), eq. 7.25 with E = 0."""
        a, b, c, d = self.rotation_bias_coefficients
        phi = np.asarray(angle_rad, dtype=float)
        return _as_output(a * np.cos(phi) + b * np.sin(phi) + c * np.cos(2.0 * phi) + d * np.sin(2.0 * phi))

    def correct(self, bearing_rad: ArrayLike, window_rad: ArrayLike) -> np.ndarray | float:
        """Corrected bearing phi - f_corr1(w) - f_corr2(phi) at the measured values (eq. 7.18, 7.24)."""
        phi = np.asarray(bearing_rad, dtype=float)
        corrected = phi - np.asarray(self.power_bias(window_rad)) - np.asarray(self.rotation_bias(phi))
        return wrap_to_pi(corrected)

    def apply_bias(self, true_bearing_rad: ArrayLike, window_rad: ArrayLike) -> np.ndarray | float:
        """The biased bearing a sensor with these imperfections measures (eq. 7.17, 7.24; correct() inverts it
        to first order)."""
        phi = np.asarray(true_bearing_rad, dtype=float)
        biased = phi + np.asarray(self.power_bias(window_rad)) + np.asarray(self.rotation_bias(phi))
        return wrap_to_pi(biased)


IDENTITY_CORRECTION = BearingCorrection()
THESIS_CORRECTION = BearingCorrection(THESIS_POWER_BIAS_COEFFICIENTS, THESIS_ROTATION_BIAS_COEFFICIENTS)
