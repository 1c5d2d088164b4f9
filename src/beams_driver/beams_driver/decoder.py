"""From one revolution's edges to identified bearings (thesis sections 2.4.3-2.4.5 and eq. 5.2): windows split
by the 4-bit timeout, their runs matched against the codes' cyclic patterns, `min_codes_seen` complete codes
(section 2.5.2); compound windows (section 2.4.5) and misfits rejected with a reason. A bearing is (phi_r +
phi_f) / 2 (eq. 2.5) with its window plus the mean shortening (eq. 5.2), variance and instant; a window
belongs to the revolution it closes in, which reports each beacon at most once."""

from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Protocol

import numpy as np

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.bearing import Bearing
from beams_driver.codes import BeaconCode
from beams_driver.edges import RevolutionEdges
from beams_driver.receiver import IDEAL_RECEIVER, ReceiverModel

TIMEOUT_BITS = 4.0
DURATION_TOLERANCE_BITS = 0.35
# The outer edges carry the receiver's AGC noise (section 5.6): judge outer bursts loosely.
OUTER_BURST_TOLERANCE_BITS = 2.0
# Section 2.5.2: the code seen at least twice in the window.
MIN_CODES_SEEN = 2
_TWO_PI = 2.0 * np.pi


class VarianceSource(Protocol):
    """What the decoder needs from a variance model (beams_driver.variance.VarianceModel)."""

    def variance(self, code: int | BeaconCode, angular_window_rad: float) -> float: ...


@dataclass(frozen=True)
class DecodedBearing:
    """One identified beacon (the fields of beams_msgs/BeaconBearing, plus its instant)."""

    beacon_id: int
    bearing: float
    variance: float
    angular_window: float
    rising_angle: float
    falling_angle: float
    codes_seen: int
    stamp_s: float

    def as_bearing(self) -> Bearing:
        """The bearing as the triangulation and the EKF take it (beams_common.geometry.bearing)."""
        return Bearing(self.stamp_s, self.beacon_id, self.bearing, self.variance)


@dataclass(frozen=True)
class Rejection:
    """A window that gave no bearing: reason 'kind: details', at the window's mid angle (rad, (-pi, pi])."""

    reason: str
    angle_rad: float

    @property
    def kind(self) -> str:
        """Category: malformed, truncated, undecodable, compound, inconsistent, ambiguous, too_few_codes,
        lost_frames, repeated."""
        return self.reason.split(":", 1)[0]


@dataclass(frozen=True)
class DecodedRevolution:
    """The bearings and rejections of one revolution."""

    revolution: int
    start_time_s: float
    period_s: float
    bearings: list[DecodedBearing] = field(default_factory=list)
    rejections: list[Rejection] = field(default_factory=list)

    def bearing_of(self, beacon_id: int) -> DecodedBearing | None:
        """The bearing of one beacon in this revolution, if it was decoded."""
        return next((b for b in self.bearings if b.beacon_id == beacon_id), None)


@dataclass(frozen=True)
class _CodePattern:
    """A code's cyclic run lengths (bits) [b1, g1, b2, g2, ...] and its gap-aligned rotations."""

    code: BeaconCode
    runs: np.ndarray
    # Offsets into `runs` of the gaps: where the first complete run of a window (a gap) can sit.
    gap_offsets: np.ndarray
    # Every run length the code holds: a window with any other length cannot be this code alone.
    lengths: frozenset[int]


@dataclass(frozen=True)
class _OpenWindow:
    """Edges of a window still open when its revolution ended (angles from that revolution's zero)."""

    revolution: int
    angles: np.ndarray
    rising: np.ndarray
    lost: np.ndarray  # that revolution's lost intervals (RevolutionEdges.lost_angles_rad)


