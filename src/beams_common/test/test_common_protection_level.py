"""The protection level (beams_common.status.protection_level, docs/protection_level.md): Monte-Carlo on a
Gaussian model, fault-free and with one faulty measurement, the error exceeds it at most at its risk; it
grows with the covariance and shrinks as measurements are added; the alert limits decide the reason."""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.status.protection_level import INTEGRITY_SPECS, Integrity, ProtectionLevel, major_sigma_m

DEFAULTS = {spec.name: spec.default for spec in INTEGRITY_SPECS}
SAMPLES = 40_000
FAULTY_SAMPLES = 5_000  # one protection level per sample


def _integrity(risk: float) -> Integrity:
    return Integrity({**DEFAULTS, "integrity_risk": risk})


def _covariance(rng: np.random.Generator, scale: float) -> np.ndarray:
    a = rng.normal(size=(3, 3)) * scale
    return a @ a.T + np.diag([1e-8, 1e-8, 1e-10])


def _exceeded(errors: np.ndarray, levels: np.ndarray | ProtectionLevel) -> tuple[float, float]:
    """Shares of the samples whose horizontal and heading errors exceed their bounds."""
    h = levels[:, 0] if isinstance(levels, np.ndarray) else levels.horizontal_m
    theta = levels[:, 1] if isinstance(levels, np.ndarray) else levels.heading_rad
    return float(np.mean(np.hypot(errors[:, 0], errors[:, 1]) > h)), float(np.mean(abs(errors[:, 2]) > theta))


def _allowed(risk: float, samples: int = SAMPLES) -> float:
    """The risk plus four binomial standard deviations of the Monte-Carlo share."""
    return risk + 4.0 * math.sqrt(risk * (1.0 - risk) / samples)


def test_the_quantiles_are_the_rayleigh_and_gaussian_ones():
    integrity = _integrity(1e-5)
    assert math.isclose(integrity.k_horizontal, 4.7985, rel_tol=1e-4)  # sqrt(chi2.ppf(1 - 1e-5, 2))
    assert math.isclose(integrity.k_heading, 4.4172, rel_tol=1e-4)  # norm.isf(0.5e-5)
    assert major_sigma_m(np.array([np.diag([4.0, 9.0, 1.0]), [[2.0, 1.0, 0], [1.0, 2.0, 0], [0, 0, 1]]])) == (
        pytest.approx([3.0, math.sqrt(3.0)])
    )


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), risk=st.sampled_from([1e-3, 1e-2, 5e-2]), scale=st.floats(1e-3, 1.0))
def test_fault_free_the_error_exceeds_the_bound_at_most_at_its_risk(seed, risk, scale):
    rng = np.random.default_rng(seed)
    covariance = _covariance(rng, scale)
    level = _integrity(risk).level(covariance)
    assert not level.faults_covered
    errors = rng.multivariate_normal(np.zeros(3), covariance, SAMPLES)
    horizontal, heading = _exceeded(errors, level)
    assert horizontal <= _allowed(risk) and heading <= _allowed(risk), (horizontal, heading)


def test_the_horizontal_bound_is_tight_for_a_circular_covariance():
    """Rayleigh: a circular position covariance meets its risk exactly (the bound is not padded)."""
    rng = np.random.default_rng(3)
    level = _integrity(1e-2).level(np.diag([1e-4, 1e-4, 1e-6]))
    horizontal, heading = _exceeded(
        rng.multivariate_normal(np.zeros(3), np.diag([1e-4, 1e-4, 1e-6]), SAMPLES), level
    )
    assert 0.7e-2 <= horizontal <= 1.3e-2 and 0.7e-2 <= heading <= 1.3e-2


