"""The band a consistent filter's mean NEES over a time window falls in, its samples being correlated.

N independent samples give chi2(n N) / N (Bar-Shalom, Li and Kirubarajan 2001, 5.4.2); correlated ones vary
as N_eff = N / tau_N, tau_N = 1 + 2 sum_{j=1}^{N-1} (1 - j / N) rho(j) (Sokal 1997, section 3; rho pooled
over runs, cut at Sokal's window). `gaussian_window_band`, the Monte-Carlo band of a Gaussian error of that
autocorrelation, is the one the benches use (docs/self_calibration.md says why).
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import chi2

# Sokal's window: the autocorrelation summed up to the first lag M >= SOKAL_WINDOW_C * tau(M)
SOKAL_WINDOW_C = 5.0
# a pose's NEES: x, y, heading
POSE_DOF = 3


@dataclass(frozen=True)
class NeesCorrelation:
    """The NEES's autocorrelation (lags 0..M, in samples, M Sokal's window) and its sampling, estimated
    from one or more runs: what the band of a window mean needs."""

    autocorrelation: np.ndarray  # rho(0) = 1, rho(1), ..., rho(M)
    sample_interval_s: float
    samples: int  # over all runs
    # True when Sokal's window was found before the longest lag the runs allow
    converged: bool
    dof: int = POSE_DOF

    @property
    def tau_samples(self) -> float:
        """The integrated autocorrelation time 1 + 2 sum_{j=1}^{M} rho(j) (samples), at least 1: a
        Gaussian error's NEES is never anti-correlated (rho = |C|_F^2 / n)."""
        return max(1.0 + 2.0 * float(np.sum(self.autocorrelation[1:])), 1.0)

    @property
    def tau_s(self) -> float:
        """The integrated autocorrelation time in seconds."""
        return self.tau_samples * self.sample_interval_s

    def effective_samples(self, window_s: float) -> float:
        """N_eff = N / tau_N of a window of window_s seconds (N samples), tau_N with the finite
        window's weights (1 - j / N): the independent samples its mean is worth."""
        n = max(window_s / self.sample_interval_s, 1.0)
        lags = np.arange(1, min(len(self.autocorrelation), int(np.ceil(n))))
        tau_n = 1.0 + 2.0 * float(np.sum((1.0 - lags / n) * self.autocorrelation[lags]))
        return n / max(tau_n, 1.0)

    def band(self, window_s: float, probability: float = 0.95) -> tuple[float, float]:
        """The two-sided `probability` band of a consistent filter's mean NEES over window_s seconds:
        chi2.ppf((1 -+ p) / 2, dof N_eff) / N_eff (Bar-Shalom et al. 5.4.2, N_eff for N)."""
        return chi_square_mean_band(self.effective_samples(window_s), probability, self.dof)


def chi_square_mean_band(
    effective_samples: float, probability: float = 0.95, dof: int = POSE_DOF
) -> tuple[float, float]:
    """Two-sided band of the mean of `effective_samples` independent chi-square (dof) draws."""
    tails = np.array([(1.0 - probability) / 2.0, (1.0 + probability) / 2.0])
    low, high = chi2.ppf(tails, dof * effective_samples) / effective_samples
    return float(low), float(high)


def _autocovariance_sums(values: np.ndarray) -> np.ndarray:
    """sum_k x_k x_(k+j) for every lag j of one series (FFT, zero-padded: no circular wrap)."""
    spectrum = np.fft.rfft(values, 2 * len(values))
    return np.fft.irfft(spectrum * np.conj(spectrum))[: len(values)]


