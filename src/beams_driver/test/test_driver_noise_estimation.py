"""The natural variance fitted from a still robot on the thesis-hardware simulator (sections 5.5-5.8).

The simulated receiver's natural variance is (sigma_r^2(w) + sigma_f^2(w)) / 4 with both edge variances
linear in the window (fig. 5.3, `receiver.HardwareNoise`): the truth the fit must recover. Poses keep
every beacon beyond 1 m, where that law is linear (it is held constant beyond the experiment's windows).
"""

import math

import numpy as np
import pytest

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_driver.estimate_noise import driver_models, estimate
from beams_driver.noise_estimation import (
    TOLERATED_RATIO,
    NoiseEstimationError,
    StaticRecording,
    beacon_spread,
    recordings_from_bearings,
)
from beams_driver.parameters import DRIVER_PARAMETERS, codes_of, variance_model_of
from beams_driver.variance import VarianceModel
from beams_sim.sensor_sim import SensorSimConfig, beacons_from_map
from beams_sim.simulated_match import simulated_bearings

HARDWARE = SensorSimConfig.thesis_hardware()
DEFAULTS = DRIVER_PARAMETERS.defaults()
CODES = codes_of(DEFAULTS)
# The driver's defaults describe the thesis hardware (issue 19); these values describe the ideal receiver
# (its constant edge noise): on the thesis hardware, a driver configured with them understates the noise.
IDEAL_RECEIVER_VALUES = {
    **DEFAULTS,
    "natural_variance_rad2": SensorSimConfig().natural_variance_rad2,
    "natural_variance_slope_rad2_per_rad": 0.0,
    "natural_variance_reference_window_rad": 0.0,
}
# Four still poses (every beacon 1.2-2.7 m away: windows 5.6-7.7 deg), 60 s each as the README asks.
POSES = [(1.5, 1.0, 0.0), (0.9, 1.2, 1.0), (2.0, 0.5, -2.0), (2.0, 1.6, 2.5)]
REVOLUTIONS = 600
LIMITS = {"max_std_rad": math.radians(0.3), "max_drift_rad": math.radians(0.1), "slope_z_threshold": 3.0}


def _record(config, model, pose, seed, revolutions=REVOLUTIONS, pose_at=None):
    """(beacon, bearing, published variance, window) of a driver decoder on a simulated still robot."""
    beacons = beacons_from_map(EUROBOT_BEACON_MAP)
    return simulated_bearings(config, model, beacons, pose_at or (lambda _t: pose), revolutions, seed)


def _recordings(config, model, seed0, revolutions=REVOLUTIONS):
    return [
        recording
        for k, pose in enumerate(POSES)
        for recording in recordings_from_bearings(
            str(pose), _record(config, model, pose, seed0 + k, revolutions)
        )
    ]


def _injected_natural_rad2(window_rad: float) -> float:
    rising, falling = HARDWARE.hardware.edge_std_rad(window_rad, CODES[0])
    return float(rising**2 + falling**2) / 4.0


@pytest.fixture(scope="module")
def hardware_report():
    """The estimation on recordings made by a driver with its default natural variance (3.05e-7)."""
    model = variance_model_of(IDEAL_RECEIVER_VALUES, CODES, HARDWARE)
    return estimate(_recordings(HARDWARE, model, 0), IDEAL_RECEIVER_VALUES, **LIMITS)


def test_fit_recovers_the_injected_window_dependent_natural_variance(hardware_report):
    """Within 15% of the injected natural variance at every recorded window, with a significant slope.

    Tolerance: each (pose, beacon) sample variance of 600 bearings has a standard error of
    sqrt(2/599) = 5.8% of s^2, ~8% of its natural part (the code's exact variance is a quarter of s^2);
    the line over 12 of them is within ~3% at the mean window and ~6% at the ends of the window range
    (the standard errors the fit reports), so 15% is 2.5 sigma at the ends, plus ~3% of model error (the
    code's error and the jittered window are not exactly independent). The slope: positive, within 3 of
    its reported standard errors of the injected one (fig. 5.3's lines: ~1.05e-5 rad^2/rad).
    """
    fit = hardware_report.fit
    for spread in hardware_report.spreads:
        injected = _injected_natural_rad2(spread.mean_window_rad)
        assert fit.at(spread.mean_window_rad) == pytest.approx(injected, rel=0.15), (
            spread.label,
            spread.beacon_id,
        )
    low, high = HARDWARE.hardware.window_range_rad
    injected_slope = (_injected_natural_rad2(high) - _injected_natural_rad2(low)) / (high - low)
    assert fit.window_dependent
    assert abs(fit.slope_rad2_per_rad - injected_slope) < 3.0 * fit.slope_standard_error
    # the ideal receiver's natural variance the recording's driver used is far below the truth
    assert IDEAL_RECEIVER_VALUES["natural_variance_rad2"] < 0.5 * fit.natural_variance_rad2


