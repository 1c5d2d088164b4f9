"""The power-bias states (issue 19): basis, calibration-file form, window fit, consider and estimate."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_ekf.bearing_ekf import BearingEkf
from beams_ekf.power_bias_states import (
    BASIS_SIZE,
    POWER_BIAS_SPECS,
    THESIS_EXPERIMENT_WINDOWS_RAD,
    PowerBiasStates,
    WindowFit,
    power_bias_states_of,
)

STATES = PowerBiasStates()
DEFAULTS = POWER_BIAS_SPECS.defaults()
LOW, HIGH = THESIS_EXPERIMENT_WINDOWS_RAD
coefficients = st.lists(st.floats(-3e-3, 3e-3), min_size=BASIS_SIZE, max_size=BASIS_SIZE).map(np.array)


def test_basis_is_chebyshev_on_the_window_range_and_clamped_outside():
    assert np.allclose(STATES.basis(LOW), [1.0, -1.0, 1.0, -1.0])
    assert np.allclose(STATES.basis(HIGH), [1.0, 1.0, 1.0, 1.0])
    assert np.allclose(STATES.basis(0.5 * (LOW + HIGH)), [1.0, 0.0, -1.0, 0.0])
    assert np.allclose(STATES.basis(10.0 * HIGH), STATES.basis(HIGH))
    assert np.allclose(STATES.basis(0.0), STATES.basis(LOW))


def test_prior_keeps_each_coefficient_within_half_the_thesis_range():
    assert STATES.prior_sigma_rad == pytest.approx(0.5 * math.radians(0.23))
    assert np.allclose(STATES.prior_covariance, STATES.prior_sigma_rad**2 * np.eye(BASIS_SIZE))


@settings(max_examples=50, deadline=None)
@given(coefficients, st.floats(0.0, 0.3))
def test_calibration_file_form_removes_the_same_bias(beta, window):
    # the chapter-7 correction (eq. 7.19 a, b, c, d) evaluates the curve the states hold, clamped alike
    correction = STATES.correction(beta)
    assert correction.power_bias(window) == pytest.approx(STATES.bias_rad(beta, window), abs=1e-12)
    assert correction.window_range_rad == (LOW, HIGH)


def test_window_fit_learns_the_gaussian_beam_and_waits_until_it_can():
    # w^2 = A + B ln d holds exactly for a Gaussian beam (eq. 2.7 power, 1.437 deg beam, ratio 48 at 1 m)
    sigma, ratio = math.radians(1.437), 48.0
    fit = WindowFit()
    rng = np.random.default_rng(3)
    answers = []
    for distance in rng.uniform(0.5, 3.5, 200):
        true = 2.0 * sigma * math.sqrt(2.0 * math.log(ratio / distance**2))
        answers.append((true, fit.window_rad(2, distance, true + rng.normal(0.0, 3e-3))))
    assert all(answer is None for _, answer in answers[: WindowFit.MIN_SAMPLES - 1])
    late = np.array(answers[100:])
    # the decoded windows' 3 mrad noise averaged away
    assert np.max(np.abs(late[:, 0] - late[:, 1])) < 1.5e-3
    # a replayed bearing (the same window again) is not counted twice
    count = fit._sums[2][0]
    fit.window_rad(2, 1.0, 0.0777)
    fit.window_rad(2, 1.0, 0.0777)
    assert fit._sums[2][0] == count + 1


def _filter(states: PowerBiasStates) -> BearingEkf:
    ekf = BearingEkf(EUROBOT_BEACON_MAP.as_dict(), blocks=(states,))
    ekf.initialise((1.5, 1.0, 0.0), np.diag([1e-4, 1e-4, 1e-4]))
    return ekf


@pytest.mark.parametrize("estimate", [True, False])
def test_a_still_robot_teaches_no_curve_but_the_bias_widens_the_pose(estimate):
    """Still, every window stays where it is: the window fit never gets the spread of distances it
    needs, so even 'estimate' keeps the states at their prior (a curve cannot be learnt from one point
    whose window is noisy and correlated with its bearing); both carry the bias's uncertainty."""
    ekf, plain = _filter(PowerBiasStates(estimate=estimate)), BearingEkf(EUROBOT_BEACON_MAP.as_dict())
    plain.initialise((1.5, 1.0, 0.0), np.diag([1e-4, 1e-4, 1e-4]))
    rng = np.random.default_rng(0)
    for _ in range(60):  # a still robot at (1.5, 1, 0): windows of about 0.1 rad, the fit gets ready
        for beacon_id, (bx, by) in EUROBOT_BEACON_MAP.as_dict().items():
            bearing = math.atan2(by - 1.0, bx - 1.5) + 2e-3 + rng.normal(0.0, 1e-3)
            ekf.update_bearing(beacon_id, bearing, 1e-6, (0.0, 0.0, 0.0), 0.1)
            plain.update_bearing(beacon_id, bearing, 1e-6, (0.0, 0.0, 0.0))
    beta, covariance = ekf.estimate(PowerBiasStates)
    assert np.all(beta == 0.0)
    assert np.allclose(covariance, PowerBiasStates().prior_covariance)
    # the 2 mrad bias shared by every bearing shows as heading uncertainty, which the plain filter lacks
    assert math.sqrt(ekf.covariance[2, 2]) > 3.0 * math.sqrt(plain.covariance[2, 2])


def test_calibrated_bearings_do_not_touch_the_bias_states():
    ekf = _filter(PowerBiasStates())
    prior = ekf.estimate(PowerBiasStates)[1].copy()
    for beacon_id, (bx, by) in EUROBOT_BEACON_MAP.as_dict().items():
        ekf.update_bearing(beacon_id, math.atan2(by - 1.0, bx - 1.5) + 1e-3, 1e-6, (0.0, 0.0, 0.0), 0.0)
    assert np.allclose(ekf.estimate(PowerBiasStates)[1], prior)
    assert np.all(ekf.estimate(PowerBiasStates)[0] == 0.0)


def test_parameters_give_the_states_or_none():
    assert power_bias_states_of(DEFAULTS) == PowerBiasStates()
    assert power_bias_states_of({**DEFAULTS, "power_bias_states": "off"}) is None
    considered = power_bias_states_of(
        {**DEFAULTS, "power_bias_states": "consider", "power_bias_sigma_rad": 1e-3}
    )
    assert considered == PowerBiasStates(prior_sigma_rad=1e-3, estimate=False)
    with pytest.raises(ValueError, match="window range"):
        power_bias_states_of({**DEFAULTS, "power_bias_window_range_rad": [0.2, 0.1]})
