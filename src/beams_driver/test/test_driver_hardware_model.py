"""The thesis-hardware receiver model against chapter 5's measurements, and the decoder's window correction.

Table 5.1's experiment column and fig. 5.3 are reproduced with the experiment of section 5.3: one beacon,
100 windows over the range of 1-6 m, 1000 measurements per window, the bias of the window measured
against C_k's (whose window is the reference, table 5.1: bias 0) and the maximum over the windows of
the sample variance of Phi_b.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.calibration.bearing_correction import BearingCorrection
from beams_common.geometry.angles import wrap_to_pi
from beams_driver.codes import BeaconCode, code_family, codes_from_strings, family_code, first_last_edges
from beams_driver.decoder import BearingDecoder
from beams_driver.edges import RevolutionEdges
from beams_driver.receiver import IDEAL_RECEIVER, ReceiverModel
from beams_driver.variance import VarianceModel
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator, SimulatedBeacon
from beams_thesis.receiver_experiment import window_experiment

HARDWARE = SensorSimConfig.thesis_hardware()
DEG = np.radians(1.0)
PHI0_RAD = code_family()[0].bit_time_s * HARDWARE.turret_speed_rad_s
# Section 5.2's test codes (C_5 is the family's code 5; the text's 13-bit string is a typo: p0 = 1/6).
TEST_CODES = {"C_k": None, "C_5": "111110111110", "C_5b": "11111001111100", "C_5c": "1111100011111000"}
# Table 5.1, experiments column (NOTES.md: the exponents' separators were lost, -4.8510^{-2} is -4.85e-2).
EXPERIMENT_WINDOW_BIAS_DEG = {"C_k": 0.0, "C_5": -4.85e-2, "C_5b": -9.53e-2, "C_5c": -1.56e-1}
EXPERIMENT_MAX_VARIANCE_DEG2 = {"C_k": 3.93e-3, "C_5": 5.49e-3, "C_5b": 1.00e-2, "C_5c": 1.82e-2}


def _code(name: str) -> BeaconCode | None:
    bits = TEST_CODES[name]
    return None if bits is None else BeaconCode.from_string(1, bits)


def _experiment(config: SensorSimConfig, seed: int) -> dict[str, tuple[float, float]]:
    """(window bias deg, maximum variance of Phi_b deg^2) per test code, as section 5.3 measured them."""
    rng = np.random.default_rng(seed)
    windows = np.linspace(*HARDWARE.hardware.window_range_rad, 100)
    results, reference = {}, None
    for name in TEST_CODES:
        rising, falling = window_experiment(config, _code(name), windows, 1000, rng)
        mean_window = np.mean(falling - rising, axis=1)
        reference = mean_window if reference is None else reference
        variance = np.var(0.5 * (rising + falling), axis=1)
        results[name] = (float(np.mean(mean_window - reference)) / DEG, float(variance.max()) / DEG**2)
    return results


@pytest.mark.parametrize("seed", [0, 1])
def test_table_5_1_experiment_column(seed):
    """Window biases within 3% and maximum variances within 12% of table 5.1's experiments column.

    Bands: the model's minimum-burst law (56% of T0 at a one-bit gap, falling as sqrt(T_b / G)) and its
    outer shortening (3.5e-3 deg) were chosen to fit the three biases, and its AGC gain (0.7) the C_5b and
    C_5c variances, so the band is what the fit cannot do better plus sampling: the table's three digits
    (0.5%) and the mean of 100 x 1000 measures (seed to seed within 1.5%) for the biases; for the
    variances, the maximum over 100 windows of a sample variance of 1000 measures (each 4.5% relative
    standard deviation) moves by about 5% between runs (12 seeds: C_5 from 5.18e-3 to 5.72e-3) and
    exceeds the true maximum by about twice that, as it did for the thesis. The ideal model misses the
    same column (its minimum burst grows with the gap: C_5b's bias comes out -0.154 deg, C_5c's
    variance 0.026 deg^2), so the test can fail.
    """
    for name, (bias_deg, variance_deg2) in _experiment(HARDWARE, seed).items():
        assert bias_deg == pytest.approx(EXPERIMENT_WINDOW_BIAS_DEG[name], rel=0.03, abs=1e-9), name
        assert variance_deg2 == pytest.approx(EXPERIMENT_MAX_VARIANCE_DEG2[name], rel=0.12), name
    ideal = _experiment(SensorSimConfig(), seed)
    assert ideal["C_5b"][0] < 1.3 * EXPERIMENT_WINDOW_BIAS_DEG["C_5b"]
    assert ideal["C_5c"][1] > 1.3 * EXPERIMENT_MAX_VARIANCE_DEG2["C_5c"]


def test_fig_5_3_edge_variances_of_c_k():
    """Rising 0.0018-0.0137 deg^2, falling 0.000066-0.0023 deg^2 over the windows, both growing (fig. 5.3).

    The ends of a straight-line fit over the 100 windows (the curves are "quasi linear", section 5.5),
    within 8%: each sample variance of 1000 measures is within 4.5% (one sigma), the fit averages 100.
    """
    windows = np.linspace(*HARDWARE.hardware.window_range_rad, 100)
    rising, falling = window_experiment(HARDWARE, None, windows, 1000, np.random.default_rng(5))
    for errors, expected in ((rising, (0.0018, 0.0137)), (falling, (0.000066, 0.0023))):
        variance = np.var(errors, axis=1) / DEG**2
        slope, intercept = np.polyfit(windows, variance, 1)
        ends = intercept + slope * windows[[0, -1]]
        assert ends == pytest.approx(expected, rel=0.08)
    assert np.all(np.var(rising, axis=1) > 4.0 * np.var(falling, axis=1))


def test_edge_simulator_agrees_with_the_window_experiment_and_the_decoder_window_is_unbiased():
    """The full edge simulator applies the same noise as window_experiment (edge variances within 25%:
    400 revolutions give a sample variance within 7% at one sigma), and the decoder's window, corrected
    by the receiver's mean shortening, equals the true window within 0.1 phi0 (the correction of the
    ideal receiver, p0 phi0, leaves it about 0.27 phi0 short: the AND hypothesis and the outer shift)."""
    code = family_code(5)
    decoder = BearingDecoder(HARDWARE.codes, VarianceModel(HARDWARE.codes), receiver=HARDWARE.receiver)
    for distance_m, seed in ((1.5, 1), (4.0, 2)):
        simulator = SensorSimulator(
            HARDWARE, [SimulatedBeacon(5, distance_m, 0.0)], np.random.default_rng(seed)
        )
        true_window = float(HARDWARE.window_rad(distance_m))
        rising, falling, windows = [], [], []
        decoder.reset()
        for turn in range(400):
            edges = simulator.revolution(lambda t: (0.0, 0.0, -1.0), turn * HARDWARE.period_s)
            rising.append(edges.edge_angles_rad[0])
            falling.append(edges.edge_angles_rad[-1])
            windows += [b.angular_window for b in decoder.decode(edges).bearings]
        reference = window_experiment(HARDWARE, code, [true_window], 4000, np.random.default_rng(seed))
        assert np.var(rising) == pytest.approx(np.var(reference[0]), rel=0.25)
        assert np.var(falling) == pytest.approx(np.var(reference[1]), rel=0.25)
        assert len(windows) >= 390
        assert abs(np.mean(windows) - true_window) < 0.1 * PHI0_RAD
        uncorrected = (
            np.mean(windows) - HARDWARE.receiver.window_shortening_s(code) * HARDWARE.turret_speed_rad_s
        )
        assert true_window - (uncorrected + code.window_bias_s * HARDWARE.turret_speed_rad_s) > 0.2 * PHI0_RAD


def test_power_bias_spans_0_23_deg_and_a_cubic_calibration_removes_it():
    """Section 5.7: the bearing's bias against the window fluctuates within 0.23 deg; eq. 7.19's cubic,
    fitted on the decoded windows of a static beacon at 10 distances, leaves less than 0.02 deg of it."""
    hardware = HARDWARE.hardware
    windows = np.linspace(*hardware.window_range_rad, 200)
    assert np.ptp(hardware.power_bias_rad(windows)) / DEG == pytest.approx(0.23, rel=1e-3)
    decoder = BearingDecoder(HARDWARE.codes, VarianceModel(HARDWARE.codes), receiver=HARDWARE.receiver)
    per_distance = []
    # the experiment's distances (1-6 m): outside its windows the bias is held (receiver.HardwareNoise)
    for k, distance_m in enumerate(np.linspace(1.0, 4.4, 10)):
        simulator = SensorSimulator(HARDWARE, [SimulatedBeacon(3, distance_m, 0.0)], np.random.default_rng(k))
        decoder.reset()
        decoded = [
            decoder.decode(simulator.revolution(lambda t: (0.0, 0.0, -1.0), n * HARDWARE.period_s))
            for n in range(150)
        ]
        bearings = [b for revolution in decoded for b in revolution.bearings]
        errors = wrap_to_pi(np.array([b.bearing for b in bearings]) - 1.0)  # the beacon is at 1 rad
        per_distance.append((np.mean([b.angular_window for b in bearings]), np.mean(errors)))
    window, bias = np.array(per_distance).T
    assert np.ptp(bias) / DEG > 0.15  # the bias is there before the correction
    correction = BearingCorrection(tuple(np.polyfit(window, bias, 3)))
    residual = wrap_to_pi(bias - np.asarray(correction.power_bias(window)))
    assert np.ptp(residual) / DEG < 0.02


@settings(max_examples=60, deadline=None)
@given(
    n_codes=st.integers(min_value=2, max_value=7),
    index=st.integers(min_value=1, max_value=7),
    fraction=st.floats(min_value=0.0, max_value=0.9),
    exponent=st.sampled_from([1.0, -0.5]),
    periods=st.floats(min_value=2.0, max_value=5.0),
)
def test_window_shortening_is_the_mean_over_every_code_phase(n_codes, index, fraction, exponent, periods):
    """Eq. 5.2 with the minimum burst: the mean of phi_W - (Phi_f - Phi_r) over a uniform code phase."""
    code = family_code(min(index, n_codes), n_codes)
    receiver = ReceiverModel(fraction, exponent)
    window_s = periods * code.duration_s
    phases = (np.arange(20000) + 0.5) / 20000 * code.duration_s
    first, last, detected = first_last_edges(code, phases, phases + window_s, receiver.min_burst_s(code))
    assert np.all(detected)
    measured = np.mean(window_s - (last - first))
    assert measured == pytest.approx(receiver.window_shortening_s(code), rel=2e-3)
    assert IDEAL_RECEIVER.window_shortening_s(code) == pytest.approx(code.window_bias_s)


def test_custom_code_shortening_reproduces_the_table_5_1_biases():
    """The hardware receiver's mean shortening of C_5, C_5b, C_5c (what the decoder adds back) is the
    experiment column of table 5.1 within 3%, the ideal receiver's (eq. 5.2) its theory column."""
    codes = codes_from_strings([TEST_CODES[name] for name in ("C_5", "C_5b", "C_5c")])
    omega = HARDWARE.turret_speed_rad_s
    for code, name in zip(codes, ("C_5", "C_5b", "C_5c"), strict=True):
        shortening_deg = HARDWARE.receiver.window_shortening_s(code) * omega / DEG
        assert -shortening_deg == pytest.approx(EXPERIMENT_WINDOW_BIAS_DEG[name], rel=0.03)


