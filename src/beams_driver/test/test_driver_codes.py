"""The code family (eq. 2.6), custom code validation (section 2.4.4) and the AND receiver (section 3.2)."""

import numpy as np
import pytest

from beams_driver.codes import (
    BeaconCode,
    bursts_in_window,
    code_family,
    codes_from_strings,
    family_code,
    first_last_edges,
    is_family_code,
    validate_codes,
)


def test_family_matches_eq_2_6_and_section_4_4_durations():
    codes = code_family()
    assert [str(c) for c in codes] == [
        "101111111110",
        "110111111110",
        "111011111110",
        "111101111110",
        "111110111110",
    ]
    for code in codes:
        assert code.p0 == pytest.approx(1.0 / 6.0)
        # 12 bits of 308 ticks of 100 ns: the 3696-tick code of section 4.4.
        assert round(code.duration_s / 100e-9) == 3696
        assert code.gap_time_s == pytest.approx(30.8e-6)
        assert is_family_code(code) == (code.code_id, 5)


@pytest.mark.parametrize("n_codes", [1, 3, 5, 8])
def test_family_sizes_within_the_receiver_limits_are_valid(n_codes):
    codes = code_family(n_codes)
    assert len(codes) == n_codes
    assert all(c.n_bits == 2 * n_codes + 2 and c.bits.count(0) == 2 for c in codes)


def test_family_of_nine_breaks_the_500_us_burst_limit_with_a_clear_error():
    # C_1 of Nc = 9 holds a run of 17 ones: 523.6 us > 500 us (section 2.4.4, constraint 1).
    with pytest.raises(ValueError, match=r"burst of 523\.6 us > 500 us"):
        code_family(9)
    assert len(code_family(9, max_burst_s=530e-6)) == 9
    with pytest.raises(ValueError, match=r"outside 1\.\.9"):
        code_family(10)


def test_custom_codes_from_table_5_1_are_accepted():
    codes = codes_from_strings(["11111001111100", "1111100011111000"])
    assert [c.p0 for c in codes] == pytest.approx([2 / 7, 3 / 8])
    assert [c.gap_time_s for c in codes] == pytest.approx([61.6e-6, 92.4e-6])


@pytest.mark.parametrize(
    ("bit_strings", "message"),
    [
        (["110111111110", "111111110110"], "rotation of code 1"),
        (["10", "1010"], "rotation of code 1"),
        (["1" * 17 + "0"], r"burst of 523\.6 us > 500 us"),
        (["1111101", "0"], "at least one 1 and one 0"),
        (["11x0"], "string of 0 and 1"),
    ],
)
def test_invalid_custom_code_lists_are_refused(bit_strings, message):
    with pytest.raises(ValueError, match=message):
        codes_from_strings(bit_strings)


def test_gap_and_burst_limits_depend_on_the_bit_time():
    with pytest.raises(ValueError, match=r"gap of 20\.0 us < 26 us"):
        codes_from_strings(["1110"], bit_time_s=20e-6)
    with pytest.raises(ValueError, match="duplicated code identifiers"):
        validate_codes([family_code(1), BeaconCode(1, (1, 1, 0))])


def test_window_bias_and_bound_reduce_to_the_thesis_formulas_for_equal_gaps():
    for code in code_family():
        t0 = code.gap_time_s
        assert code.window_bias_s == pytest.approx(code.p0 * t0)  # eq. 5.2
        assert code.variance_bound_s2 == pytest.approx(code.p0 * t0**2 / 6.0)  # eq. 3.41


def _brute_force_edges(code, start, end, min_burst, step):
    """First rising and last falling edge by sampling code AND window on a fine grid."""
    t = np.arange(start, end, step)
    bit = np.floor(np.mod(t, code.duration_s) / code.bit_time_s).astype(int)
    # Code time 0 is the start of runs_bits[0] (the burst after a gap).
    levels = np.repeat([lvl for lvl, _ in code.runs_bits], [n for _, n in code.runs_bits])
    on = levels[bit] == 1
    if not on.any():
        return None
    changes = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(int), [0]])))
    bursts = [(t[a], t[b - 1] + step) for a, b in zip(changes[0::2], changes[1::2], strict=True)]
    bursts = [(a, min(b, end)) for a, b in bursts if min(b, end) - a >= min_burst]
    return (bursts[0][0], bursts[-1][1]) if bursts else None


@pytest.mark.parametrize("min_burst_fraction", [0.0, 0.56])
def test_first_last_edges_agree_with_sampling_the_and_receiver(min_burst_fraction):
    rng = np.random.default_rng(7)
    step = 0.05e-6
    for code in code_family():
        min_burst = min_burst_fraction * code.bit_time_s
        starts = rng.uniform(0.0, 3 * code.duration_s, 40)
        windows = rng.uniform(0.0, 3 * code.duration_s, 40)
        rising, falling, detected = first_last_edges(code, starts, starts + windows, min_burst)
        for k in range(starts.size):
            expected = _brute_force_edges(code, starts[k], starts[k] + windows[k], min_burst, step)
            assert detected[k] == (expected is not None)
            if expected is not None:
                assert rising[k] == pytest.approx(expected[0], abs=2 * step)
                assert falling[k] == pytest.approx(expected[1], abs=2 * step)
                bursts_start, bursts_end = bursts_in_window(
                    code, starts[k], starts[k] + windows[k], min_burst
                )
                assert (bursts_start[0], bursts_end[-1]) == pytest.approx((rising[k], falling[k]))
