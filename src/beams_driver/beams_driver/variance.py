"""Variance of a BeAMS bearing against the angular window (thesis chapters 3 and 4): the family's closed
form (section 4.2.3, eq. 4.69-4.76), the enumeration over every shift for any code (section 4.4), and
`VarianceModel`, what the decoder uses per code and window: "exact", "bound" (theorem 3.1) or "constant",
plus a natural variance constant or linear in the window (section 5.5, fitted by `noise_estimation`).
"""

from bisect import bisect_right
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from beams_common.calibration.bearing_correction import BearingCorrection
from beams_driver.codes import BeaconCode, first_last_edges, is_family_code
from beams_driver.edges import TURRET_SPEED_RAD_S
from beams_driver.receiver import ReceiverModel

VarianceMode = Literal["exact", "bound", "constant"]
Polynomial = Callable[[np.ndarray], np.ndarray]
VARIANCE_MODES: tuple[str, ...] = ("exact", "bound", "constant")
# The real system's maximum measured variance with code C5 (table 5.1): 5.49e-3 deg^2.
MEASURED_VARIANCE_RAD2 = 5.49e-3 * np.radians(1.0) ** 2
# Lookup resolution of the enumeration: the variance is a cubic per bit, so linear steps of a
# 64th of a bit stay within 1e-3 of the bound.
GRID_POINTS_PER_BIT = 64
_GAUSS_NODES = np.array([-1.0, 1.0]) / np.sqrt(3.0)


# ---- section 4.2.3: the closed form for the code family ----


def _p_0(lam: np.ndarray, p0: float) -> np.ndarray:
    """Case 0, eq. 4.69."""
    return lam**3 / (1.0 - p0 + p0 * lam)


def _p_b(lam: np.ndarray) -> np.ndarray:
    """Case B, eq. 4.71."""
    return 1.0 - lam**3 / 4.0


def _p_c(lam: np.ndarray) -> np.ndarray:
    """Case C, eq. 4.72."""
    return (3.0 - 3.0 * lam + 3.0 * lam**2 + lam**3) / 4.0


def _p_d(lam: np.ndarray) -> np.ndarray:
    """Case D, eq. 4.73."""
    return 1.0 - lam**3 / 2.0


def _p_e(lam: np.ndarray) -> np.ndarray:
    """Case E, eq. 4.74."""
    return (1.0 - 3.0 * lam + 3.0 * lam**2 + lam**3) / 2.0


def _p_a(lam: np.ndarray) -> np.ndarray:
    """Case A, eq. 4.70: the bound itself."""
    return 1.0 + 0.0 * lam


@lru_cache(maxsize=64)
def _family_segments(index: int, n_codes: int) -> tuple[int, tuple[float, ...], tuple[Polynomial, ...]]:
    """(period, segment starts, case polynomials) of one period of the variance, phi_W >= phi0."""
    n_ones = 2 * n_codes
    if index == n_codes:
        period = n_codes + 1
        cases = [(0, _p_e), (1, _p_a), (n_codes, _p_d)]
    else:
        period = n_ones + 2
        cases = [(0, _p_e), (1, _p_a)]
        for low in (index, n_ones - index):
            cases += [(low, _p_b), (low + 1, _p_c), (low + 2, _p_a)]
        cases.append((n_ones + 1, _p_d))
    # Where an A interval is empty (i = 1 or i = Nc - 1) the later entry at the same start wins.
    table = dict(sorted(cases, key=lambda case: case[0]))
    starts = tuple(float(k) for k in sorted(table))
    return period, starts, tuple(table[int(k)] for k in starts)


def family_normalized_variance(index: int, n_codes: int, window_over_phi0: ArrayLike) -> np.ndarray | float:
    """sigma^2 / (p0 phi0^2 / 6) for code C_index of the family with Nc codes (eq. 4.75 as corrected in
    NOTES.md, 4.76): the cases of m = phi_W mod (2Nc + 2) phi0 (code Nc: period Nc + 1), case 0 below phi0.
    """
    if not 1 <= index <= n_codes:
        raise ValueError(f"family code index {index} outside 1..{n_codes}")
    p0 = 2.0 / (2 * n_codes + 2)
    period, starts, polynomials = _family_segments(index, n_codes)
    if np.ndim(window_over_phi0) == 0:
        x = float(window_over_phi0)  # type: ignore[arg-type]
        if x < 0.0:
            raise ValueError("angular window must be >= 0")
        if x < 1.0:
            return float(_p_0(x, p0))
        m = x % period
        k = bisect_right(starts, m) - 1
        return float(polynomials[k](m - starts[k]))
    x = np.asarray(window_over_phi0, dtype=float)
    if np.any(x < 0.0):
        raise ValueError("angular window must be >= 0")
    m = np.mod(x, period)
    k = np.searchsorted(np.array(starts), m, side="right") - 1
    result = np.ones_like(x)
    for segment, (start, polynomial) in enumerate(zip(starts, polynomials, strict=True)):
        chosen = k == segment
        result[chosen] = polynomial(m[chosen] - start)
    return np.where(x < 1.0, _p_0(np.minimum(x, 1.0), p0), result)