class BearingDecoder:
    """Decoder shared by every edge source (simulated or serial)."""

    def __init__(
        self,
        codes: Sequence[BeaconCode],
        variance_model: VarianceSource,
        *,
        timeout_bits: float = TIMEOUT_BITS,
        duration_tolerance_bits: float = DURATION_TOLERANCE_BITS,
        min_codes_seen: int = MIN_CODES_SEEN,
        receiver: ReceiverModel = IDEAL_RECEIVER,
    ) -> None:
        """codes: the valid code list; a window must show min_codes_seen complete codes to be accepted;
        receiver: whose minimum burst (and outer shift) the window correction accounts for."""
        if not codes:
            raise ValueError("decoder: empty code list")
        bit_times = {c.bit_time_s for c in codes}
        if len(bit_times) != 1:
            raise ValueError(f"decoder: all codes must share one bit time, got {sorted(bit_times)}")
        if not 0.0 < duration_tolerance_bits < 0.5:
            raise ValueError("decoder: duration tolerance must be in (0, 0.5) bit")
        if int(min_codes_seen) < 1:
            raise ValueError(f"decoder: min_codes_seen must be >= 1, got {min_codes_seen}")
        self.codes = tuple(codes)
        self.bit_time_s = bit_times.pop()
        self.variance_model = variance_model
        self.timeout_bits = float(timeout_bits)
        self.duration_tolerance_bits = float(duration_tolerance_bits)
        self.min_codes_seen = int(min_codes_seen)
        self._patterns = [_pattern(c) for c in self.codes]
        self.receiver = receiver
        self._window_shortening_s = {c.code_id: receiver.window_shortening_s(c) for c in self.codes}
        self._open: _OpenWindow | None = None
        # the last revolution decoded: a window at the start of the next one may have begun in it
        self._last_revolution: int | None = None

    def decode(self, edges: RevolutionEdges) -> DecodedRevolution:
        """Bearings and rejections of the windows that closed during this revolution; an open window is
        carried into the next, one opening on the zero reference after a skipped revolution is truncated."""
        result = DecodedRevolution(edges.revolution, edges.start_time_s, edges.period_s)
        omega = edges.turret_speed_rad_s
        timeout_rad = self.timeout_bits * self.bit_time_s * omega
        angles, rising, lost = edges.edge_angles_rad, edges.edge_rising, edges.lost_angles_rad
        carried, self._open = self._open, None
        follows_previous = self._last_revolution == edges.revolution - 1
        self._last_revolution = edges.revolution
        if carried is not None and follows_previous:
            angles = np.concatenate([carried.angles - _TWO_PI, angles])
            rising = np.concatenate([carried.rising, rising])
            lost = np.concatenate([carried.lost - _TWO_PI, lost])
        elif carried is not None:
            where = float(wrap_to_pi(carried.angles[-1]))
            result.rejections.append(Rejection("truncated: the next revolution is missing", where))
        windows = _split(angles, rising, timeout_rad)
        if windows and not follows_previous and (windows[0][0][0] <= timeout_rad or not windows[0][1][0]):
            # its head may lie in the undecoded revolution before: the bearing would be off by half of it
            where = float(wrap_to_pi(0.5 * (windows[0][0][0] + windows[0][0][-1])))
            result.rejections.append(
                Rejection("truncated: the window began before the first decoded revolution", where)
            )
            windows.pop(0)
        if windows and (windows[-1][1][-1] or _TWO_PI - windows[-1][0][-1] <= timeout_rad):
            last_angles, last_rising = windows.pop()
            if last_angles[-1] - last_angles[0] < _TWO_PI:
                self._open = _OpenWindow(edges.revolution, last_angles, last_rising, edges.lost_angles_rad)
            else:
                # A receiver stuck on (or flooded) never closes a window: drop it rather than grow it.
                where = float(wrap_to_pi(last_angles[-1]))
                result.rejections.append(Rejection("malformed: a window longer than a revolution", where))
        for window_angles, window_rising in windows:
            if _touches(lost, window_angles[0] - timeout_rad, window_angles[-1] + timeout_rad):
                where = float(wrap_to_pi(0.5 * (window_angles[0] + window_angles[-1])))
                result.rejections.append(Rejection("lost_frames: edges of the window may be missing", where))
                continue
            outcome = self._decode_window(window_angles, window_rising, omega)
            if isinstance(outcome, Rejection):
                result.rejections.append(outcome)
            else:
                code, codes_seen = outcome
                bearing = self._bearing(code, codes_seen, window_angles, edges.start_time_s, omega)
                result.bearings.append(bearing)
        _one_pass_per_beacon(result)
        return result

    def reset(self) -> None:
        """Forget the window carried over from the last revolution (after a gap in the stream)."""
        self._open = None
        self._last_revolution = None

    def _decode_window(
        self, angles: np.ndarray, rising: np.ndarray, omega: float
    ) -> Rejection | tuple[BeaconCode, int]:
        """(code, complete codes seen) for a clean window, else a Rejection."""
        where = float(wrap_to_pi(0.5 * (angles[0] + angles[-1])))
        if not rising[0]:
            return Rejection("malformed: the window opens with a falling edge", where)
        if angles.size < 2 or angles.size % 2 or not (np.all(rising[0::2]) and not np.any(rising[1::2])):
            return Rejection(f"malformed: {angles.size} edges do not alternate rising/falling", where)
        bit_rad = self.bit_time_s * omega
        bursts = (angles[1::2] - angles[0::2]) / bit_rad
        gaps = (angles[2::2] - angles[1:-1:2]) / bit_rad
        runs = np.empty(2 * gaps.size - 1 if gaps.size else 0)
        runs[0::2] = gaps
        runs[1::2] = bursts[1:-1]
        counts = np.rint(runs).astype(int)
        bad = int(np.count_nonzero((np.abs(runs - counts) > self.duration_tolerance_bits) | (counts < 1)))
        if runs.size == 0:
            return Rejection("undecodable: no complete burst or gap", where)
        if bad == 0:
            lengths = set(counts.tolist())
            candidates = [p for p in self._patterns if lengths <= p.lengths]
            fits = [(p, offsets) for p in candidates if (offsets := _matching_offsets(p, counts)).size]
            return self._choose(fits, counts, (bursts[0], bursts[-1]), where)
        return self._diagnose(counts, bad, where)

    def _choose(
        self,
        fits: list[tuple[_CodePattern, np.ndarray]],
        runs: np.ndarray,
        outer_bits: tuple[float, float],
        where: float,
    ) -> Rejection | tuple[BeaconCode, int]:
        """The code whose pattern every complete run fits, if it is unique and seen often enough."""
        if not fits:
            return self._diagnose(runs, 0, where)
        complete = [(p, o) for p, o in fits if runs.size >= p.runs.size]
        if len(complete) > 1:
            return Rejection(f"ambiguous: runs fit codes {[p.code.code_id for p, _ in complete]}", where)
        if len(fits) > 1 and not complete:
            return Rejection(
                f"too_few_codes: no complete code, runs fit {[p.code.code_id for p, _ in fits]}", where
            )
        pattern, offsets = complete[0] if complete else fits[0]
        seen = runs.size // pattern.runs.size
        if seen < self.min_codes_seen:
            detail = f"{seen} complete code(s) {pattern.code.code_id} < {self.min_codes_seen}"
            return Rejection(f"too_few_codes: {detail}", where)
        # The partial outer bursts cannot exceed the code's bursts there (a merged stray pulse would).
        period = pattern.runs.size
        first_limit = pattern.runs[(offsets - 1) % period].max() + OUTER_BURST_TOLERANCE_BITS
        last_limit = pattern.runs[(offsets + runs.size) % period].max() + OUTER_BURST_TOLERANCE_BITS
        if outer_bits[0] > first_limit or outer_bits[1] > last_limit:
            return Rejection(
                f"inconsistent: outer burst longer than code {pattern.code.code_id} allows", where
            )
        return pattern.code, seen

    def _diagnose(self, runs: np.ndarray, bad: int, where: float) -> Rejection:
        """Why a window fits no single code: several codes (compound), one code plus noise, or none."""
        seen_ids = [p.code.code_id for p in self._patterns if _contains_complete_code(p, runs)]
        if len(seen_ids) > 1:
            return Rejection(f"compound: codes {seen_ids} in one window", where)
        if seen_ids:
            detail = f"code {seen_ids[0]} mixed with {bad} bad or foreign durations"
            return Rejection(f"inconsistent: {detail}", where)
        return Rejection(f"undecodable: no complete code among {runs.size} runs ({bad} bad durations)", where)

    def _bearing(
        self, code: BeaconCode, codes_seen: int, angles: np.ndarray, start_time_s: float, omega: float
    ) -> DecodedBearing:
        """Eq. 2.5 bearing, eq. 5.2 window (the receiver's mean shortening added back), variance from the
        model at that window, stamped at the mid-window instant."""
        rising_angle, falling_angle = float(angles[0]), float(angles[-1])
        middle = 0.5 * (rising_angle + falling_angle)
        window = falling_angle - rising_angle + self._window_shortening_s[code.code_id] * omega
        wrapped = wrap_to_pi(np.array([middle, rising_angle, falling_angle]))
        return DecodedBearing(
            beacon_id=code.code_id,
            bearing=float(wrapped[0]),
            variance=float(self.variance_model.variance(code.code_id, window)),
            angular_window=float(window),
            rising_angle=float(wrapped[1]),
            falling_angle=float(wrapped[2]),
            codes_seen=int(codes_seen),
            stamp_s=float(start_time_s + middle / omega),
        )


