"""BeAMS beacon codes: the family of eq. 2.6 and validated custom code lists (thesis section 2.4.4). The
family C_i = [1^i 0 1^(2Nc-i) 0], i = 1..Nc, at 30.8 us a bit (14 periods of the 455 kHz carrier, the
TSOP7000's best sensitivity), is the thesis's choice; any other list must meet the constraints
`validate_codes` checks."""

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

BIT_TIME_S = 30.8e-6
DEFAULT_CODE_COUNT = 5
MAX_FAMILY_CODE_COUNT = 9
# TSOP7000 limits (section 2.4.4, constraint 1).
MIN_BURST_S = 22e-6
MAX_BURST_S = 500e-6
MIN_GAP_S = 26e-6
# Durations compared to these limits are products of floats: allow for rounding only.
_LIMIT_TOLERANCE_S = 1e-12


@dataclass(frozen=True)
class BeaconCode:
    """One beacon code: its identifier, its bits (one period, sent in a loop) and the bit time (s)."""

    code_id: int
    bits: tuple[int, ...]
    bit_time_s: float = BIT_TIME_S

    def __post_init__(self) -> None:
        bits = tuple(int(b) for b in self.bits)
        if any(b not in (0, 1) for b in bits):
            raise ValueError(f"code {self.code_id}: bits must be 0 or 1, got {self.bits!r}")
        if 0 not in bits or 1 not in bits:
            raise ValueError(f"code {self.code_id}: a code needs at least one 1 and one 0, got {bits!r}")
        if not self.bit_time_s > 0.0:
            raise ValueError(f"code {self.code_id}: bit time must be positive, got {self.bit_time_s}")
        object.__setattr__(self, "bits", bits)

    @classmethod
    def from_string(cls, code_id: int, bit_string: str, bit_time_s: float = BIT_TIME_S) -> "BeaconCode":
        """Build a code from a string of '0' and '1' (e.g. '111110111110')."""
        text = bit_string.strip()
        if not text or set(text) - {"0", "1"}:
            raise ValueError(f"code {code_id}: expected a string of 0 and 1, got {bit_string!r}")
        return cls(code_id, tuple(int(c) for c in text), bit_time_s)

    def __str__(self) -> str:
        return "".join(str(b) for b in self.bits)

    @property
    def n_bits(self) -> int:
        """N_b, bits in one period of the code."""
        return len(self.bits)

    @property
    def duration_s(self) -> float:
        """T_c = N_b T_b (s)."""
        return self.n_bits * self.bit_time_s

    @property
    def p0(self) -> float:
        """p0 = N_0 / N_b, the probability of a 0 at a random instant (section 3.3)."""
        return self.bits.count(0) / self.n_bits

    @cached_property
    def runs_bits(self) -> tuple[tuple[int, int], ...]:
        """Cyclic run lengths (level, n_bits), starting with the burst that follows a gap."""
        start = next(k for k in range(self.n_bits) if self.bits[k] == 1 and self.bits[k - 1] == 0)
        rotated = self.bits[start:] + self.bits[:start]
        runs: list[tuple[int, int]] = []
        for bit in rotated:
            if runs and runs[-1][0] == bit:
                runs[-1] = (bit, runs[-1][1] + 1)
            else:
                runs.append((bit, 1))
        return tuple(runs)

    @property
    def burst_bits(self) -> tuple[int, ...]:
        """Lengths (bits) of the bursts of one period, in emission order."""
        return tuple(n for level, n in self.runs_bits if level == 1)

    @property
    def gap_bits(self) -> tuple[int, ...]:
        """Lengths (bits) of the gaps of one period, in emission order."""
        return tuple(n for level, n in self.runs_bits if level == 0)

    @cached_property
    def on_intervals_s(self) -> tuple[np.ndarray, np.ndarray]:
        """Burst starts and ends (s) over one period [0, T_c], the period starting on a burst."""
        lengths = np.array([n for _, n in self.runs_bits], dtype=float) * self.bit_time_s
        edges = np.concatenate([[0.0], np.cumsum(lengths)])
        return edges[:-1:2].copy(), edges[1::2].copy()

    @property
    def window_bias_s(self) -> float:
        """Mean shortening of the measured window (s): sum of squared gaps / T_c (eq. 5.2: p0 T0)."""
        gaps_s = np.array(self.gap_bits, dtype=float) * self.bit_time_s
        return float(np.sum(gaps_s**2) / self.duration_s)

    @property
    def variance_bound_s2(self) -> float:
        """Upper bound of the bearing error variance (s^2): sum of cubed gaps / (6 T_c), theorem 3.1's
        (eq. 3.41) E{E_r^2}/2 for gaps of any lengths."""
        gaps_s = np.array(self.gap_bits, dtype=float) * self.bit_time_s
        return float(np.sum(gaps_s**3) / (6.0 * self.duration_s))

    @property
    def gap_time_s(self) -> float | None:
        """T_0, the single gap duration (s), or None when the gaps differ (section 3.3 assumes one)."""
        gaps = set(self.gap_bits)
        return gaps.pop() * self.bit_time_s if len(gaps) == 1 else None

    @cached_property
    def canonical_pattern(self) -> tuple[int, ...]:
        """The smallest rotation of the code's shortest period: equal for codes that send the same signal."""
        n = self.n_bits
        period = next(p for p in range(1, n + 1) if n % p == 0 and self.bits == self.bits[p:] + self.bits[:p])
        base = self.bits[:period]
        return min(base[k:] + base[:k] for k in range(period))


