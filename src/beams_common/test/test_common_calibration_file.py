"""The chapter-7 bias models (bearing_correction) and the calibration file (calibration_file)."""

import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from beams_common.calibration import calibration_file
from beams_common.calibration.bearing_correction import (
    IDENTITY_CORRECTION,
    THESIS_CALIBRATION_WINDOW_RANGE_RAD,
    THESIS_CORRECTION,
    BearingCorrection,
)
from beams_common.calibration.calibration_file import (
    CalibrationFileError,
    RmsFigures,
    SensorCalibration,
    load_calibration,
    save_calibration,
)
from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import BeaconMap

# Table 7.4 (after calibration) and the figure 7.11/7.12 coefficients.
THESIS_COEFFICIENTS = (
    THESIS_CORRECTION.power_bias_coefficients,
    THESIS_CORRECTION.rotation_bias_coefficients,
)
THESIS_MAP = BeaconMap.from_lists((1, 2, 3), (1.1499, 0.6048, 0.0455), (0.0455, 0.9076, 0.0516))


def _calibration(offset_m: tuple[float, float] = (-0.00098, -0.00011)) -> SensorCalibration:
    return SensorCalibration(
        beacon_map=THESIS_MAP,
        bearing_correction=BearingCorrection(
            THESIS_CORRECTION.power_bias_coefficients,
            THESIS_CORRECTION.rotation_bias_coefficients,
            (0.08, 0.19),
        ),
        turret_offset_m=offset_m,
        rms=(
            RmsFigures("no calibration", 0.00875, np.radians(0.4297)),
            RmsFigures("global", 0.00216, 0.00315),
        ),
        leave_one_out=RmsFigures("leave one position out", 0.0025, 0.0034),
        warnings=("beacon 1 moved by 4.5 mm",),
        created_utc="2026-11-22T03:30:00Z",
    )


def _assert_same(loaded: SensorCalibration, expected: SensorCalibration) -> None:
    assert loaded.beacon_map.ids == expected.beacon_map.ids
    np.testing.assert_array_equal(loaded.beacon_map.xy, expected.beacon_map.xy)
    assert loaded.bearing_correction == expected.bearing_correction
    assert loaded.turret_offset_m == expected.turret_offset_m
    assert loaded.rms == expected.rms
    assert loaded.leave_one_out == expected.leave_one_out
    assert loaded.warnings == expected.warnings
    assert loaded.created_utc == expected.created_utc


# --- bearing_correction -----------------------------------------------------------------------


def test_power_bias_is_the_cubic_of_eq_7_19():
    # a w^3 + b w^2 + c w + d with figure 7.11's coefficients, by hand at w = 0.1 rad.
    expected = -90.46e-3 + 35.83e-2 - 4.59e-1 + 0.19
    assert THESIS_CORRECTION.power_bias(0.1) == pytest.approx(expected, abs=1e-12)
    windows = np.array([0.05, 0.1, 0.15])
    np.testing.assert_allclose(
        THESIS_CORRECTION.power_bias(windows), np.polyval(THESIS_CORRECTION.power_bias_coefficients, windows)
    )


def test_rotation_bias_is_the_fourier_series_of_eq_7_25():
    a, b, c, d = THESIS_CORRECTION.rotation_bias_coefficients
    assert THESIS_CORRECTION.rotation_bias(0.0) == pytest.approx(a + c, abs=1e-15)
    assert THESIS_CORRECTION.rotation_bias(np.pi / 2) == pytest.approx(b - c, abs=1e-15)
    assert THESIS_CORRECTION.rotation_bias(np.pi / 4) == pytest.approx((a + b) / np.sqrt(2) + d, abs=1e-15)
    # Periodic in the turret angle, and E = 0: zero mean over a revolution.
    angles = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    np.testing.assert_allclose(
        THESIS_CORRECTION.rotation_bias(angles),
        THESIS_CORRECTION.rotation_bias(angles + 2 * np.pi),
        atol=1e-15,
    )
    assert abs(np.mean(THESIS_CORRECTION.rotation_bias(angles))) < 1e-15


