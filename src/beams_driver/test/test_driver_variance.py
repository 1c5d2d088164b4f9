"""The variance of a bearing against the angular window, held to chapters 3-5 of the thesis."""

from collections.abc import Sequence

import numpy as np
import pytest

from beams_driver.codes import BeaconCode, code_family, codes_from_strings, family_code
from beams_driver.edges import TURRET_SPEED_RAD_S
from beams_driver.variance import (
    MEASURED_VARIANCE_RAD2,
    VarianceModel,
    enumerated_variance_s2,
    family_normalized_variance,
)
from beams_sim.sensor_sim import (
    SensorSimConfig,
    SensorSimulator,
    SimulatedBeacon,
    fixed_window_bearing_errors,
)

CODES = code_family()
PHI0_RAD = CODES[0].bit_time_s * TURRET_SPEED_RAD_S
TICK_S = 100e-9
COPRIME_PERIOD_S = 998401 * TICK_S
REAL_PERIOD_S = 998400 * TICK_S


def variance_bound_rad2(code: BeaconCode, turret_speed_rad_s: float = TURRET_SPEED_RAD_S) -> float:
    """Theorem 3.1 (eq. 3.41): sigma^2 <= p0 phi0^2 / 6 (generalised to unequal gaps by the code)."""
    return code.variance_bound_s2 * turret_speed_rad_s**2


def edge_variance_rad2(p0: float, phi0_rad: float) -> float:
    """Variance of one edge, sigma_r^2 = p0 phi0^2/3 - p0^2 phi0^2/4 (eq. 3.8): the first bound (eq. 3.18)."""
    return p0 * phi0_rad**2 / 3.0 - p0**2 * phi0_rad**2 / 4.0


def family_minimum_windows_over_phi0(index: int, n_codes: int, periods: Sequence[int]) -> np.ndarray:
    """Local minima of the variance (units of phi0), eq. 4.80 (code Nc) and 4.81 (others)."""
    root = np.sqrt(2.0) - 1.0
    k = np.asarray(periods, dtype=float)
    if index == n_codes:
        return (n_codes + 1) * (1.0 + k) + root
    period = 2 * n_codes + 2
    starts = np.array([index + 1, 2 * n_codes + 1 - index, period], dtype=float)
    return np.sort((starts[None, :] + root + period * k[:, None]).ravel())


def _simulated_normalized_variance(code, windows_s, period_s, n_turns):
    """Variance / bound of the section-4.3 simulation for each window (detected turns only)."""
    errors, detected = fixed_window_bearing_errors(code, windows_s, period_s, n_turns, tick_s=TICK_S)
    count = detected.sum(axis=1)
    mean = errors.sum(axis=1) / count
    return ((errors**2).sum(axis=1) / count - mean**2) / code.variance_bound_s2


def test_table_3_1_bounds():
    code = CODES[4]
    first = np.degrees(np.sqrt(edge_variance_rad2(code.p0, PHI0_RAD)))
    new = np.degrees(np.sqrt(variance_bound_rad2(code)))
    assert np.degrees(PHI0_RAD) == pytest.approx(0.111, abs=5e-4)
    assert round(first, 4) == 0.0245
    assert round(new, 4) == 0.0185


@pytest.mark.parametrize(
    ("bits", "window_bias_deg", "variance_deg2"),
    [
        ("111110111110", -1.85e-2, 3.43e-4),
        ("11111001111100", -6.35e-2, 2.35e-3),
        ("1111100011111000", -1.25e-1, 6.94e-3),
    ],
)
def test_theory_column_of_table_5_1(bits, window_bias_deg, variance_deg2):
    code = codes_from_strings([bits])[0]
    bias_deg = -np.degrees(code.window_bias_s * TURRET_SPEED_RAD_S)  # eq. 5.2
    model = VarianceModel([code], mode="bound")
    assert bias_deg == pytest.approx(window_bias_deg, rel=6e-3)
    assert np.degrees(np.degrees(model.variance(code.code_id, 0.1))) == pytest.approx(variance_deg2, rel=6e-3)


def test_code_5_minima_of_eq_5_3():
    minima_deg = family_minimum_windows_over_phi0(5, 5, [7, 8, 9]) * np.degrees(PHI0_RAD)
    assert np.round(minima_deg, 2) == pytest.approx([5.38, 6.04, 6.71])
    # They are true local minima of the model, of depth P_E(sqrt(2) - 1) = 3 - 2 sqrt(2) (eq. 4.79).
    model = VarianceModel(CODES)
    bound = variance_bound_rad2(CODES[4])
    for minimum in np.radians(minima_deg):
        around = minimum + np.linspace(-0.3, 0.3, 601) * PHI0_RAD
        values = model.variance(5, around)
        assert around[np.argmin(values)] == pytest.approx(minimum, abs=2e-3 * PHI0_RAD)
        assert values.min() / bound == pytest.approx(3.0 - 2.0 * np.sqrt(2.0), abs=1e-3)


def test_closed_form_is_continuous_and_below_the_bound():
    x = np.linspace(0.0, 30.0, 30001)
    for code in CODES:
        values = family_normalized_variance(code.code_id, 5, x)
        assert np.all(values <= 1.0 + 1e-12) and np.all(values >= 0.0)
        assert np.max(np.abs(np.diff(values))) < 5e-3  # no jump at the case transitions
    # Case A plateaus of table 4.2 (code 1: [3, 9) phi0) and the case-C minimum 2 - sqrt(2) (eq. 4.78).
    assert family_normalized_variance(1, 5, [3.0, 5.0, 8.99]) == pytest.approx([1.0, 1.0, 1.0])
    assert family_normalized_variance(1, 5, 2.0 + np.sqrt(2.0) - 1.0) == pytest.approx(2.0 - np.sqrt(2.0))