def family_code(index: int, n_codes: int = DEFAULT_CODE_COUNT, bit_time_s: float = BIT_TIME_S) -> BeaconCode:
    """C_i = [1^i 0 1^(2Nc-i) 0] of eq. 2.6, with identifier i."""
    if not 1 <= index <= n_codes:
        raise ValueError(f"family code index {index} outside 1..{n_codes}")
    bits = (1,) * index + (0,) + (1,) * (2 * n_codes - index) + (0,)
    return BeaconCode(index, bits, bit_time_s)


def code_family(
    n_codes: int = DEFAULT_CODE_COUNT, bit_time_s: float = BIT_TIME_S, max_burst_s: float = MAX_BURST_S
) -> tuple[BeaconCode, ...]:
    """The family C_1..C_Nc of eq. 2.6, validated against the receiver's limits (Nc = 9, allowed by section
    2.5.2, holds a 523.6 us burst: it needs max_burst_s raised knowingly)."""
    if not 1 <= n_codes <= MAX_FAMILY_CODE_COUNT:
        raise ValueError(f"code family: Nc = {n_codes} outside 1..{MAX_FAMILY_CODE_COUNT} (section 2.5.2)")
    codes = tuple(family_code(i, n_codes, bit_time_s) for i in range(1, n_codes + 1))
    validate_codes(codes, max_burst_s=max_burst_s)
    return codes


def is_family_code(code: BeaconCode) -> tuple[int, int] | None:
    """(i, Nc) when the code is C_i of a family with Nc codes (any bit time), else None."""
    n_bits = code.n_bits
    if n_bits % 2 or n_bits < 4:
        return None
    n_codes = n_bits // 2 - 1
    index = code.bits.index(0)
    if 1 <= index <= n_codes and code.bits == family_code(index, n_codes).bits:
        return index, n_codes
    return None


def codes_from_strings(bit_strings: Sequence[str], bit_time_s: float = BIT_TIME_S) -> tuple[BeaconCode, ...]:
    """A validated custom code list; code k (1-based) gets identifier k."""
    codes = tuple(BeaconCode.from_string(k, s, bit_time_s) for k, s in enumerate(bit_strings, start=1))
    validate_codes(codes)
    return codes


def validate_codes(
    codes: Sequence[BeaconCode],
    min_burst_s: float = MIN_BURST_S,
    max_burst_s: float = MAX_BURST_S,
    min_gap_s: float = MIN_GAP_S,
) -> None:
    """Raise ValueError unless the list meets section 2.4.4's constraints: bursts in [22, 500] us and gaps
    >= 26 us, runs wrapping around (sent in a loop), and no rotation of one code equal to another."""
    if not codes:
        raise ValueError("code list is empty")
    ids = [c.code_id for c in codes]
    if len(set(ids)) != len(ids):
        raise ValueError(f"code list: duplicated code identifiers {ids}")
    problems: list[str] = []
    for code in codes:
        problems.extend(_receiver_problems(code, min_burst_s, max_burst_s, min_gap_s))
    seen: dict[tuple[int, ...], int] = {}
    for code in codes:
        other = seen.setdefault(code.canonical_pattern, code.code_id)
        if other != code.code_id:
            problems.append(
                f"code {code.code_id} ({code}) is a rotation of code {other}: indistinguishable in a loop"
            )
    if problems:
        raise ValueError("invalid code list: " + "; ".join(problems))