def _one_code_window(bit_rad: float, runs: list[int]) -> RevolutionEdges:
    boundaries = 1.0 + np.concatenate([[0.0], np.cumsum(runs)]) * bit_rad
    times = boundaries / (2 * np.pi) * 0.09984
    return RevolutionEdges(0, 0.0, 0.09984, times, boundaries, np.arange(boundaries.size) % 2 == 0)


def test_complete_codes_needed_is_a_parameter_with_the_thesis_default():
    """Section 2.5.2: the code seen at least twice by default; one complete code of code 2 (runs
    1 2 1 8 after a partial burst) is rejected then, accepted with min_codes_seen=1; below 1 is refused."""
    codes = code_family()
    bit = codes[0].bit_time_s * 2 * np.pi / 0.09984
    once = _one_code_window(bit, [1, 1, 2, 1, 8, 1, 1])
    twice = _one_code_window(bit, [1, 1, 2, 1, 8, 1, 2, 1, 8, 1, 1])
    default = BearingDecoder(codes, VarianceModel(codes))
    assert default.decode(once).bearings == []
    assert [r.kind for r in default.decode(once).rejections] == ["too_few_codes"]
    assert [b.codes_seen for b in default.decode(twice).bearings] == [2]
    assert [
        b.beacon_id
        for b in BearingDecoder(codes, VarianceModel(codes), min_codes_seen=1).decode(once).bearings
    ] == [2]
    with pytest.raises(ValueError, match="min_codes_seen"):
        BearingDecoder(codes, VarianceModel(codes), min_codes_seen=0)


