"""Calibration plausibility (issue 18): values against what chapter 7 measured, refused wherever a file is
loaded; a calibration against its nominal geometry; a calibration that makes recent bearings worse."""

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from beams_common.calibration.bearing_correction import (
    THESIS_CALIBRATION_WINDOW_RANGE_RAD,
    THESIS_CORRECTION,
    BearingCorrection,
)
from beams_common.calibration.calibration_checks import (
    MAX_BEACON_CORRECTION_M,
    MAX_ROTATION_BIAS_RAD,
    BearingSample,
    RecentBearings,
    bearing_residual_rms,
    calibration_nominal_problem,
    calibration_value_problem,
    calibration_worse_problem,
    power_bias_extent_rad,
    rotation_bias_extent_rad,
)
from beams_common.calibration.calibration_file import (
    CalibrationFileError,
    SensorCalibration,
    load_calibration,
    node_refusal,
    save_calibration,
)
from beams_common.config.geometry_parameters import geometry_of
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP, BeaconMap

THESIS_OFFSET_M = (-0.00098, -0.00011)  # section 7.3.5


def test_the_thesis_calibration_is_plausible_and_its_extents_are_the_thesis_s():
    assert calibration_value_problem(THESIS_CORRECTION, THESIS_OFFSET_M) == ""
    # fig. 7.11 over the thesis's windows (5-13 deg): up to 3.7 deg; fig. 7.12: 0.21 deg
    assert math.degrees(power_bias_extent_rad(THESIS_CORRECTION)) == pytest.approx(3.7, abs=0.1)
    assert math.degrees(rotation_bias_extent_rad(THESIS_CORRECTION)) == pytest.approx(0.21, abs=0.01)


@pytest.mark.parametrize(
    ("correction", "offset", "reason"),
    [
        (
            BearingCorrection(rotation_bias_coefficients=(3.0, 0.0, 0.0, 0.0)),
            (0.0, 0.0),
            "rotation_bias reaches",
        ),
        (
            BearingCorrection(power_bias_coefficients=(1e300, 0.0, 0.0, 0.0)),
            (0.0, 0.0),
            "power_bias reaches 6.69e+299 deg",
        ),
        (
            BearingCorrection(power_bias_coefficients=(0.0, 0.0, 0.0, 0.5)),
            (0.0, 0.0),
            "power_bias reaches 28.6",
        ),
        (BearingCorrection(), (0.5, 0.0), "turret_offset_m is 0.5 m"),
    ],
)
def test_the_issue_s_implausible_values_are_refused_with_the_reason(correction, offset, reason):
    assert reason in calibration_value_problem(correction, offset)


@given(st.lists(st.floats(-0.1, 0.1), min_size=4, max_size=4))
def test_a_rotation_bias_is_refused_exactly_when_its_extent_exceeds_the_limit(coefficients):
    correction = BearingCorrection(rotation_bias_coefficients=tuple(coefficients))
    angles = np.linspace(-math.pi, math.pi, 4096)
    extent = float(np.max(np.abs(correction.rotation_bias(angles))))
    problem = calibration_value_problem(correction, (0.0, 0.0))
    if extent < 0.99 * MAX_ROTATION_BIAS_RAD:  # the check's grid is coarser than this one
        assert problem == ""
    elif extent > 1.01 * MAX_ROTATION_BIAS_RAD:
        assert "rotation_bias" in problem


def _write(
    tmp_path: Path, correction: BearingCorrection, offset=(0.0, 0.0), beacon_map=EUROBOT_BEACON_MAP
) -> Path:
    path = tmp_path / "calibration.yaml"
    save_calibration(SensorCalibration(beacon_map, correction, offset), path)
    return path


def test_loading_refuses_an_implausible_file_and_names_it(tmp_path):
    path = _write(tmp_path, BearingCorrection(rotation_bias_coefficients=(3.0, 0.0, 0.0, 0.0)))
    with pytest.raises(CalibrationFileError, match=r"calibration\.yaml: implausible, rotation_bias reaches"):
        load_calibration(path)
    path = _write(tmp_path, THESIS_CORRECTION, THESIS_OFFSET_M)
    # written without its window range: loaded with the thesis's calibration windows (calibration_file)
    ranged = replace(THESIS_CORRECTION, window_range_rad=THESIS_CALIBRATION_WINDOW_RANGE_RAD)
    assert load_calibration(path).bearing_correction == ranged


def test_a_node_refusal_is_known_before_the_file_is_written():
    """node_refusal runs the start-up checks (schema, values, nominal geometry) on a calibration."""
    far = BeaconMap.from_lists((1, 2, 3), (-0.062, -0.062, 2.5), (-0.062, 2.062, 1.0))
    calibration = SensorCalibration(far, THESIS_CORRECTION, THESIS_OFFSET_M)
    assert node_refusal(calibration, far, (0.0, 0.0)) == ""
    assert "beacon 3 is 0.562 m from its nominal position" in node_refusal(
        calibration, EUROBOT_BEACON_MAP, (0.0, 0.0)
    )
    rotated = SensorCalibration(far, BearingCorrection(rotation_bias_coefficients=(3.0, 0.0, 0.0, 0.0)))
    assert "rotation_bias reaches" in node_refusal(rotated, far, (0.0, 0.0))


def _nominal(**changes):
    values = {
        "beacon_ids": list(EUROBOT_BEACON_MAP.ids),
        "beacon_x": EUROBOT_BEACON_MAP.xy[:, 0].tolist(),
        "beacon_y": EUROBOT_BEACON_MAP.xy[:, 1].tolist(),
        "turret_offset_m": [0.0, 0.0],
    }
    return {**values, **changes}