def _one_pass_per_beacon(result: DecodedRevolution) -> None:
    """At most one bearing per beacon (in place): the pass nearest the revolution's middle is kept (the
    revolution's own, where `validation.one_sighting_per_beacon`'s median could keep a carried-over one), any
    other rejected as `repeated`."""
    middle_s = result.start_time_s + 0.5 * result.period_s
    kept: dict[int, DecodedBearing] = {}
    for bearing in result.bearings:
        other = kept.get(bearing.beacon_id)
        if other is None or abs(bearing.stamp_s - middle_s) < abs(other.stamp_s - middle_s):
            kept[bearing.beacon_id] = bearing
    if len(kept) == len(result.bearings):
        return
    for bearing in result.bearings:
        if kept[bearing.beacon_id] is not bearing:
            result.rejections.append(
                Rejection(
                    f"repeated: beacon {bearing.beacon_id} passed twice in one revolution (the robot "
                    f"turning against the turret), the pass nearest the revolution's middle kept",
                    bearing.bearing,
                )
            )
    result.bearings[:] = [b for b in result.bearings if kept[b.beacon_id] is b]


def _touches(intervals: np.ndarray, low: float, high: float) -> bool:
    """Whether any interval (m, 2) overlaps [low, high]."""
    return bool(np.any((intervals[:, 0] <= high) & (intervals[:, 1] >= low)))


