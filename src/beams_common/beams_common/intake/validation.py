"""The checks every input and output of the BeAMS nodes goes through, returning a reason ('' when valid):
the bearing and odometry rules of ToTal and the EKF alike, `planar_estimate_problem` on what leaves a node.
"""

import math
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

# A real turret sees 3 beacons (the thesis's setup), a few more on a crowded table; 64 leaves room for
# 21 robots' worth of beacons yet bounds a revolution's cost (10,000 bearings froze the EKF for 0.5 s).
MAX_BEARINGS_PER_REVOLUTION = 64
# The quantisation variance of a 2 pi / 62,400 rad tick, tick^2 / 12: a bearing is known no better, and 0
# would give ToTal a singular pose covariance (eq. 6.30).
ENCODER_TICK_RAD = 2.0 * math.pi / 62_400
MIN_BEARING_VARIANCE_RAD2 = ENCODER_TICK_RAD**2 / 12.0
# Reasons travel in service replies, log lines and /diagnostics: long enough for a path and a value.
MAX_REASON_CHARS = 240
# Relative asymmetry tolerated in a covariance computed in floating point (J S J' is symmetric to
# rounding only).
SYMMETRY_TOLERANCE = 1e-9
# Eigenvalue ratio below which a covariance is singular in floating point (Cholesky may still succeed):
# six orders beyond any the nodes compute (1e-8 m^2 next to 1e-2 rad^2).
MAX_CONDITION_RECIPROCAL = 1e-12


def bounded(text: str, limit: int = MAX_REASON_CHARS) -> str:
    """`text` cut to `limit` characters, the cut marked, so that no reason costs unbounded work."""
    return text if len(text) <= limit else text[: limit - 15] + f" ... (+{len(text) - limit + 15} chars)"


def revolution_size_problem(count: int) -> str:
    """Why a revolution of `count` bearings is refused whole (too many to be a real turret's), or ''."""
    if count > MAX_BEARINGS_PER_REVOLUTION:
        return f"{count} bearings in one revolution, more than the limit {MAX_BEARINGS_PER_REVOLUTION}"
    return ""


def bearing_problem(
    beacon_id: int, bearing_rad: float, variance_rad2: float, stamp_s: float, known_ids: Iterable[int]
) -> str:
    """Why one bearing can never be used (unknown beacon, non-finite value, variance below
    MIN_BEARING_VARIANCE_RAD2), or ''."""
    if beacon_id not in known_ids:
        return f"unknown beacon id {beacon_id}: not on the beacon map"
    if not (math.isfinite(bearing_rad) and math.isfinite(stamp_s)):
        return f"beacon {beacon_id}: non-finite bearing {float(bearing_rad)!r} or stamp {float(stamp_s)!r}"
    if not (math.isfinite(variance_rad2) and variance_rad2 >= MIN_BEARING_VARIANCE_RAD2):
        return (
            f"beacon {beacon_id}: invalid bearing variance {float(variance_rad2)!r} rad^2 (must be "
            f"finite and >= {MIN_BEARING_VARIANCE_RAD2:.2e} rad^2, the encoder's quantisation)"
        )
    return ""


class Sighting(Protocol):
    """What `one_sighting_per_beacon` needs of a bearing."""

    beacon_id: int
    stamp_s: float


@dataclass(frozen=True)
class Sightings:
    """A revolution's bearings sorted out: one per beacon (`kept`), the repeated sightings set aside
    (`dropped`), and the beacons seen twice at one instant (`conflicting_ids`, not physical: refused)."""

    kept: list[Any]
    dropped: list[Any]
    conflicting_ids: list[int]