# ---- section 4.4: every shift of the code against the window ----


def enumerated_variance_s2(
    code: BeaconCode, window_s: ArrayLike, min_burst_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(variance s^2, mean bearing error s, detection probability) of Phi_b for windows (s), the start u
    uniform over a code period (section 4.4): the edges are piecewise linear in u, so two Gauss-Legendre
    nodes per piece integrate exactly; shifts with no detection are left out (as in case 0)."""
    windows = np.atleast_1d(np.asarray(window_s, dtype=float))
    period = code.duration_s
    on_start, on_end = code.on_intervals_s
    boundaries = np.concatenate([on_start, on_end])
    offsets = np.array([0.0, -min_burst_s, min_burst_s]) if min_burst_s > 0 else np.zeros(1)
    marks = (boundaries[:, None] + offsets[None, :]).ravel()
    n = windows.size
    at_start = np.broadcast_to(marks, (n, marks.size))
    at_end = marks[None, :] - windows[:, None]
    breaks = np.mod(np.concatenate([at_start, at_end], axis=1), period)
    breaks = np.sort(np.concatenate([breaks, np.zeros((n, 1)), np.full((n, 1), period)], axis=1), axis=1)
    half = 0.5 * np.diff(breaks, axis=1)
    centre = 0.5 * (breaks[:, 1:] + breaks[:, :-1])
    shifts = (centre[:, :, None] + half[:, :, None] * _GAUSS_NODES[None, None, :]).reshape(n, -1)
    weights = np.repeat(half, _GAUSS_NODES.size, axis=1)
    ends = shifts + windows[:, None]
    rising, falling, detected = first_last_edges(code, shifts, ends, min_burst_s)
    error = 0.5 * ((rising - shifts) + (falling - ends))
    weights = np.where(detected, weights, 0.0)
    error = np.where(detected, error, 0.0)
    total = weights.sum(axis=1)
    safe_total = np.where(total > 0, total, 1.0)
    mean = (weights * error).sum(axis=1) / safe_total
    variance = np.maximum((weights * error**2).sum(axis=1) / safe_total - mean**2, 0.0)
    return variance, mean, total / period


class _EnumeratedLookup:
    """The enumerated variance of one code tabulated once over a window range that covers its period."""

    def __init__(self, code: BeaconCode, min_burst_s: float) -> None:
        # Beyond the longest gap (plus the undetectable slivers) detection is certain and the variance
        # repeats with the code period.
        self.periodic_from_s = max(code.gap_bits) * code.bit_time_s + 2.0 * min_burst_s + code.bit_time_s
        self.period_s = code.duration_s
        step = code.bit_time_s / GRID_POINTS_PER_BIT
        self.windows_s = np.arange(0.0, self.periodic_from_s + self.period_s + 2.0 * step, step)
        self.variance_s2 = enumerated_variance_s2(code, self.windows_s, min_burst_s)[0]

    def __call__(self, window_s: np.ndarray) -> np.ndarray:
        w = np.maximum(window_s, 0.0)
        folded = self.periodic_from_s + np.mod(w - self.periodic_from_s, self.period_s)
        w = np.where(w > self.periodic_from_s, folded, w)
        return np.interp(w, self.windows_s, self.variance_s2)


class VarianceModel:
    """Bearing variance (rad^2) per code and angular window, as fed to the filters.

    mode "exact": chapter 4's artificial variance (closed form for the family, else an enumeration lookup);
    "bound": p0 phi0^2 / 6 (theorem 3.1, stretched by the minimum burst); both plus the natural variance,
    linear in the window from natural_variance_reference_window_rad (fig. 5.3), never below 0; "constant".
    """

    def __init__(
        self,
        codes: Sequence[BeaconCode],
        mode: VarianceMode = "exact",
        *,
        turret_speed_rad_s: float = TURRET_SPEED_RAD_S,
        natural_variance_rad2: float = 0.0,
        constant_variance_rad2: float = MEASURED_VARIANCE_RAD2,
        min_burst_fraction: float = 0.0,
        min_burst_gap_exponent: float = 1.0,
        natural_variance_slope_rad2_per_rad: float = 0.0,
        natural_variance_reference_window_rad: float = 0.0,
    ) -> None:
        """min_burst_fraction, min_burst_gap_exponent: the minimum burst, as receiver.ReceiverModel has it;
        natural_variance_rad2 is the natural variance at natural_variance_reference_window_rad."""
        if mode not in VARIANCE_MODES:
            raise ValueError(f"variance mode {mode!r} is not one of {VARIANCE_MODES}")
        if natural_variance_rad2 < 0.0 or constant_variance_rad2 < 0.0 or min_burst_fraction < 0.0:
            raise ValueError("variance model: variances and min_burst_fraction must be >= 0")
        if not turret_speed_rad_s > 0.0:
            raise ValueError("variance model: turret speed must be positive")
        if not (
            np.isfinite(natural_variance_slope_rad2_per_rad) and natural_variance_reference_window_rad >= 0
        ):
            raise ValueError("variance model: the natural variance's slope must be finite, its window >= 0")
        self.mode: VarianceMode = mode
        self.turret_speed_rad_s = float(turret_speed_rad_s)
        self.natural_variance_rad2 = float(natural_variance_rad2)
        self.natural_variance_slope_rad2_per_rad = float(natural_variance_slope_rad2_per_rad)
        self.natural_variance_reference_window_rad = float(natural_variance_reference_window_rad)
        self.constant_variance_rad2 = float(constant_variance_rad2)
        self.min_burst_fraction = float(min_burst_fraction)
        self._receiver = ReceiverModel(self.min_burst_fraction, float(min_burst_gap_exponent))
        self._codes = {c.code_id: c for c in codes}
        # The closed form applies to family codes under the ideal AND receiver only.
        self._families = {
            c.code_id: is_family_code(c) if self.min_burst_fraction == 0.0 else None for c in codes
        }
        self._lookups: dict[int, _EnumeratedLookup] = {}
        if mode == "exact":
            for code in codes:
                if self._family(code) is None:
                    self._lookups[code.code_id] = _EnumeratedLookup(code, self._min_burst_s(code))

    def code(self, code: int | BeaconCode) -> BeaconCode:
        """The code object for an identifier (or the code itself)."""
        if isinstance(code, BeaconCode):
            return code
        try:
            return self._codes[int(code)]
        except KeyError:
            raise KeyError(f"variance model: unknown code {code}; known {sorted(self._codes)}") from None

    def variance(self, code: int | BeaconCode, angular_window_rad: ArrayLike) -> np.ndarray | float:
        """Bearing variance (rad^2) for a code (id or object) and angular window(s) (rad)."""
        if self.mode == "exact":
            return self.artificial_variance_rad2(code, angular_window_rad) + self.natural_variance(
                angular_window_rad
            )
        if self.mode == "bound":
            return self.bound_rad2(code) + self.natural_variance(angular_window_rad)
        value = self.constant_variance_rad2
        return value if np.ndim(angular_window_rad) == 0 else np.full(np.shape(angular_window_rad), value)

    def natural_variance(self, angular_window_rad: ArrayLike) -> np.ndarray | float:
        """The natural (edge noise) variance (rad^2) at angular window(s) (rad): constant, or linear in the
        window (sections 5.5-5.6: the rising edge's noise grows with the window), at least 0."""
        if self.natural_variance_slope_rad2_per_rad == 0.0:
            if np.ndim(angular_window_rad) == 0:
                return self.natural_variance_rad2
            return np.full(np.shape(angular_window_rad), self.natural_variance_rad2)
        offset = np.asarray(angular_window_rad, dtype=float) - self.natural_variance_reference_window_rad
        value = np.maximum(
            self.natural_variance_rad2 + self.natural_variance_slope_rad2_per_rad * offset, 0.0
        )
        return float(value) if value.ndim == 0 else value

    def artificial_variance_rad2(
        self, code: int | BeaconCode, angular_window_rad: ArrayLike
    ) -> np.ndarray | float:
        """The OOK part alone (chapter 4), without the natural variance."""
        code = self.code(code)
        family = self._family(code)
        if family is not None:
            phi0 = code.bit_time_s * self.turret_speed_rad_s
            ratio = np.maximum(angular_window_rad, 0.0) / phi0
            normalized = family_normalized_variance(family[0], family[1], ratio)
            return normalized * code.variance_bound_s2 * self.turret_speed_rad_s**2
        window = np.asarray(angular_window_rad, dtype=float)
        lookup = self._lookups.get(code.code_id)
        if lookup is None:
            lookup = self._lookups.setdefault(code.code_id, _EnumeratedLookup(code, self._min_burst_s(code)))
        result = lookup(window / self.turret_speed_rad_s) * self.turret_speed_rad_s**2
        return float(result) if result.ndim == 0 else result

    def window_variance_rad2(
        self, code: int | BeaconCode, angular_window_rad: ArrayLike
    ) -> np.ndarray | float:
        """OOK variance (rad^2) of the decoded window (chapter 3): each outer edge late by e over a gap
        stretched by the minimum burst, bearing error (e_r - e_f) / 2 and window error -(e_r + e_f), so
        Var(window) = 4 Var(e) - 4 Var(bearing)."""
        code = self.code(code)
        mean_delay_rad = 0.5 * self._receiver.window_shortening_s(code) * self.turret_speed_rad_s
        edge_variance = 2.0 * self.bound_rad2(code) - mean_delay_rad**2
        artificial = np.asarray(self.artificial_variance_rad2(code, angular_window_rad))
        result = np.maximum(4.0 * (edge_variance - artificial), 0.0)
        return float(result) if result.ndim == 0 else result

    def bound_rad2(self, code: int | BeaconCode) -> float:
        """Theorem 3.1 for the code, with gaps stretched by the minimum detectable burst (section 5.6)."""
        code = self.code(code)
        gaps_s = np.array(code.gap_bits, dtype=float) * code.bit_time_s + self._min_burst_s(code)
        return float(np.sum(gaps_s**3) / (6.0 * code.duration_s)) * self.turret_speed_rad_s**2

    def _min_burst_s(self, code: BeaconCode) -> float:
        return self._receiver.min_burst_s(code)

    def _family(self, code: BeaconCode) -> tuple[int, int] | None:
        """(i, Nc) when the closed form applies to this code, else None."""
        if self._codes.get(code.code_id) is code:
            return self._families[code.code_id]
        return is_family_code(code) if self.min_burst_fraction == 0.0 else None


# (rising, falling) edge-noise variances (rad^2) of a code's window: what the power-bias correction's
# variance needs of the receiver
EdgeVariances = Callable[[BeaconCode, float], tuple[float, float]]


@dataclass(frozen=True)
class CorrectedVariance:
    """The variance (rad^2) of a bearing the power-bias correction f(w^) moved (eq. 7.18, 7.19), to first
    order with f' = `BearingCorrection.power_bias_slope`:

        Var(phi^ - f(w^)) = Var(phi^) + f'^2 Var(w^) - 2 f' Cov(phi^, w^),

    phi^ = (r + f) / 2 and w^ = f - r (eq. 2.5) with independent edge noises: Var(w^) = sigma_r^2 +
    sigma_f^2 (plus the code's `window_variance_rad2`), Cov = (sigma_f^2 - sigma_r^2) / 2.
    """

    model: VarianceModel
    correction: BearingCorrection
    edge_variances_rad2: EdgeVariances

    def variance(self, code: int | BeaconCode, angular_window_rad: float) -> float:
        variance = float(self.model.variance(code, angular_window_rad))
        slope = float(self.correction.power_bias_slope(angular_window_rad))
        if slope == 0.0:
            return variance
        code = self.model.code(code)
        rising, falling = self.edge_variances_rad2(code, angular_window_rad)
        window_variance = rising + falling + float(self.model.window_variance_rad2(code, angular_window_rad))
        return variance + slope**2 * window_variance + slope * (rising - falling)


def split_natural_variance(model: VarianceModel, rising_share: Callable[[float], float]) -> EdgeVariances:
    """The model's natural variance, (sigma_r^2 + sigma_f^2) / 4 (eq. 3.13 with independent edges), as
    the two edges' variances, the rising edge's share of them given by `rising_share(window)`."""

    def edge_variances(code: BeaconCode, angular_window_rad: float) -> tuple[float, float]:
        edges = 4.0 * float(model.natural_variance(angular_window_rad))
        share = rising_share(angular_window_rad)
        return edges * share, edges * (1.0 - share)

    return edge_variances