@pytest.mark.parametrize(("distance_m", "rate_one", "rate_two"), [(3.6, 1.0, 1.0), (5.5, 1.0, 0.0)])
def test_detection_against_distance_with_one_or_two_complete_codes(distance_m, rate_one, rate_two):
    """On the Eurobot table (at most 3.6 m, 42 bits) two complete codes cost no detection; at 5.5 m
    (25 bits) they need more bits than the window holds (bench/bench_driver.py sweeps the window)."""
    rates = []
    for needed in (1, 2):
        decoder = BearingDecoder(HARDWARE.codes, VarianceModel(HARDWARE.codes), min_codes_seen=needed)
        simulator = SensorSimulator(HARDWARE, [SimulatedBeacon(4, distance_m, 0.0)], np.random.default_rng(7))
        decoded = [
            decoder.decode(simulator.revolution(lambda t: (0.0, 0.0, -1.0), n * HARDWARE.period_s))
            for n in range(60)
        ]
        rates.append(sum(len(d.bearings) for d in decoded[1:]) / 59)
    assert rates == pytest.approx([rate_one, rate_two], abs=0.05)


@settings(max_examples=40, deadline=None)
@given(st.floats(0.0, 1.0))
def test_power_bias_slope_is_the_cubics_derivative_and_zero_where_held(fraction):
    """The correction's slope (what a window error does to a corrected bearing) against a central
    difference of the simulated bias inside the experiment's windows; 0 outside them, where it is held."""
    correction = HARDWARE.hardware.power_bias_correction()
    low, high = HARDWARE.hardware.window_range_rad
    window, step = low + 0.02 + fraction * (high - low - 0.04), 1e-6
    difference = (
        HARDWARE.hardware.power_bias_rad(window + step) - HARDWARE.hardware.power_bias_rad(window - step)
    ) / (2 * step)
    assert correction.power_bias_slope(window) == pytest.approx(float(difference), rel=1e-5, abs=1e-9)
    assert correction.power_bias_slope(high + 0.01) == 0.0
    assert HARDWARE.hardware.power_bias_rad(high + 0.1) == pytest.approx(
        HARDWARE.hardware.power_bias_rad(high)
    )