def one_sighting_per_beacon(bearings: Sequence[Sighting]) -> Sightings:
    """One bearing per beacon: of a beacon seen at two instants (a robot turning against the turret), the
    sighting nearest the revolution's median instant (the least motion compensation); at one instant,
    conflicting."""
    median_s = None  # needed only for a beacon seen twice (rare): found then
    kept: dict[int, Any] = {}
    dropped: list[Any] = []
    conflicting: list[int] = []
    for bearing in bearings:
        previous = kept.get(bearing.beacon_id)
        if previous is None:
            kept[bearing.beacon_id] = bearing
            continue
        if previous.stamp_s == bearing.stamp_s:
            if bearing.beacon_id not in conflicting:
                conflicting.append(bearing.beacon_id)
            dropped.append(bearing)
            continue
        if median_s is None:
            finite = [b.stamp_s for b in bearings if math.isfinite(b.stamp_s)]
            median_s = statistics.median(finite) if finite else 0.0
        if abs(bearing.stamp_s - median_s) < abs(previous.stamp_s - median_s):
            dropped.append(previous)
            kept[bearing.beacon_id] = bearing
        else:
            dropped.append(bearing)
    return Sightings(list(kept.values()), dropped, conflicting)


def odometry_problem(stamp_s: float, pose: Sequence[float], twist: Sequence[float] | None = None) -> str:
    """Why an odometry sample (stamp s, pose (x, y, theta) in the odom frame, optional twist) is refused:
    a non-finite value; ''."""
    if not (math.isfinite(stamp_s) and all(math.isfinite(float(v)) for v in pose)):
        return bounded(f"odometry at {float(stamp_s):.3f} s: non-finite stamp or pose {tuple(pose)}")
    if twist is not None and not all(math.isfinite(float(v)) for v in twist):
        return bounded(f"odometry at {stamp_s:.3f} s: non-finite twist {tuple(twist)}")
    return ""


def clearly_conditioned(matrix: np.ndarray, ratio: float = 0.0) -> bool:
    """Whether the symmetric matrix of a normalised 3x3's lower triangle has lambda_min > 2 ratio lambda_max
    + 1e-12 for sure (definite by Sylvester's criterion, lambda_min >= det/(trace/2)^2, lambda_max <= trace):
    eigvalsh (backward stable, errors ~1e-15 here) then decides `lambda_min > ratio lambda_max` alike."""
    (a, _, _), (b, c, _), (d, e, f) = matrix.tolist()
    trace, det = a + c + f, a * (c * f - e * e) - b * (b * f - e * d) + d * (b * e - c * d)
    definite = a > 0.0 and a * c - b * b > 0.0 and det > 0.0
    return definite and 4.0 * det / (trace * trace) > 2.0 * ratio * trace + 1e-12


def covariance_problem(covariance: Any) -> str:
    """Why a covariance cannot be published (shape, non-finite, asymmetric, not positive definite), or ''."""
    matrix = np.asarray(covariance, dtype=float)
    if matrix.shape != (3, 3):
        return f"covariance of shape {matrix.shape}, expected (3, 3)"
    if not np.all(np.isfinite(matrix)):
        return "covariance has a non-finite entry"
    scale = float(np.max(np.abs(matrix)))
    if scale == 0.0:
        return "covariance is all zero"
    normalised = matrix / scale  # entries in [-1, 1]: no overflow whatever the magnitude
    if float(np.max(np.abs(normalised - normalised.T))) > SYMMETRY_TOLERANCE:
        return "covariance is not symmetric"
    symmetric = 0.5 * (normalised + normalised.T)
    if clearly_conditioned(symmetric, MAX_CONDITION_RECIPROCAL):
        return ""
    eigenvalues = np.linalg.eigvalsh(symmetric)
    if not eigenvalues[0] > MAX_CONDITION_RECIPROCAL * eigenvalues[-1]:
        return f"covariance is not positive definite (eigenvalues {eigenvalues.tolist()} x {scale:.3g})"
    return ""


def planar_estimate_problem(pose: Sequence[float], covariance: Any) -> str:
    """Why a planar pose (x, y, theta) and its 3x3 covariance must not leave a node, or ''."""
    if len(pose) != 3 or not all(math.isfinite(float(v)) for v in pose):
        return bounded(f"pose {tuple(pose)} is not three finite numbers")
    problem = covariance_problem(covariance)
    return f"pose ({pose[0]:.3f}, {pose[1]:.3f}, {pose[2]:.3f}): {problem}" if problem else ""
