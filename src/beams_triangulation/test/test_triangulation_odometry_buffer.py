"""The odometry the triangulation compensates with (odometry_buffer), a revolution it does not cover (its
pose rejected), the pipeline triangulation_node and the replay run (a revolution waits for the odometry
covering it), and the parameters -> settings mapping they share."""

import math
import pathlib

import numpy as np
import pytest
import yaml

from beams_common.config.parameters import node_section
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.bearing import Bearing
from beams_common.geometry.pose2d import between
from beams_common.geometry.pose_buffer import PoseBuffer
from beams_triangulation.gating import REASON_NOT_COMPENSATED, GateConfig, PoseEstimate
from beams_triangulation.motion_compensation import odometry_buffer
from beams_triangulation.pipeline import (
    RevolutionEstimator,
    TriangulationPipeline,
    TriangulationSettings,
    triangulation_settings,
)
from beams_triangulation.revolution import estimate_revolution
from beams_triangulation.total import expected_bearings

ODOM_IN_MAP = (0.5, 0.2, 0.4)  # where the odometry frame stands in the map
SPEED_MPS, YAW_RATE_RAD_S = 0.5, 2.0  # a Eurobot robot at full speed and yaw rate
VARIANCE_RAD2 = np.deg2rad(0.1) ** 2
# the shipped parameter file (beams_bringup), this node's section
CONFIG = pathlib.Path(__file__).resolve().parents[2] / "beams_bringup" / "config" / "beams_params.yaml"


def _truth(t: float) -> tuple[float, float, float]:
    """The robot on a circle of radius 0.25 m at constant twist (0.5 m/s, 2 rad/s)."""
    heading = 0.3 + YAW_RATE_RAD_S * t
    return (1.5 + 0.25 * math.sin(heading), 1.0 - 0.25 * math.cos(heading), heading)


def _odometry(t: float) -> tuple[float, float, float]:
    return between(ODOM_IN_MAP, _truth(t))


def _buffer(start_s: float, stop_s: float, span_s: float = 2.0) -> PoseBuffer:
    """50 Hz odometry from start_s to stop_s (inclusive)."""
    odometry = odometry_buffer(span_s, max_extrapolation_s=0.05)
    for t in np.arange(start_s, stop_s + 1e-9, 0.02):
        odometry.add(float(t), _odometry(float(t)), (SPEED_MPS, YAW_RATE_RAD_S))
    return odometry


def _revolution(start_s: float) -> list[Bearing]:
    """Each beacon's exact bearing at its own instant of a 0.1 s revolution."""
    stamps = (start_s + 0.01, start_s + 0.04, start_s + 0.075)
    return [
        Bearing(
            t,
            beacon_id,
            float(expected_bearings(EUROBOT_BEACON_MAP.subset([beacon_id]), _truth(t))[0]),
            VARIANCE_RAD2,
        )
        for beacon_id, t in zip(EUROBOT_BEACON_MAP.ids, stamps, strict=True)
    ]


def _position_error(estimate: PoseEstimate, t: float) -> float:
    true = _truth(t)
    return math.hypot(estimate.x - true[0], estimate.y - true[1])


def test_buffer_interpolates_and_extrapolates_along_the_arc():
    """Between samples: linear (error of the chord, < 0.1 mm over 20 ms); past the newest, the last
    twist's arc, exact for a constant twist; past max_extrapolation_s or before the oldest: None."""
    odometry = _buffer(0.0, 1.0)
    assert len(odometry) == 51
    between_samples = odometry.pose_at(0.51)
    assert math.dist(between_samples[:2], _odometry(0.51)[:2]) < 1e-4
    assert odometry.pose_at(0.5) == pytest.approx(_odometry(0.5), abs=1e-12)
    assert odometry.pose_at(1.04) == pytest.approx(_odometry(1.04), abs=1e-12)
    assert odometry.pose_at(1.06) is None
    assert odometry.pose_at(-0.001) is None