def test_a_calibration_is_checked_against_the_nominal_geometry_at_start_up(tmp_path):
    moved = BeaconMap.from_lists((1, 2, 3), (-0.062, -0.062, 3.062 - 0.004), (-0.062, 2.062, 1.003))
    path = _write(tmp_path, THESIS_CORRECTION, THESIS_OFFSET_M, moved)  # millimetres: a correction
    geometry = geometry_of({**_nominal(), "calibration_file": str(path)})
    assert geometry.beacon_map == moved
    far = BeaconMap.from_lists((1, 2, 3), (-0.062, -0.062, 2.5), (-0.062, 2.062, 1.0))
    path = _write(tmp_path, THESIS_CORRECTION, THESIS_OFFSET_M, far)
    with pytest.raises(ValueError, match=r"beacon 3 is 0\.562 m from its nominal position"):
        geometry_of({**_nominal(), "calibration_file": str(path)})
    path = _write(tmp_path, THESIS_CORRECTION, (0.05, 0.0))
    with pytest.raises(ValueError, match=r"0\.050 m from the nominal turret_offset_m"):
        geometry_of({**_nominal(), "calibration_file": str(path)})
    # the same offset is a correction of a turret mounted 5 cm forward
    assert geometry_of({**_nominal(turret_offset_m=[0.05, 0.0]), "calibration_file": str(path)})


def test_a_calibrated_beacon_that_is_not_on_the_nominal_map_is_refused():
    other = BeaconMap.from_lists((1, 2, 7), (-0.062, -0.062, 3.062), (-0.062, 2.062, 1.0))
    problem = calibration_nominal_problem(other, (0.0, 0.0), EUROBOT_BEACON_MAP, (0.0, 0.0))
    assert "beacon 7 is not on the nominal map" in problem
    nudged = BeaconMap.from_lists(
        (1, 2, 3), (-0.062, -0.062, 3.062 + 0.9 * MAX_BEACON_CORRECTION_M), (-0.062, 2.062, 1.0)
    )
    assert calibration_nominal_problem(nudged, (0.0, 0.0), EUROBOT_BEACON_MAP, (0.0, 0.0)) == ""


def _samples(beacon_map: BeaconMap, offset, poses, noise_rad=0.0, seed=0):
    """Exact bearings (plus noise) of every beacon from each pose."""
    rng = np.random.default_rng(seed)
    samples = []
    for x, y, theta in poses:
        tx = x + math.cos(theta) * offset[0] - math.sin(theta) * offset[1]
        ty = y + math.sin(theta) * offset[0] + math.cos(theta) * offset[1]
        for beacon_id, (bx, by) in beacon_map.as_dict().items():
            bearing = (
                math.atan2(by - ty, bx - tx) - theta + (rng.normal(0.0, noise_rad) if noise_rad else 0.0)
            )
            samples.append(BearingSample((x, y, theta), beacon_id, math.remainder(bearing, 2 * math.pi)))
    return samples


POSES = [(0.5 + 0.2 * k, 0.4 + 0.1 * k, 0.3 * k) for k in range(10)]


def test_the_residual_rms_is_zero_on_the_true_geometry_and_grows_with_a_wrong_one():
    offset = (0.02, -0.01)
    samples = _samples(EUROBOT_BEACON_MAP, offset, POSES)
    truth = EUROBOT_BEACON_MAP.as_dict()
    assert bearing_residual_rms(samples, truth, offset) == pytest.approx(0.0, abs=1e-12)
    wrong = {**truth, 3: (2.5, 1.0)}
    worse = bearing_residual_rms(samples, wrong, offset)
    assert worse > math.radians(3.0)
    assert "residual RMS 0.000 ->" in calibration_worse_problem(0.0, worse)
    assert math.isnan(bearing_residual_rms([], truth, offset))


def test_noise_alone_is_not_a_worse_calibration():
    offset = (0.0, 0.0)
    noisy = _samples(EUROBOT_BEACON_MAP, offset, POSES, noise_rad=math.radians(0.27), seed=3)
    truth = EUROBOT_BEACON_MAP.as_dict()
    before = bearing_residual_rms(noisy, truth, offset)
    # a calibration moving a beacon by 4 mm (thesis table 7.4) changes the RMS by the noise, no more
    corrected = {**truth, 1: (-0.058, -0.062)}
    assert calibration_worse_problem(before, bearing_residual_rms(noisy, corrected, offset)) == ""
    assert calibration_worse_problem(math.nan, 1.0) == ""


def test_recent_bearings_flag_a_calibration_that_moves_a_beacon_by_4_cm_not_4_mm():
    recent = RecentBearings(size=30)
    offset = (0.0, 0.0)
    for sample in _samples(EUROBOT_BEACON_MAP, offset, POSES, noise_rad=math.radians(0.05), seed=1):
        recent.add(sample)
    assert len(recent) == 30  # the newest only
    truth = EUROBOT_BEACON_MAP.as_dict()
    assert recent.worse_problem((truth, offset), ({**truth, 3: (3.062, 1.004)}, offset)) == ""
    problem = recent.worse_problem((truth, offset), ({**truth, 3: (3.062, 1.04)}, offset))
    assert "makes the recent bearings worse" in problem
    recent.clear()
    assert recent.worse_problem((truth, offset), ({**truth, 3: (3.062, 1.04)}, offset)) == ""