def test_correct_subtracts_both_biases_and_wraps():
    # A bearing near +pi pushed over the cut must come back wrapped to (-pi, pi].
    correction = BearingCorrection((0.0, 0.0, 0.0, -0.01), (0.0, 0.0, 0.0, 0.0))
    assert correction.correct(np.pi - 0.005, 0.1) == pytest.approx(-np.pi + 0.005, abs=1e-12)
    phi, window = 1.0, 0.12
    expected = phi - THESIS_CORRECTION.power_bias(window) - THESIS_CORRECTION.rotation_bias(phi)
    assert THESIS_CORRECTION.correct(phi, window) == pytest.approx(expected, abs=1e-15)


def test_correct_inverts_apply_bias_to_second_order():
    rng = np.random.default_rng(1)
    true_bearings = rng.uniform(-np.pi, np.pi, 1000)
    windows = rng.uniform(0.08, 0.19, 1000)
    biased = THESIS_CORRECTION.apply_bias(true_bearings, windows)
    # Without correction the biases reach several mrad; corrected, what remains is f_corr2 evaluated at
    # the biased instead of the true angle: at most max|f_corr2'| * max|bias|.
    bias = wrap_to_pi(biased - true_bearings)
    assert np.max(np.abs(bias)) > 3e-3
    a, b, c, d = THESIS_CORRECTION.rotation_bias_coefficients
    slope_bound = abs(a) + abs(b) + 2 * (abs(c) + abs(d))
    residual = wrap_to_pi(np.asarray(THESIS_CORRECTION.correct(biased, windows)) - true_bearings)
    assert np.max(np.abs(residual)) <= slope_bound * np.max(np.abs(bias))
    assert np.sqrt(np.mean(residual**2)) < np.sqrt(np.mean(bias**2)) / 100


def test_power_bias_is_clamped_to_the_fitted_window_range():
    clamped = BearingCorrection(THESIS_CORRECTION.power_bias_coefficients, window_range_rad=(0.08, 0.19))
    assert clamped.power_bias(0.30) == THESIS_CORRECTION.power_bias(0.19)
    assert clamped.power_bias(0.01) == THESIS_CORRECTION.power_bias(0.08)
    assert clamped.power_bias(0.12) == THESIS_CORRECTION.power_bias(0.12)
    with pytest.raises(ValueError, match="low < high"):
        BearingCorrection(window_range_rad=(0.2, 0.1))


# A cubic near 0 over the thesis's 5-13 deg windows (roots at 5, 9 and 13 deg) that reaches -1.2 rad at a
# 0.04 rad window and +2.6 rad at 0.3 rad: checked over the windows it applies to, it passes.
WILD_CUBIC = tuple(1167.0 * np.poly(np.radians([5.0, 9.0, 13.0])))


@given(
    st.lists(st.floats(-500.0, 500.0), min_size=4, max_size=4),
    st.floats(0.01, 0.3).flatmap(lambda low: st.tuples(st.just(low), st.floats(low + 1e-3, 0.6))),
    st.floats(0.0, 1.0),
    st.floats(-3.0, 3.0),
)
def test_outside_its_fitted_range_the_power_bias_is_held_at_the_edge_value(
    coefficients, window_range, w, phi
):
    correction = BearingCorrection(coefficients, (1e-3, 0.0, 0.0, 2e-3), window_range)
    low, high = window_range
    edge = min(max(w, low), high)
    assert correction.power_bias(w) == correction.power_bias(edge)
    assert correction.correct(phi, w) == correction.correct(phi, edge)
    assert correction.holds_power_bias(w) == (w != edge and any(coefficients))  # a zero bias holds nothing
    if w != edge:
        assert correction.power_bias_slope(w) == 0.0