def test_buffer_drops_stale_and_non_finite_samples_and_restarts_on_a_clock_jump_not_a_stray():
    odometry = _buffer(10.0, 11.0, span_s=0.5)
    assert odometry.pose_at(10.4) is None  # older than the span
    newest = odometry.pose_at(11.0)
    odometry.add(10.99, (9.0, 9.0, 0.0), (0.0, 0.0))  # late: dropped
    odometry.add(11.02, (math.nan, 0.0, 0.0), (0.0, 0.0))  # not finite: ignored
    assert odometry.pose_at(11.0) == newest and odometry.pose_at(11.01) is not None
    odometry.add(2.0, (1.0, 2.0, 0.5), (0.0, 0.0))  # 9 s back, alone: a stray message, dropped
    odometry.add(11.03, (7.0, 7.0, 0.0), (0.0, 0.0))
    assert odometry.pose_at(11.0) == pytest.approx(newest, abs=1e-9)
    assert odometry.pose_at(11.03) == (7.0, 7.0, 0.0)
    odometry.add(2.0, (1.0, 2.0, 0.5), (0.0, 0.0))  # 9 s back, and again: a new start (a bag loop)
    assert odometry.pose_at(11.0) is not None
    odometry.add(2.02, (1.0, 2.0, 0.5), (0.0, 0.0))
    assert len(odometry) == 1
    assert odometry.pose_at(11.0) is None
    assert odometry.pose_at(2.02) == (1.0, 2.0, 0.5)


def test_covered_revolution_is_compensated_and_accepted():
    outcome = RevolutionEstimator(EUROBOT_BEACON_MAP).update(_revolution(0.5), _buffer(0.0, 1.0).pose_at)
    assert outcome.compensated and outcome.result.accepted
    assert _position_error(outcome.result, outcome.stamp_s) < 1e-3


def test_revolution_odometry_does_not_cover_is_rejected_with_the_reason():
    """Start-up: the first revolution ends before the first odometry. Its uncompensated pose is
    13 cm off with a position std of 5 mm, so with odometry in use it is published rejected;
    without odometry (nothing to wait for) the same pose is accepted."""
    odometry = _buffer(0.1, 1.0)  # odometry starts after the revolution
    estimator = RevolutionEstimator(EUROBOT_BEACON_MAP)
    outcome = estimator.update(_revolution(0.0), odometry.pose_at)
    estimate = outcome.result
    assert isinstance(estimate, PoseEstimate) and not outcome.compensated
    assert not estimate.accepted and estimate.reason == REASON_NOT_COMPENSATED
    assert _position_error(estimate, outcome.stamp_s) > 0.1 > 20 * estimate.position_std_m  # 130 mm, 4.7 mm
    without = estimate_revolution(_revolution(0.0), EUROBOT_BEACON_MAP).result
    assert without.accepted and (without.x, without.y) == (estimate.x, estimate.y)
    # the next revolution the odometry covers is accepted again (after the motion-inflated one above)
    assert estimator.update(_revolution(0.5), odometry.pose_at).result.accepted


def test_a_gate_rejection_keeps_its_reason_first():
    tight = GateConfig(max_inverse_abs_d=1e-6)
    estimate = estimate_revolution(
        _revolution(0.0), EUROBOT_BEACON_MAP, tight, odometry_at=_buffer(0.5, 1.0).pose_at
    ).result
    assert not estimate.accepted
    assert estimate.reason.startswith("1/|D|") and estimate.reason.endswith(REASON_NOT_COMPENSATED)


def test_settings_from_the_node_parameter_file():
    """Every value of the triangulation_node section of beams_params.yaml reaches the settings; a missing one
    takes its default."""
    parameters = node_section(yaml.safe_load(CONFIG.read_text()), "triangulation_node")
    settings = triangulation_settings({**parameters, "max_position_std_m": 0.07, "use_odometry": False})
    assert settings.gates == GateConfig(parameters["max_inverse_abs_d"], 0.07)
    assert settings.use_odometry is False
    assert settings.odometry_history_s == parameters["odometry_history_s"]
    assert settings.max_odometry_extrapolation_s == parameters["max_odometry_extrapolation_s"]
    assert triangulation_settings({}) == TriangulationSettings()
    with pytest.raises(ValueError):
        triangulation_settings({"max_inverse_abs_d": 0.0})