@pytest.mark.parametrize("n_codes", [3, 5, 7])
def test_enumeration_agrees_with_the_closed_form(n_codes):
    for index in range(1, n_codes + 1):
        code = family_code(index, n_codes)
        x = np.linspace(0.0, 2 * n_codes + 3, 1201)
        variance, mean, _ = enumerated_variance_s2(code, x * code.bit_time_s)
        assert variance / code.variance_bound_s2 == pytest.approx(
            family_normalized_variance(index, n_codes, x), abs=1e-9
        )
        assert np.abs(mean).max() < 1e-9 * code.bit_time_s  # unbiased estimator, eq. 3.12


@pytest.mark.parametrize("code", CODES, ids=lambda c: f"C{c.code_id}")
def test_coprime_simulation_matches_the_closed_form_within_2_percent(code):
    # Section 4.4: 998401 ticks is coprime with 3696, so 3696 turns visit every shift once.
    x = np.concatenate([np.linspace(0.02, 13.0, 150), [0.5, 5.5, 11.5, 12.5]])
    windows_s = np.round(x * code.bit_time_s / TICK_S) * TICK_S
    simulated = _simulated_normalized_variance(code, windows_s, COPRIME_PERIOD_S, 3696)
    theory = family_normalized_variance(code.code_id, 5, windows_s / code.bit_time_s)
    assert np.max(np.abs(simulated - theory)) < 0.02


def test_non_coprime_real_period_exceeds_the_bound_by_up_to_14_percent_for_codes_2_and_4():
    # 998400 and 3696 share gcd 48: only 77 turns of distinct shifts (eq. 4.82).
    x = np.linspace(0.05, 13.0, 2591)
    peaks = {}
    for code in CODES:
        windows_s = np.round(x * code.bit_time_s / TICK_S) * TICK_S
        peaks[code.code_id] = _simulated_normalized_variance(code, windows_s, REAL_PERIOD_S, 77).max()
    assert all(peak > 1.0 for peak in peaks.values())
    assert 1.12 < peaks[2] < 1.16 and 1.12 < peaks[4] < 1.16
    assert max(peaks, key=peaks.get) in (2, 4)
    assert max(peaks[1], peaks[3], peaks[5]) < peaks[2] - 0.02


def test_full_edge_simulator_matches_the_closed_form_with_a_coprime_period():
    code = CODES[2]
    config = SensorSimConfig.ideal(period_s=COPRIME_PERIOD_S, tick_s=TICK_S, codes=CODES)
    distance = 2.0
    window = float(config.window_rad(distance))
    simulator = SensorSimulator(
        config, [SimulatedBeacon(code.code_id, distance, 0.0)], np.random.default_rng(3)
    )
    bearings = []
    for turn in range(3696):
        edges = simulator.revolution(lambda t: (0.0, 0.0, -1.0), turn * config.period_s)
        bearings.append(0.5 * (edges.edge_angles_rad[0] + edges.edge_angles_rad[-1]))
    simulated = np.var(bearings) / variance_bound_rad2(code, config.turret_speed_rad_s)
    theory = family_normalized_variance(
        code.code_id, 5, window / (code.bit_time_s * config.turret_speed_rad_s)
    )
    assert simulated == pytest.approx(float(theory), abs=0.02)


def test_variance_model_modes_and_natural_variance():
    natural = 1e-7
    exact = VarianceModel(CODES, natural_variance_rad2=natural)
    bound = VarianceModel(CODES, mode="bound", natural_variance_rad2=natural)
    constant = VarianceModel(CODES, mode="constant")
    window = 12.5 * PHI0_RAD  # case E of code 1 with lambda_e = 0.5 (eq. 4.74)
    p_e = (1 - 1.5 + 0.75 + 0.125) / 2
    assert exact.variance(1, window) == pytest.approx(p_e * variance_bound_rad2(CODES[0]) + natural)
    assert bound.variance(1, window) == pytest.approx(variance_bound_rad2(CODES[0]) + natural)
    assert constant.variance(3, window) == pytest.approx(MEASURED_VARIANCE_RAD2)
    assert exact.variance(CODES[0], np.array([window, window])).shape == (2,)
    with pytest.raises(ValueError, match="variance mode"):
        VarianceModel(CODES, mode="worst")
    with pytest.raises(KeyError, match="unknown code 9"):
        exact.variance(9, window)


def test_custom_codes_use_the_precomputed_enumeration():
    codes = codes_from_strings(["11111001111100", "1101111100"])
    model = VarianceModel(codes)
    windows = np.linspace(0.0, 60.0, 301) * codes[0].bit_time_s * TURRET_SPEED_RAD_S
    for code in codes:
        exact = enumerated_variance_s2(code, windows / TURRET_SPEED_RAD_S)[0] * TURRET_SPEED_RAD_S**2
        bound = variance_bound_rad2(code)
        assert model.variance(code.code_id, windows) == pytest.approx(exact, abs=2e-3 * bound)
        assert np.all(exact <= bound * (1 + 1e-9))


def test_minimum_burst_raises_the_variance_as_section_5_6_says():
    ideal = VarianceModel(CODES)
    receiver = VarianceModel(CODES, min_burst_fraction=0.56)
    windows = np.linspace(3.0, 40.0, 2000) * PHI0_RAD
    # phi0 and p0 both stretched by 56%: the bound grows by 1.56^3 and the curve reaches it.
    assert receiver.bound_rad2(5) == pytest.approx(1.56**3 * ideal.bound_rad2(5))
    assert receiver.variance(5, windows).max() == pytest.approx(receiver.bound_rad2(5), rel=1e-6)
    assert receiver.variance(5, windows).mean() > 2.0 * ideal.variance(5, windows).mean()