def nees_correlation(
    runs: Sequence[tuple[ArrayLike, ArrayLike]], dof: int = POSE_DOF, window_c: float = SOKAL_WINDOW_C
) -> NeesCorrelation:
    """The NEES's autocorrelation pooled over runs, each (stamps_s, nees) in time order.

    rho(j) = sum over runs and k of (x_k - m)(x_(k+j) - m) / sum of (x_k - m)^2, m the pooled mean (the
    biased estimator: its error shrinks at long lags); cut at Sokal's window."""
    series = [np.asarray(nees, dtype=float) for _, nees in runs]
    stamps = [np.asarray(t, dtype=float) for t, _ in runs]
    if not series or any(len(v) < 2 or len(v) != len(t) for v, t in zip(series, stamps, strict=True)):
        raise ValueError("nees_correlation: every run needs two or more (stamp, NEES) samples")
    if not all(np.all(np.isfinite(v)) for v in series):
        raise ValueError("nees_correlation: a NEES is not finite")
    mean = float(np.mean(np.concatenate(series)))
    longest = max(len(v) for v in series)
    sums = np.zeros(longest)
    for values in series:
        sums[: len(values)] += _autocovariance_sums(values - mean)
    if not sums[0] > 0.0:
        raise ValueError("nees_correlation: the NEES does not vary")
    rho = sums / sums[0]
    taus = 1.0 + 2.0 * np.cumsum(rho[1:])
    lags = np.arange(1, longest)
    within = np.nonzero(lags >= window_c * taus)[0]
    window = int(lags[within[0]]) if len(within) else longest - 1
    duration_s = sum(float(t[-1] - t[0]) for t in stamps)
    interval_s = duration_s / sum(len(t) - 1 for t in stamps)
    if not interval_s > 0.0:
        raise ValueError("nees_correlation: the stamps do not advance")
    return NeesCorrelation(
        rho[: window + 1].copy(), interval_s, sum(map(len, series)), bool(len(within)), dof
    )


def window_means(
    stamps_s: ArrayLike,
    nees: ArrayLike,
    windows_s: Sequence[tuple[float, float]],
    origin_s: float | None = None,
) -> list[float | None]:
    """The mean NEES over each window [start, end) of time since origin_s (default: the first stamp);
    None for an empty one."""
    t = np.asarray(stamps_s, dtype=float)
    values = np.asarray(nees, dtype=float)
    t = t - (t[0] if origin_s is None else origin_s)
    means: list[float | None] = []
    for start_s, end_s in windows_s:
        keep = (t >= start_s) & (t < end_s)
        means.append(float(values[keep].mean()) if keep.any() else None)
    return means


def gaussian_window_band(
    correlation: NeesCorrelation,
    window_s: float,
    probability: float = 0.95,
    windows: int = 20000,
    seed: int = 0,
) -> tuple[float, float]:
    """The Monte-Carlo band of a consistent filter's mean NEES over window_s seconds: the quantiles of the
    window means of a stationary Gaussian error whose NEES has `correlation`'s autocorrelation, skew included.
    Its `dof` components are independent, each of autocorrelation sqrt(rho(j)), drawn by circulant embedding
    (Dietrich and Newsam 1997, the spectrum's negative parts set to 0)."""
    rho = np.clip(correlation.autocorrelation, 0.0, None)
    r = np.sqrt(rho)
    n = max(round(window_s / correlation.sample_interval_s), 1)
    length = 1 << int(np.ceil(np.log2(max(64 * n, 4 * len(r)))))
    circle = np.zeros(length)
    circle[: len(r)] = r
    circle[length - len(r) + 1 :] = r[1:][::-1]
    spectrum = np.clip(np.fft.fft(circle).real, 0.0, None)
    scale = np.sqrt(spectrum / length) / np.sqrt(spectrum.mean())  # unit variance after the clipping
    rng = np.random.default_rng(seed)
    per_draw = length // n
    means: list[np.ndarray] = []
    while sum(map(len, means)) < windows:
        # each complex draw gives two independent components (its real and imaginary parts)
        draws = [np.fft.fft(scale * (rng.standard_normal(length) + 1j * rng.standard_normal(length)))]
        while 2 * len(draws) < correlation.dof:
            draws.append(np.fft.fft(scale * (rng.standard_normal(length) + 1j * rng.standard_normal(length))))
        components = [part for d in draws for part in (d.real, d.imag)][: correlation.dof]
        nees = np.sum(np.square(components), axis=0)
        means.append(nees[: per_draw * n].reshape(per_draw, n).mean(axis=1))
    tails = [(1.0 - probability) / 2.0, (1.0 + probability) / 2.0]
    low, high = np.quantile(np.concatenate(means), tails)
    return float(low), float(high)