def _odometry_messages(start_s: float, stop_s: float):
    return [
        (float(t), _odometry(float(t)), (SPEED_MPS, YAW_RATE_RAD_S))
        for t in np.arange(start_s, stop_s + 1e-9, 0.02)
    ]


def test_pipeline_result_does_not_depend_on_arrival_order():
    """A revolution that arrives before the odometry covering its last bearing waits for it: the same
    pose, bit for bit, as when the odometry came first (the node over DDS, the replay by stamp)."""
    settings = TriangulationSettings()
    odometry_first = TriangulationPipeline(EUROBOT_BEACON_MAP, settings)
    revolution_first = TriangulationPipeline(EUROBOT_BEACON_MAP, settings)
    for sample in _odometry_messages(0.0, 0.5):
        assert odometry_first.on_odometry(*sample) == revolution_first.on_odometry(*sample) == []
    late = _odometry_messages(0.52, 0.6)
    for sample in late:
        odometry_first.on_odometry(*sample)
    [(tag, expected)] = odometry_first.on_revolution(7, _revolution(0.5))
    assert tag == 7 and expected.compensated and expected.result.accepted
    assert revolution_first.on_revolution(7, _revolution(0.5)) == []  # last bearing at 0.575 s: waits
    [(tag, waited)] = [c for sample in late for c in revolution_first.on_odometry(*sample)]
    assert tag == 7 and waited.stamp_s == expected.stamp_s and waited.compensated
    pose = (waited.result.x, waited.result.y, waited.result.heading, waited.result.covariance.tobytes())
    assert pose == (
        expected.result.x,
        expected.result.y,
        expected.result.heading,
        expected.result.covariance.tobytes(),
    )
    assert _position_error(expected.result, expected.stamp_s) < 1e-3
    assert odometry_first.revolutions_before_odometry == revolution_first.revolutions_before_odometry == 0


def test_pipeline_waits_at_most_until_the_next_revolution():
    """Odometry stopped: the waiting revolution goes out, rejected, when the next one arrives; without
    odometry in use nothing waits."""
    pipeline = TriangulationPipeline(EUROBOT_BEACON_MAP)
    for sample in _odometry_messages(0.0, 0.5):
        pipeline.on_odometry(*sample)
    assert pipeline.on_revolution(1, _revolution(0.55)) == []
    [(tag, outcome)] = pipeline.on_revolution(2, _revolution(0.65))
    assert tag == 1 and not outcome.result.accepted
    assert outcome.result.reason == REASON_NOT_COMPENSATED
    assert pipeline.revolutions_before_odometry == 1
    [(tag, outcome)] = pipeline.flush()
    assert tag == 2 and pipeline.flush() == []
    assert pipeline.revolutions_before_odometry == 2  # counted once each, an empty flush not at all
    without = TriangulationPipeline(EUROBOT_BEACON_MAP, TriangulationSettings(use_odometry=False))
    assert without.on_odometry(*_odometry_messages(0.0, 0.0)[0]) == []
    [(tag, outcome)] = without.on_revolution(3, _revolution(0.55))
    assert tag == 3 and outcome.result.accepted and not outcome.compensated


def test_pipeline_counts_non_finite_odometry_and_keeps_the_rest():
    import math

    from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
    from beams_triangulation.pipeline import TriangulationPipeline

    pipeline = TriangulationPipeline(EUROBOT_BEACON_MAP, triangulation_settings({}), (0.0, 0.0))
    pipeline.on_odometry(1.0, (0.5, 0.5, 0.0), (0.1, 0.0))
    pipeline.on_odometry(1.02, (math.nan, 0.5, 0.0), (0.1, 0.0))
    pipeline.on_odometry(1.04, (0.504, 0.5, 0.0), (0.1, 0.0))
    assert pipeline.rejected_odometry == 1
    assert pipeline.odometry.pose_at(1.02) == pytest.approx((0.502, 0.5, 0.0))