def test_driver_configured_with_the_fit_publishes_variances_matching_the_spread(hardware_report):
    """Before: the published variances understate the spread (ratio ~2, outside 0.8-1.25, for some
    beacon: here all, the check's verdict says so). After: a driver decoder whose variance model has the
    fitted parameters, on new recordings (other seeds, 1000 revolutions), publishes variances whose ratio
    to the bearings' sample variance is within 0.8-1.25 for every beacon of every pose."""
    before = [check.ratio for check in hardware_report.published]
    assert max(before) > TOLERATED_RATIO[1]
    assert any(check.verdict == "understated" for check in hardware_report.published)
    fitted_values = {**IDEAL_RECEIVER_VALUES, **hardware_report.fit.parameters()}
    model = variance_model_of(fitted_values, CODES, HARDWARE)
    spreads = [beacon_spread(r) for r in _recordings(HARDWARE, model, 100, revolutions=1000)]
    assert len(spreads) == 3 * len(POSES)
    for spread in spreads:
        ratio = spread.observed_variance_rad2 / spread.mean_published_variance_rad2
        assert TOLERATED_RATIO[0] <= ratio <= TOLERATED_RATIO[1], (spread.label, spread.beacon_id, ratio)


def test_constant_noise_keeps_a_constant_natural_variance():
    """The ideal receiver's edge noise does not depend on the window: the slope is not selected, and the
    natural variance is its (0.06^2 + 0.02^2) / 4 deg^2 within 15% (the band of the first test)."""
    values = {**IDEAL_RECEIVER_VALUES, "sim_noise_model": "ideal"}
    ideal = SensorSimConfig()
    model, _ = driver_models(values)
    report = estimate(_recordings(ideal, model, 50), values, **LIMITS)
    assert not report.fit.window_dependent
    assert report.fit.slope_rad2_per_rad == 0.0
    assert report.fit.natural_variance_rad2 == pytest.approx(ideal.natural_variance_rad2, rel=0.15)
    # with the right natural variance configured, the published variances pass the check
    assert all(check.verdict == "ok" for check in report.published)


def test_the_default_variances_pass_the_check_on_the_thesis_hardware():
    """The driver's defaults are the thesis hardware's natural variance (issue 19): on that receiver the
    published variances match the bearings' spread at every pose (the check's verdict 'ok')."""
    model = variance_model_of(DEFAULTS, CODES, HARDWARE)
    report = estimate(_recordings(HARDWARE, model, 200), DEFAULTS, **LIMITS)
    assert all(check.verdict == "ok" for check in report.published), [c.ratio for c in report.published]


def test_a_moving_robot_and_empty_recordings_are_refused():
    """A robot turning at 0.02 deg/s (0.6 deg in 30 s: std within 0.3 deg) is refused for its drift;
    at 0.5 deg/s for its spread; no bearings, too few, or bearings without windows are refused too."""
    model = variance_model_of(DEFAULTS, CODES, HARDWARE)
    for rate_deg_s, reason in ((0.02, "drifted"), (0.5, "spread")):
        rows = _record(
            HARDWARE, model, None, 3, 300, pose_at=lambda t, r=rate_deg_s: (1.5, 1.0, math.radians(r) * t)
        )
        with pytest.raises(NoiseEstimationError, match=f"{reason}.*moved"):
            [beacon_spread(r) for r in recordings_from_bearings("turning", rows)]
    with pytest.raises(NoiseEstimationError, match="no bearings"):
        recordings_from_bearings("empty", [])
    with pytest.raises(NoiseEstimationError, match="no beacon with 50 bearings"):
        recordings_from_bearings("short", [(1, 0.1, 1e-6, 0.1)] * 10)
    with pytest.raises(NoiseEstimationError, match="without an angular window"):
        recordings_from_bearings("no windows", [(1, 0.1, 1e-6, 0.0)] * 60)


def test_a_beacon_behind_the_robot_is_one_cluster_across_pi():
    """Bearings on both sides of +-pi (std 0.05 deg) give that std, not a spread of 2 pi."""
    rng = np.random.default_rng(4)
    bearings = np.angle(np.exp(1j * (math.pi + rng.normal(0.0, math.radians(0.05), 400))))
    assert np.ptp(bearings) > math.pi
    recording = StaticRecording("behind", 1, bearings, np.full(400, 1e-6), np.full(400, 0.1))
    assert math.sqrt(beacon_spread(recording).observed_variance_rad2) == pytest.approx(
        math.radians(0.05), rel=0.1
    )


def test_variance_model_natural_variance_slope():
    """Slope 0 keeps the constant natural variance (scalars and arrays); a slope makes it linear in the
    window around the reference window, never below 0, in the exact and the bound modes."""
    windows = np.array([0.05, 0.1, 0.14])
    plain = VarianceModel(CODES, natural_variance_rad2=3e-7)
    zero = VarianceModel(CODES, natural_variance_rad2=3e-7, natural_variance_reference_window_rad=0.1)
    np.testing.assert_array_equal(plain.variance(2, windows), zero.variance(2, windows))
    assert plain.variance(2, 0.1) == zero.variance(2, 0.1)
    for mode in ("exact", "bound"):
        sloped = VarianceModel(
            CODES,
            mode,
            natural_variance_rad2=1e-6,
            natural_variance_slope_rad2_per_rad=2e-5,
            natural_variance_reference_window_rad=0.1,
        )
        base = VarianceModel(CODES, mode)
        natural = sloped.variance(2, windows) - base.variance(2, windows)
        np.testing.assert_allclose(natural, [0.0, 1e-6, 1.8e-6], rtol=1e-9, atol=1e-18)
        assert sloped.variance(2, 0.01) == pytest.approx(base.variance(2, 0.01))  # 1e-6 - 1.8e-6: clamped
        assert sloped.natural_variance(0.01) == 0.0