def _receiver_problems(
    code: BeaconCode, min_burst_s: float, max_burst_s: float, min_gap_s: float
) -> list[str]:
    """The TSOP7000 limits one code breaks, as readable messages."""
    name = f"code {code.code_id} ({code})"
    shortest_burst = min(code.burst_bits) * code.bit_time_s
    longest_burst = max(code.burst_bits) * code.bit_time_s
    shortest_gap = min(code.gap_bits) * code.bit_time_s
    checks = (
        (shortest_burst < min_burst_s - _LIMIT_TOLERANCE_S, "burst", shortest_burst, "<", min_burst_s),
        (longest_burst > max_burst_s + _LIMIT_TOLERANCE_S, "burst", longest_burst, ">", max_burst_s),
        (shortest_gap < min_gap_s - _LIMIT_TOLERANCE_S, "gap", shortest_gap, "<", min_gap_s),
    )
    return [
        f"{name}: {what} of {value * 1e6:.1f} us {sign} {limit * 1e6:g} us"
        for broken, what, value, sign, limit in checks
        if broken
    ]


# ---- The ideal receiver: output = code AND window (section 3.2), with the minimum burst of section 5.6 ----


def bursts_in_window(
    code: BeaconCode, start_s: float, end_s: float, min_burst_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Bursts (start, end) (s, code time) the receiver outputs for the window [start_s, end_s], the code's
    period starting at 0 on runs_bits[0]; clipped outer bursts shorter than min_burst_s are not detected (the
    'AND hypothesis' departure of section 5.6)."""
    period_s = code.duration_s
    on_start, on_end = code.on_intervals_s
    first, last = int(np.floor(start_s / period_s)), int(np.floor(end_s / period_s))
    offsets = np.arange(first, last + 1, dtype=float)[:, None] * period_s
    starts = np.maximum((on_start + offsets).ravel(), start_s)
    ends = np.minimum((on_end + offsets).ravel(), end_s)
    keep = _detectable(ends - starts, min_burst_s)
    return starts[keep], ends[keep]


def first_last_edges(
    code: BeaconCode, start_s: np.ndarray, end_s: np.ndarray, min_burst_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rising_s, falling_s, detected): the first rising and last falling edge (code time) of code AND window,
    vectorised over windows; meaningless where nothing is detected."""
    start = np.asarray(start_s, dtype=float)
    end = np.asarray(end_s, dtype=float)
    starts, ends = _periodic_bursts(code)
    period_s = code.duration_s
    base = np.floor(start / period_s) * period_s
    rising, detected = _first_rising(starts, ends, start - base, end - base, min_burst_s)
    base_end = np.floor(end / period_s) * period_s
    falling = _last_falling(starts, ends, start - base_end, end - base_end, min_burst_s)
    return rising + base, falling + base_end, detected


def _detectable(length_s: np.ndarray, min_burst_s: float) -> np.ndarray:
    """A burst triggers the receiver when it lasts at least min_burst_s (and is not empty)."""
    return (length_s > 0.0) & (length_s >= min_burst_s)


def _periodic_bursts(code: BeaconCode) -> tuple[np.ndarray, np.ndarray]:
    """Burst starts and ends over periods -2..2, so that look-ups around [0, T_c) stay inside."""
    on_start, on_end = code.on_intervals_s
    offsets = np.arange(-2, 3, dtype=float)[:, None] * code.duration_s
    return (on_start + offsets).ravel(), (on_end + offsets).ravel()


def _first_rising(
    starts: np.ndarray, ends: np.ndarray, start: np.ndarray, end: np.ndarray, min_burst_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """First detected burst start at or after `start` (in [0, T_c)), clipped by `end`."""
    i = np.searchsorted(ends, start, side="right")
    rise1 = np.maximum(starts[i], start)
    ok1 = _detectable(np.minimum(ends[i], end) - rise1, min_burst_s)
    # Only the burst after a too-short first one can still be detected: the next one is complete or clipped.
    rise2 = starts[i + 1]
    ok2 = _detectable(np.minimum(ends[i + 1], end) - rise2, min_burst_s)
    return np.where(ok1, rise1, rise2), ok1 | ok2


def _last_falling(
    starts: np.ndarray, ends: np.ndarray, start: np.ndarray, end: np.ndarray, min_burst_s: float
) -> np.ndarray:
    """Last detected burst end at or before `end` (in [0, T_c)), clipped by `start`."""
    j = np.searchsorted(starts, end, side="left") - 1
    fall1 = np.minimum(ends[j], end)
    ok1 = _detectable(fall1 - np.maximum(starts[j], start), min_burst_s)
    return np.where(ok1, fall1, ends[j - 1])
