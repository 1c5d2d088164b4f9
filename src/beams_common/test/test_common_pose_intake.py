"""The pose intake: each rule once (frame, finiteness, covariance), a kept pose or a refusal with its
kind, reason and counter key, for ToTal's and an operator's poses alike."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.intake.plausibility import MAX_POSE_SIGMA_M, MAX_POSE_SIGMA_RAD
from beams_common.intake.pose_intake import (
    KeptPose,
    PoseRefusal,
    PoseSource,
    RefusedPose,
    planar_pose_intake,
    pose_covariance_problem,
    pose_intake,
)

MAP = "map"
QUARTER_TURN = (0.0, 0.0, math.sin(math.pi / 8), math.cos(math.pi / 8))  # yaw pi/4
RVIZ = np.diag([0.25, 0.25, 0.0, 0.0, 0.0, 0.06853891945200942]).ravel().tolist()
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64)


def _ros(planar: np.ndarray) -> list[float]:
    full = np.zeros((6, 6))
    full[np.ix_((0, 1, 5), (0, 1, 5))] = planar
    return full.ravel().tolist()


def _intake(covariance=RVIZ, *, frame=MAP, position=(1.0, 0.5, 0.0), quaternion=QUARTER_TURN, source=None):
    return pose_intake(source or PoseSource.OPERATOR, frame, MAP, 12.5, position, quaternion, covariance)


def test_a_good_pose_is_kept_planar_with_its_covariance():
    kept = _intake()
    assert isinstance(kept, KeptPose) and kept.operator and kept.stamp_s == 12.5
    np.testing.assert_allclose(kept.pose, (1.0, 0.5, math.pi / 4), atol=1e-12)
    np.testing.assert_allclose(kept.covariance, np.diag([0.25, 0.25, 0.06853891945200942]))
    total = _intake(source=PoseSource.TOTAL, frame="")  # an empty frame is the map's
    assert isinstance(total, KeptPose) and not total.operator


def test_a_sequence_of_well_formed_but_wrong_poses_each_refused_once_with_its_kind():
    """One run of poses as an operator (or a faulty relay) sends them: the good ones kept between."""
    asymmetric = np.diag([0.01, 0.01, 0.01])
    asymmetric[0, 1] = 0.005
    sequence = [
        (_intake(), None),
        (_intake(frame="odom"), PoseRefusal.WRONG_FRAME),
        (_intake(position=(math.nan, 0.0, 0.0)), PoseRefusal.INVALID),
        (_intake(quaternion=(0.0, 0.0, 0.0, 0.0)), PoseRefusal.INVALID),
        (_intake(_ros(np.diag([0.01, math.inf, 0.01]))), PoseRefusal.INVALID),
        (_intake(_ros(asymmetric)), PoseRefusal.COVARIANCE),
        (_intake(_ros(np.diag([0.01, -0.01, 0.01]))), PoseRefusal.COVARIANCE),  # a negative variance
        (_intake(_ros(np.diag([1e12, 1e12, 0.01]))), PoseRefusal.COVARIANCE),  # wedged the filter
        (_intake(_ros(np.diag([0.01, 0.01, 100.0]))), PoseRefusal.COVARIANCE),  # sigma 10 rad
        (_intake([0.0] * 36), None),  # RViz's zeros: kept, the default replaces the covariance
        (_intake(), None),
    ]
    for answer, refusal in sequence:
        if refusal is None:
            assert isinstance(answer, KeptPose), answer
        else:
            assert isinstance(answer, RefusedPose) and answer.refusal is refusal, answer
            assert answer.counter_key == f"operator_poses_{refusal}" and answer.reason
    assert sequence[-2][0].covariance is None
    counts = [a.counter_key for a, _ in sequence if isinstance(a, RefusedPose)]
    assert counts.count("operator_poses_covariance") == 4 and counts.count("operator_poses_invalid") == 3


def test_the_bound_is_the_table_and_a_turn():
    assert pose_covariance_problem(np.diag([MAX_POSE_SIGMA_M**2] * 2 + [MAX_POSE_SIGMA_RAD**2])) == ""
    for huge in (1e12, 1e300):
        assert "beyond 4 m" in pose_covariance_problem(np.diag([huge, huge, 0.01]))
    assert "beyond" in pose_covariance_problem(np.diag([0.01, (MAX_POSE_SIGMA_M * 1.01) ** 2, 0.01]))
    assert "beyond" in pose_covariance_problem(np.diag([0.01, 0.01, (MAX_POSE_SIGMA_RAD * 1.01) ** 2]))


@settings(max_examples=500, deadline=None)
@given(
    st.lists(ANY_FLOAT, min_size=3, max_size=3),
    st.lists(ANY_FLOAT, min_size=4, max_size=4),
    st.lists(ANY_FLOAT, min_size=36, max_size=36),
    st.sampled_from(list(PoseSource)),
)
def test_anything_kept_is_finite_symmetric_semi_definite_and_bounded(
    position, quaternion, covariance, source
):
    """NaN, inf or anything anywhere: a pose is kept only when every field is finite, and its covariance
    is then one the filter can take (or None)."""
    answer = pose_intake(source, MAP, MAP, 3.0, position, quaternion, covariance)
    finite = all(map(math.isfinite, (*position, *quaternion, *covariance)))
    if not finite or math.hypot(*quaternion) < 1e-6:
        assert isinstance(answer, RefusedPose) and answer.refusal is PoseRefusal.INVALID
        return
    if isinstance(answer, RefusedPose):
        assert answer.refusal is PoseRefusal.COVARIANCE and answer.counter_key == f"{source}_poses_covariance"
        return
    assert all(map(math.isfinite, answer.pose)) and -math.pi <= answer.pose[2] <= math.pi
    if answer.covariance is not None:
        matrix = answer.covariance
        np.testing.assert_allclose(matrix, matrix.T, rtol=1e-8, atol=1e-300)
        assert np.all(np.linalg.eigvalsh(matrix / np.max(np.abs(matrix))) > 0.0)
        assert (
            max(matrix[0, 0], matrix[1, 1]) <= MAX_POSE_SIGMA_M**2 and matrix[2, 2] <= MAX_POSE_SIGMA_RAD**2
        )


@settings(max_examples=300, deadline=None)
@given(
    st.floats(1e-8, MAX_POSE_SIGMA_M**2),
    st.floats(1e-8, MAX_POSE_SIGMA_RAD**2),
    st.floats(-0.99, 0.99),
    st.floats(1.0, 1e300),
    st.floats(1e-6, 1.0),
)
def test_a_covariance_is_refused_exactly_when_asymmetric_negative_or_beyond(
    var_m2, var_rad2, rho, scale, skew
):
    """Within the bound and symmetric positive definite: kept as given; scaled beyond the bound, made
    asymmetric or given a negative variance: refused as a covariance."""
    good = np.diag([var_m2, var_m2, var_rad2])
    good[0, 1] = good[1, 0] = rho * var_m2
    kept = planar_pose_intake(PoseSource.TOTAL, 1.0, (0.5, 0.5, 0.1), good)
    assert isinstance(kept, KeptPose)
    np.testing.assert_array_equal(kept.covariance, good)
    asymmetric = good.copy()
    asymmetric[0, 1] += skew * var_m2
    negative = good.copy()
    negative[2, 2] = -var_rad2
    huge = good * (scale + MAX_POSE_SIGMA_M**2 / var_m2 * 1.01)
    for bad in (asymmetric, negative, huge):
        answer = planar_pose_intake(PoseSource.TOTAL, 1.0, (0.5, 0.5, 0.1), bad)
        assert isinstance(answer, RefusedPose) and answer.refusal is PoseRefusal.COVARIANCE, bad
        assert answer.counter_key == "total_poses_covariance"


@given(st.sampled_from(["odom", "base_link", "Map", " map", "map/"]), st.sampled_from(list(PoseSource)))
def test_a_pose_in_another_frame_is_refused_whatever_else_it_holds(frame, source):
    for covariance in (RVIZ, [math.nan] * 36):
        answer = _intake(covariance, frame=frame, source=source)
        assert isinstance(answer, RefusedPose) and answer.refusal is PoseRefusal.WRONG_FRAME
        assert repr(frame) in answer.reason and answer.counter_key == f"{source}_poses_wrong_frame"


@given(st.lists(ANY_FLOAT, min_size=3, max_size=3), ANY_FLOAT)
def test_a_planar_pose_or_stamp_not_finite_is_invalid(pose, stamp_s):
    answer = planar_pose_intake(PoseSource.TOTAL, stamp_s, tuple(pose), np.eye(3) * 1e-4)
    finite = all(map(math.isfinite, (*pose, stamp_s)))
    assert isinstance(answer, KeptPose) == finite
    if not finite:
        assert answer.refusal is PoseRefusal.INVALID and answer.counter_key == "total_poses_invalid"


def test_a_huge_but_finite_quaternion_is_its_normalised_rotation():
    """Found by hypothesis: entries near 1e291 overflowed the yaw's products to NaN (refused as 'not
    finite' although every field was); the quaternion is normalised first, as its rotation is."""
    quaternion = [0.0, 0.0, 6.2e291, 6.2e291]  # 90 degrees about z, scaled
    answer = pose_intake(PoseSource.TOTAL, MAP, MAP, 3.0, [1.0, 2.0, 0.0], quaternion, [0.0] * 36)
    assert not isinstance(answer, RefusedPose)
    assert math.isclose(answer.pose[2], math.pi / 2, rel_tol=1e-12)