def test_a_file_without_its_window_range_holds_the_power_bias_outside_the_thesis_windows(tmp_path):
    document = calibration_file.calibration_to_dict(
        SensorCalibration(THESIS_MAP, BearingCorrection(WILD_CUBIC, window_range_rad=(0.01, 0.5)))
    )
    del document["power_bias"]["window_range_rad"]
    path = tmp_path / "old.yaml"
    path.write_text(yaml.safe_dump(document))
    correction = load_calibration(path).bearing_correction  # accepted: small over 5-13 deg
    assert correction.window_range_rad == THESIS_CALIBRATION_WINDOW_RANGE_RAD
    unheld = BearingCorrection(WILD_CUBIC)
    assert unheld.power_bias(0.04) == pytest.approx(-1.2, abs=0.05)
    assert unheld.power_bias(0.3) == pytest.approx(2.6, abs=0.05)
    low, high = THESIS_CALIBRATION_WINDOW_RANGE_RAD
    assert correction.power_bias(0.04) == unheld.power_bias(low) and abs(correction.power_bias(0.04)) < 1e-9
    assert correction.power_bias(0.3) == unheld.power_bias(high) and abs(correction.power_bias(0.3)) < 1e-9
    assert correction.holds_power_bias(np.array([0.04, 0.1, 0.3])).tolist() == [True, False, True]


def test_scalars_give_floats_arrays_give_arrays():
    assert isinstance(THESIS_CORRECTION.power_bias(0.1), float)
    assert isinstance(THESIS_CORRECTION.correct(0.3, 0.1), float)
    assert THESIS_CORRECTION.rotation_bias(np.zeros((2, 3))).shape == (2, 3)


def test_identity_changes_nothing():
    bearings = np.linspace(-3.0, 3.0, 13)
    assert IDENTITY_CORRECTION.is_identity and not THESIS_CORRECTION.is_identity
    np.testing.assert_array_equal(IDENTITY_CORRECTION.correct(bearings, 0.1), bearings)


@pytest.mark.parametrize("coefficients", [(1.0, 2.0, 3.0), (0.0, 0.0, float("nan"), 0.0)])
def test_invalid_coefficients_are_refused(coefficients):
    with pytest.raises(ValueError, match="4 finite numbers"):
        BearingCorrection(power_bias_coefficients=coefficients)


# --- calibration_file -------------------------------------------------------------------------


def test_save_then_load_round_trips(tmp_path: Path):
    path = tmp_path / "calibration.yaml"
    save_calibration(_calibration(), path)
    _assert_same(load_calibration(path), _calibration())
    text = path.read_text()
    assert text.startswith("# BeAMS sensor calibration") and "eq. 7.19" in text


def test_previous_file_is_kept_as_backup(tmp_path: Path):
    path = tmp_path / "calibration.yaml"
    save_calibration(_calibration((0.001, 0.002)), path)
    save_calibration(_calibration((0.003, 0.004)), path)
    assert load_calibration(path).turret_offset_m == (0.003, 0.004)
    assert load_calibration(tmp_path / "calibration.yaml.bak").turret_offset_m == (0.001, 0.002)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calibration.yaml", "calibration.yaml.bak"]


def test_a_crash_during_the_write_leaves_the_old_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    path = tmp_path / "calibration.yaml"
    save_calibration(_calibration((0.001, 0.002)), path)
    real_replace = os.replace

    def crash_on_target(source, destination):
        if Path(destination) == path:
            raise OSError("simulated power loss")
        real_replace(source, destination)

    monkeypatch.setattr(calibration_file.os, "replace", crash_on_target)
    with pytest.raises(OSError, match="power loss"):
        save_calibration(_calibration((0.003, 0.004)), path)
    monkeypatch.undo()
    assert load_calibration(path).turret_offset_m == (0.001, 0.002)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_missing_file_is_a_clear_error(tmp_path: Path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_calibration(tmp_path / "nowhere.yaml")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("beacons: [unclosed", "not valid YAML"),
        ("- just a list", "mapping"),
        ("format: something-else\nversion: 1\n", "format"),
        ("format: beams-calibration\nversion: 1\nbeacons: []\n", "at least 3"),
    ],
)
def test_malformed_file_is_a_clear_error(tmp_path: Path, text: str, message: str):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(CalibrationFileError, match=message) as raised:
        load_calibration(path)
    assert str(path) in str(raised.value)


def test_missing_entry_is_named(tmp_path: Path):
    path = tmp_path / "calibration.yaml"
    save_calibration(_calibration(), path)
    path.write_text(path.read_text().replace("rotation_bias: {A:", "rotation_bias: {Z:"))
    with pytest.raises(CalibrationFileError, match="missing entry 'A'"):
        load_calibration(path)
