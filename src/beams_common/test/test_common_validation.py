"""The shared checks of beams_common.intake.validation: bounded reasons, the output covariance invariant, the
operator pose, one sighting per beacon; searched with generated values."""

import math
from dataclasses import dataclass

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from beams_common.intake.validation import (
    MAX_REASON_CHARS,
    bounded,
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
    assert np.all(np.linalg.eigvalsh(0.5 * (matrix + matrix.T)) > 0.0)


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