def _split(angles: np.ndarray, rising: np.ndarray, timeout_rad: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Windows: a rising edge more than the timeout after a falling edge opens a new one (section 2.4.4)."""
    if angles.size == 0:
        return []
    opens = np.zeros(angles.size, dtype=bool)
    opens[0] = True
    opens[1:] = rising[1:] & ~rising[:-1] & (np.diff(angles) > timeout_rad)
    boundaries = np.append(np.flatnonzero(opens), angles.size)
    return [(angles[a:b], rising[a:b]) for a, b in pairwise(boundaries)]


def _pattern(code: BeaconCode) -> _CodePattern:
    """The code's runs [b1, g1, b2, g2, ...] and the offsets of its gaps (where a window's runs start)."""
    runs = np.array([n for _, n in code.runs_bits], dtype=int)
    return _CodePattern(code, runs, np.arange(1, runs.size, 2), frozenset(int(n) for n in runs))


def _expected(pattern: _CodePattern, length: int) -> np.ndarray:
    """Expected runs (alignments, length) for every gap-aligned phase of the code."""
    index = (pattern.gap_offsets[:, None] + np.arange(length)[None, :]) % pattern.runs.size
    return pattern.runs[index]


def _matching_offsets(pattern: _CodePattern, runs: np.ndarray) -> np.ndarray:
    """Offsets (into the pattern) of the phases at which every complete run fits the code."""
    return pattern.gap_offsets[np.all(_expected(pattern, runs.size) == runs[None, :], axis=1)]


def _contains_complete_code(pattern: _CodePattern, runs: np.ndarray) -> bool:
    """True when some stretch of one full code period, starting on a gap, fits the code."""
    period = pattern.runs.size
    if runs.size < period:
        return False
    mismatch = (_expected(pattern, runs.size) != runs[None, :]).astype(int)
    cumulative = np.zeros((mismatch.shape[0], runs.size + 1), dtype=int)
    cumulative[:, 1:] = np.cumsum(mismatch, axis=1)
    window_mismatch = cumulative[:, period:] - cumulative[:, :-period]
    # A stretch must start on a gap (even index) with the alignment whose phase it is in.
    return bool(np.any(window_mismatch[:, 0::2] == 0))