@settings(max_examples=20, deadline=None)
@given(st.floats(20.0, 80.0))
def test_window_variance_is_the_codes_outer_edges_variance(window_bits):
    """The decoded window's OOK variance from the model against the first and last edges of code AND
    window over a fine grid of code phases (the minimum burst of the thesis hardware included)."""
    code = HARDWARE.codes[1]
    model = VarianceModel(
        HARDWARE.codes,
        min_burst_fraction=HARDWARE.min_burst_fraction,
        min_burst_gap_exponent=HARDWARE.min_burst_gap_exponent,
    )
    window_s = window_bits * code.bit_time_s
    starts = np.linspace(0.0, code.duration_s, 40000, endpoint=False)
    rising, falling, detected = first_last_edges(
        code, starts, starts + window_s, HARDWARE.receiver.min_burst_s(code)
    )
    assert detected.all()
    measured = np.var(falling - rising) * HARDWARE.turret_speed_rad_s**2
    predicted = model.window_variance_rad2(code, window_s * HARDWARE.turret_speed_rad_s)
    assert predicted == pytest.approx(measured, rel=0.02, abs=1e-4 * PHI0_RAD**2)


class _EdgeNoiseOnly:
    """A variance model of edge noise alone (no code: no window variance of its own), for the
    propagation through the power-bias correction."""

    def __init__(self, rising_rad2: float, falling_rad2: float) -> None:
        self.edges = (rising_rad2, falling_rad2)

    def code(self, code):
        return code

    def variance(self, code, angular_window_rad):
        return sum(self.edges) / 4.0

    def window_variance_rad2(self, code, angular_window_rad):
        return 0.0


