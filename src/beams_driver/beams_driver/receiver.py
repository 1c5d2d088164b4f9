"""What the infrared receiver does to code AND window (thesis sections 5.5-5.7): `ReceiverModel`, the
systematic part the decoder must know; `HardwareNoise`, the thesis hardware's noise (chapter 5)."""

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from beams_common.calibration.bearing_correction import BearingCorrection
from beams_driver.codes import BeaconCode
from beams_driver.edges import TURRET_PERIOD_S

# The AND hypothesis: bursts shorter than 56% of T0 do not trigger the receiver (section 5.6).
THESIS_MIN_BURST_FRACTION = 0.56
# ... for the family codes; a longer OFF period G lowers it as sqrt(T_b / G) (the AGC's gain recovering,
# section 5.6), which with the modulated windows' extra shortening reproduces table 5.1's experiments.
THESIS_MIN_BURST_GAP_EXPONENT = -0.5
# Table 5.1: the AGC shortens a modulated window by about 3.5e-3 deg more than the AND alone.
THESIS_MODULATION_SHORTENING_RAD = math.radians(3.5e-3)
# Fig. 5.3, code C_k: variance of the first rising and last falling edge (deg^2) over the windows
# of the experiment, smallest to largest (section 5.6).
THESIS_RISING_VARIANCE_DEG2 = (0.0018, 0.0137)
THESIS_FALLING_VARIANCE_DEG2 = (0.000066, 0.0023)
# Section 5.7: the bias fluctuates with the received power within 0.23 deg.
THESIS_POWER_BIAS_RANGE_DEG = 0.23
# Fig. 5.3's windows (rad): section 5.3's experiment, 6 m to 1 m (2.18 to 8.0 deg; the device's beam).
THESIS_WINDOW_RANGE_RAD = (0.03804832377144775, 0.13957318546672076)


@dataclass(frozen=True)
class ReceiverModel:
    """Minimum detectable burst and mean window shortening of a receiver (sections 5.3 and 5.6): the minimum
    burst is min_burst_fraction * T_b * (G / T_b)^min_burst_gap_exponent for a shortest gap G (56% of T0 for
    the one-bit gaps; -0.5: a longer OFF lets the AGC recover); outer_shortening_s halved per edge."""

    min_burst_fraction: float = 0.0
    min_burst_gap_exponent: float = 1.0
    outer_shortening_s: float = 0.0

    def __post_init__(self) -> None:
        if self.min_burst_fraction < 0.0 or self.outer_shortening_s < 0.0:
            raise ValueError("receiver: min_burst_fraction and outer_shortening_s must be >= 0")

    @classmethod
    def thesis_hardware(cls, period_s: float = TURRET_PERIOD_S) -> "ReceiverModel":
        """The receiver the thesis measured (sections 5.5-5.7) on a turret of this period (s): what the driver
        assumes of real hardware and the simulator's `thesis_hardware` noise emulates."""
        turret_speed_rad_s = 2.0 * np.pi / period_s
        return cls(
            THESIS_MIN_BURST_FRACTION,
            THESIS_MIN_BURST_GAP_EXPONENT,
            THESIS_MODULATION_SHORTENING_RAD / turret_speed_rad_s,
        )

    def min_burst_s(self, code: BeaconCode) -> float:
        """Shortest clipped burst (s) that still triggers the receiver for this code."""
        gap_s = min(code.gap_bits) * code.bit_time_s
        if self.min_burst_gap_exponent == 1.0:
            return self.min_burst_fraction * gap_s
        return (
            self.min_burst_fraction
            * code.bit_time_s
            * (gap_s / code.bit_time_s) ** self.min_burst_gap_exponent
        )

    def window_shortening_s(self, code: BeaconCode) -> float:
        """Mean of phi_W - Phi_w (s of turret time): sum over gaps of (G_j + m)^2 / T_c, plus the outer shift
        (eq. 5.2 with a minimum burst m: the edge also waits out a burst too short to trigger)."""
        gaps_s = np.array(code.gap_bits, dtype=float) * code.bit_time_s
        m = self.min_burst_s(code)
        return float(np.sum((gaps_s + m) ** 2) / code.duration_s) + self.outer_shortening_s


IDEAL_RECEIVER = ReceiverModel()