def _separated_solutions(h: np.ndarray, r: np.ndarray, z: np.ndarray):
    """Weighted least squares with every measurement (n, 3 unknowns) and without each one in turn: the
    all-in-view estimates (k, 3) and covariance, the shifts (k, n, 3) and separated covariances (n, 3, 3)."""

    def solve(rows: np.ndarray):
        weighted = h[rows].T / r[rows]
        covariance = np.linalg.inv(weighted @ h[rows])
        return z[:, rows] @ (covariance @ weighted).T, covariance

    everything, covariance = solve(np.arange(len(r)))
    without = [solve(np.delete(np.arange(len(r)), i)) for i in range(len(r))]
    shifts = np.stack([everything - estimate for estimate, _ in without], axis=1)
    return everything, covariance, shifts, np.array([c for _, c in without])


@settings(max_examples=6, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    faulty=st.integers(0, 5),
    bias_sigmas=st.sampled_from([0.0, 2.0, 5.0, 20.0, 1e3]),
    risk=st.sampled_from([1e-2, 5e-2]),
)
def test_with_one_faulty_measurement_the_error_exceeds_the_bound_at_most_at_its_risk(
    seed, faulty, bias_sigmas, risk
):
    """Six measurements of three unknowns, one of them biased by any amount (of its own sigmas): the
    solution separation's bound still holds at its risk (the fault-free one alone does not)."""
    rng = np.random.default_rng(seed)
    h = rng.normal(size=(6, 3))
    r = rng.uniform(0.5, 2.0, size=6) * 1e-4
    noise = rng.normal(size=(FAULTY_SAMPLES, 6)) * np.sqrt(r)
    noise[:, faulty] += bias_sigmas * math.sqrt(r[faulty])
    errors, covariance, shifts, separated = _separated_solutions(
        h, r, noise[:FAULTY_SAMPLES]
    )  # the truth is zero
    integrity = _integrity(risk)
    levels = [integrity.level(covariance, shifts[k], separated) for k in range(FAULTY_SAMPLES)]
    bounds = np.array([(level.horizontal_m, level.heading_rad) for level in levels])
    horizontal, heading = _exceeded(errors, bounds)
    allowed = _allowed(risk, FAULTY_SAMPLES)
    assert horizontal <= allowed and heading <= allowed, (horizontal, heading)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scale=st.floats(1e-3, 1.0))
def test_the_bound_grows_with_the_covariance(seed, scale):
    rng = np.random.default_rng(seed)
    integrity = _integrity(1e-5)
    covariance, more = _covariance(rng, scale), _covariance(rng, scale)
    low, high = integrity.level(covariance), integrity.level(covariance + more)
    assert high.horizontal_m >= low.horizontal_m * (1 - 1e-12)
    assert high.heading_rad >= low.heading_rad * (1 - 1e-12)
    shift = rng.normal(size=(1, 3)) * scale
    faulty = integrity.level(covariance, shift, covariance[None] + more)
    assert faulty.horizontal_m >= low.horizontal_m and faulty.heading_rad >= low.heading_rad


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_the_fault_free_bound_shrinks_as_measurements_are_added(seed):
    rng = np.random.default_rng(seed)
    h, r = rng.normal(size=(7, 3)), rng.uniform(0.5, 2.0, size=7) * 1e-4
    integrity = _integrity(1e-5)
    levels = [integrity.level(np.linalg.inv((h[:n].T / r[:n]) @ h[:n])) for n in range(3, 8)]
    for fewer, more in itertools.pairwise(levels):
        assert more.horizontal_m <= fewer.horizontal_m * (1 + 1e-9)
        assert more.heading_rad <= fewer.heading_rad * (1 + 1e-9)


def test_the_alert_limits_make_the_reason():
    integrity = _integrity(1e-5)
    assert integrity.problem(None) == "" and integrity.problem(ProtectionLevel(0.05, math.radians(3.0))) == ""
    problem = integrity.problem(ProtectionLevel(0.062, 0.01))
    assert problem == (
        "protection level 62 mm / 0.57 deg above the alert limits 50 mm / 3.00 deg: "
        "unavailable for navigation"
    )
    assert not integrity.within(ProtectionLevel(0.01, math.radians(3.5)))
    assert not integrity.within(ProtectionLevel(math.nan, 0.0))