@settings(max_examples=20, deadline=None)
@given(fraction=st.floats(0.0, 1.0), seed=st.integers(0, 2**32 - 1))
def test_corrected_variance_is_the_spread_of_bearings_corrected_at_their_noisy_window(fraction, seed):
    """Edges jittered as the thesis hardware's at a window (rising the noisier, fig. 5.3), the bearing and
    window of eq. 2.5, the bias corrected at the noisy window (eq. 7.18): the corrected bearings' spread
    is CorrectedVariance's, with its cross term (its sign flipped fails this), not the
    uncorrected bearing's variance."""
    from beams_driver.variance import CorrectedVariance

    noise = HARDWARE.hardware
    correction = noise.power_bias_correction()
    low, high = noise.window_range_rad
    window = low + 0.005 + fraction * (high - low - 0.01)
    rising_std, falling_std = (float(s) for s in noise.edge_std_rad(window, None))
    rng = np.random.default_rng(seed)
    samples = 40000
    rising = -window / 2 + rising_std * rng.standard_normal(samples)
    falling = window / 2 + falling_std * rng.standard_normal(samples)
    decoded_window = falling - rising
    corrected = (rising + falling) / 2 - np.asarray(correction.power_bias(decoded_window))
    model = _EdgeNoiseOnly(rising_std**2, falling_std**2)
    published = CorrectedVariance(model, correction, lambda code, w: model.edges).variance(None, window)
    # 40000 samples: the sample variance within 1.5 % (1 sd), 6 % is 4 sd
    assert np.var(corrected) == pytest.approx(published, rel=0.06)
    assert CorrectedVariance(model, correction, lambda code, w: model.edges).variance(None, high + 0.01) == (
        model.variance(None, high + 0.01)
    )


def test_the_driver_splits_its_natural_variance_as_the_thesis_receiver():
    """parameters.corrected_variance_of: the natural variance (sigma_r^2 + sigma_f^2) / 4 split as fig. 5.3
    (the rising edge 0.96 of it at the smallest window, 0.86 at the largest), so the published variance
    of a corrected bearing is what the simulator's true edge noise gives at the default natural variance."""
    from beams_driver.parameters import SENSOR_PARAMETERS, corrected_variance_of, variance_model_of
    from beams_driver.variance import CorrectedVariance

    noise = HARDWARE.hardware
    low, high = noise.window_range_rad
    assert noise.rising_share(low) == pytest.approx(0.0018 / (0.0018 + 0.000066))
    assert noise.rising_share(high) == pytest.approx(0.0137 / (0.0137 + 0.0023))
    model = variance_model_of(SENSOR_PARAMETERS.defaults(), HARDWARE.codes, HARDWARE)
    correction = noise.power_bias_correction()

    def true_edges(code, window):
        return tuple(float(s) ** 2 for s in noise.edge_std_rad(window, code))

    simulated = CorrectedVariance(model, correction, true_edges)
    published = corrected_variance_of(model, correction)
    for window in np.linspace(low + 0.002, high - 0.002, 7):
        code = HARDWARE.codes[0].code_id
        assert published.variance(code, window) == pytest.approx(simulated.variance(code, window), rel=0.02)
    assert published.variance(code, 0.0) == model.variance(code, 0.0)  # below the range: held, slope 0
