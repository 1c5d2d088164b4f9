"""The shared checks of beams_common.intake.validation: bounded reasons, the output covariance invariant, the
operator pose, one sighting per beacon; searched with generated values."""

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from beams_common.intake import pose_intake, validation
from beams_common.intake.validation import (
    MAX_REASON_CHARS,
    bounded,
    clearly_conditioned,
    covariance_problem,
    one_sighting_per_beacon,
    planar_estimate_problem,
)

ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64)
MATRICES = hnp.arrays(np.float64, (3, 3), elements=ANY_FLOAT)


@settings(max_examples=1000, deadline=None)
@given(st.text(max_size=5000))
def test_a_reason_is_bounded_and_a_short_one_unchanged(text):
    result = bounded(text)
    assert len(result) <= MAX_REASON_CHARS
    assert (result == text) == (len(text) <= MAX_REASON_CHARS)


@settings(max_examples=2000, deadline=None)
@given(MATRICES)
def test_a_covariance_passes_only_when_finite_symmetric_and_positive_definite(matrix):
    problem = covariance_problem(matrix)
    if problem:
        return
    assert np.all(np.isfinite(matrix))
    np.testing.assert_allclose(matrix, matrix.T, rtol=0.0, atol=1e-9 * np.max(np.abs(matrix)))
    scaled = matrix / np.max(np.abs(matrix))  # matrix + matrix.T overflows near the largest float
    assert np.all(np.linalg.eigvalsh(0.5 * (scaled + scaled.T)) > 0.0)


@settings(max_examples=1000, deadline=None)
@given(hnp.arrays(np.float64, (3, 3), elements=st.floats(-10.0, 10.0)), st.floats(1e-6, 10.0))
def test_every_gram_matrix_plus_a_ridge_passes(factor, ridge):
    """J J' + r I is what a propagated covariance looks like: always publishable."""
    assert covariance_problem(factor @ factor.T + ridge * np.eye(3)) == ""


def test_the_covariances_issue_15_published_are_refused():
    assert "all zero" in covariance_problem(np.zeros((3, 3)))
    assert "not positive definite" in covariance_problem(np.diag([1e-4, 1e-4, -1e-6]))
    assert "non-finite" in covariance_problem(np.diag([1e-4, math.nan, 1e-3]))
    assert "not symmetric" in covariance_problem(np.array([[1.0, 0.5, 0], [0.0, 1.0, 0], [0, 0, 1.0]]))
    assert "not three finite numbers" in planar_estimate_problem((math.nan, 0.0, 0.0), np.eye(3))


def _near_singular(seed: int) -> np.ndarray:
    """A Gram matrix with eigenvalues spread from 1 down to ~1e-18, turned at random, at a random scale."""
    rng = np.random.default_rng(seed)
    turn, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    spread = 10.0 ** rng.uniform(-18.0, 0.0, 3)
    return 10.0 ** rng.uniform(-300, 300) * (turn * spread) @ turn.T


_EDGE_COVARIANCES = [
    np.zeros((3, 3)),
    -np.eye(3),
    np.diag([1.0, 1.0, -1e-6]),
    np.diag([1.0, 1.0, 0.0]),
    np.diag([1.0, 1.0, -1e-10]),  # within the intake's semi-definite tolerance
    *(np.diag([1.0, 1.0, v]) for v in (1e-13, 1e-12, 1.5e-12, 2e-12, 3e-12, 1e-11, 1e-300)),
    np.diag([1e300, 1e300, 1e-300]),
    np.diag([1e-300, 2e-300, 3e-300]),
    np.diag([1e308, 1e308, 1e308]),
    np.diag([1.0, math.nan, 1.0]),
    np.diag([1.0, math.inf, 1.0]),
    np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),  # singular
    np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),  # not symmetric
    np.array([[1.0, 0.0, 0.0], [1e-10, 1.0, 0.0], [0.0, 0.0, 1.0]]),  # asymmetric within the tolerance
    np.array([[1.0, 0.0, 0.0], [-2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),  # a lower triangle not definite
    np.array([[1.0, 2.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),  # an upper triangle not definite
    np.array([[4e-6, 1e-6, 2e-8], [1e-6, 3e-6, -1e-8], [2e-8, -1e-8, 5e-9]]),  # an EKF's
    *(_near_singular(seed) for seed in range(200)),
]


def _decisions(matrix: np.ndarray) -> tuple:
    """What the three covariance checks answer (the published estimate's, a pose's, its information)."""
    kept = pose_intake.planar_pose_intake(pose_intake.PoseSource.TOTAL, 1.0, (1.0, 1.0, 0.0), matrix)
    return covariance_problem(matrix), kept.reason if isinstance(
        kept, pose_intake.RefusedPose
    ) else kept.covariance is None


@pytest.mark.parametrize("matrix", _EDGE_COVARIANCES)
def test_the_closed_form_check_decides_as_eigvalsh(matrix, monkeypatch):
    """The closed form only answers where eigvalsh would answer the same: each check's answer (accepted,
    refused and its reason) is the one it gives with eigvalsh alone, on the edge cases and near-singular
    matrices of every scale."""
    decided = _decisions(matrix)
    for module in (validation, pose_intake):
        monkeypatch.setattr(module, "clearly_conditioned", lambda *_: False)
    assert decided == _decisions(matrix)


@settings(max_examples=2000, deadline=None)
@given(MATRICES, st.sampled_from([0.0, 1e-12]))
def test_a_clearly_conditioned_matrix_is_so_for_eigvalsh(matrix, ratio):
    matrix = matrix / max(np.max(np.abs(matrix)), 1.0) if np.all(np.isfinite(matrix)) else matrix
    if clearly_conditioned(matrix, ratio):
        eigenvalues = np.linalg.eigvalsh(matrix)  # its lower triangle, as the closed form
        assert eigenvalues[0] > ratio * eigenvalues[-1] and eigenvalues[0] > 0.0


@dataclass(frozen=True)
class _Sighting:
    beacon_id: int
    stamp_s: float


@settings(max_examples=2000, deadline=None)
@given(st.lists(st.builds(_Sighting, st.integers(1, 4), st.sampled_from([0.0, 0.02, 0.05, 0.09, math.nan]))))
def test_one_sighting_per_beacon_keeps_each_beacon_once_and_loses_nothing(bearings):
    sightings = one_sighting_per_beacon(bearings)
    kept_ids = [b.beacon_id for b in sightings.kept]
    assert sorted(kept_ids) == sorted(set(kept_ids)) == sorted({b.beacon_id for b in bearings})
    assert len(sightings.kept) + len(sightings.dropped) == len(bearings)
    for beacon_id in sightings.conflicting_ids:
        stamps = [b.stamp_s for b in bearings if b.beacon_id == beacon_id]
        assert len(stamps) != len(set(stamps))