@dataclass(frozen=True)
class HardwareNoise:
    """The thesis hardware's receiver noise (sections 5.5-5.7), applied by the simulator to each window.

    Gaussian jitter of the window's two edges, larger at its start (the AGC's gain after a silence, fig. 5.3),
    linear in the window between the experiment's extremes; off_noise_gain: the natural variance times 1 +
    gain (G / T_b - 1), G the longest gap (section 5.6); power_bias_coefficients: f(w) of eq. 7.19 (eq. 7.17),
    constant outside power_bias_range_rad (default window_range_rad, section 5.7)."""

    window_range_rad: tuple[float, float]
    power_bias_coefficients: tuple[float, float, float, float]
    rising_variance_deg2: tuple[float, float] = THESIS_RISING_VARIANCE_DEG2
    falling_variance_deg2: tuple[float, float] = THESIS_FALLING_VARIANCE_DEG2
    off_noise_gain: float = 0.7
    modulation_shortening_rad: float = THESIS_MODULATION_SHORTENING_RAD
    power_bias_range_rad: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        low, high = self.window_range_rad
        if not 0.0 < low < high:
            raise ValueError(
                f"hardware noise: window range must satisfy 0 < low < high, got {self.window_range_rad}"
            )
        if min(*self.rising_variance_deg2, *self.falling_variance_deg2, self.off_noise_gain) < 0.0:
            raise ValueError("hardware noise: variances and off_noise_gain must be >= 0")

    @classmethod
    def thesis_hardware(cls) -> "HardwareNoise":
        """The receiver noise the thesis measured over section 5.3's windows: fig. 5.3's edge noise, table
        5.1's shortening, a power bias within section 5.7's 0.23 deg (`thesis_power_bias_coefficients`)."""
        bias_range_rad = math.radians(THESIS_POWER_BIAS_RANGE_DEG)
        return cls(
            THESIS_WINDOW_RANGE_RAD, thesis_power_bias_coefficients(THESIS_WINDOW_RANGE_RAD, bias_range_rad)
        )

    def edge_std_rad(self, window_rad: ArrayLike, code: BeaconCode | None) -> tuple[np.ndarray, np.ndarray]:
        """(rising, falling) standard deviations (rad) of the window boundaries; code None is C_k."""
        low, high = self.window_range_rad
        fraction = np.clip((np.asarray(window_rad, dtype=float) - low) / (high - low), 0.0, 1.0)
        scale = self.off_gain(code) * math.radians(1.0) ** 2
        rising = self.rising_variance_deg2[0] + fraction * np.diff(self.rising_variance_deg2)[0]
        falling = self.falling_variance_deg2[0] + fraction * np.diff(self.falling_variance_deg2)[0]
        return np.sqrt(rising * scale), np.sqrt(falling * scale)

    def rising_share(self, window_rad: float) -> float:
        """sigma_r^2 / (sigma_r^2 + sigma_f^2) at window w (rad): the rising edge's share of the edge noise
        (fig. 5.3: 0.96 at the smallest window, 0.86 at the largest; the same for every code)."""
        rising, falling = self.edge_std_rad(window_rad, None)
        return float(rising**2 / (rising**2 + falling**2))

    def off_gain(self, code: BeaconCode | None) -> float:
        """Factor on the natural variance for a code's OFF periods (1 for C_k and one-bit gaps)."""
        if code is None:
            return 1.0
        return 1.0 + self.off_noise_gain * (max(code.gap_bits) - 1)

    def power_bias_rad(self, window_rad: ArrayLike) -> np.ndarray:
        """Power bias f(w) (rad) of the bearing for true windows w (rad), eq. 7.19, the window held
        inside the experiment's range: the cubic models the fluctuation within 0.23 deg that section 5.7
        measured there, and would run away outside it (0.9 deg at 0.5 m)."""
        return np.asarray(self.power_bias_correction().power_bias(window_rad), dtype=float)

    def power_bias_correction(self) -> BearingCorrection:
        """The chapter-7 correction that removes this power bias exactly (eq. 7.18): what a perfect
        calibration of this receiver finds (its window range the experiment's)."""
        bias_range = self.power_bias_range_rad or self.window_range_rad
        return BearingCorrection(self.power_bias_coefficients, window_range_rad=bias_range)

    def natural_variance_rad2(self, window_rad: ArrayLike, code: BeaconCode | None) -> np.ndarray:
        """Bearing variance (rad^2) the edge noise adds at true windows w: (sigma_r^2 + sigma_f^2) / 4
        (eq. 3.13 with independent edges)."""
        rising, falling = self.edge_std_rad(window_rad, code)
        return (rising**2 + falling**2) / 4.0

    def natural_variance_line(self) -> tuple[float, float, float]:
        """(natural variance (rad^2) at the smallest window, its slope (rad^2 per rad), that window (rad)):
        the edge noise (eq. 3.13), linear over the experiment's windows (fig. 5.3), as the driver takes it."""
        low, high = self.window_range_rad
        at_low, at_high = (float(self.natural_variance_rad2(w, None)) for w in (low, high))
        return at_low, (at_high - at_low) / (high - low), low


def thesis_power_bias_coefficients(
    window_range_rad: tuple[float, float], range_rad: float
) -> tuple[float, float, float, float]:
    """Eq. 7.19 coefficients (a, b, c, d) of a zero-mean bias fluctuating within range_rad over the windows
    (fig. 5.6: 0.23 deg): Chebyshev's T3(x) = 4x^3 - 3x on the windows mapped onto [-1, 1] sweeps it twice."""
    low, high = window_range_rad
    windows = np.linspace(low, high, 16)
    x = (2.0 * windows - low - high) / (high - low)
    a, b, c, d = np.polyfit(windows, 0.5 * range_rad * (4.0 * x**3 - 3.0 * x), 3)
    return (float(a), float(b), float(c), float(d))
