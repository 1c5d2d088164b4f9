"""ToTal: three object triangulation by the power centre of three circles (thesis ch. 6, Algorithm 6.1). The
scalar (`triangulate`) and vectorised (`triangulate_many`) forms share helpers of `+ - * /` only, so they
give the same numbers."""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from beams_common.geometry.angles import wrap_to_pi

#: Bound on the cotangents (thesis 6.3.5): an angle of about 1e-8 rad, far below any sensor's precision,
#: so the pseudo-singular bearings phi_ij = 0 or pi need no special case.
COT_BOUND = 1e8
#: |D| (m^2) at or below which the robot is taken to be on the critical circumference (no fix).
MIN_ABS_D_M2 = 1e-12
#: The finite 1/|D| reported with a no-fix (never Inf, so that messages and logs stay printable).
NO_FIX_INVERSE_ABS_D = sys.float_info.max

TWO_PI = 2.0 * math.pi
#: Rows per block in the vectorised form (about 128 kB per temporary array).
BLOCK_SIZE = 16384

REASON_CRITICAL = "robot on the critical circumference (D = 0): beacons and robot concyclic or collinear"
REASON_NON_FINITE = "non-finite bearing or beacon coordinate"


@dataclass(frozen=True)
class ToTalFix:
    """One ToTal result; when `ok` is False, x, y and heading are 0.0 and `reason` says why."""

    x: float
    y: float
    heading: float
    inverse_abs_d: float
    ok: bool
    reason: str


@dataclass(frozen=True)
class ToTalBatch:
    """Vectorised ToTal results, arrays of shape (N,); rows with ok False hold 0.0 (and the no-fix 1/|D|)."""

    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    inverse_abs_d: np.ndarray
    ok: np.ndarray

    def __len__(self) -> int:
        return len(self.x)

    def fix(self, index: int) -> ToTalFix:
        """Row `index` as a ToTalFix."""
        ok = bool(self.ok[index])
        return ToTalFix(
            float(self.x[index]),
            float(self.y[index]),
            float(self.heading[index]),
            float(self.inverse_abs_d[index]),
            ok,
            "" if ok else REASON_CRITICAL,
        )


def _bounded_ratio_scalar(numerator: float, denominator: float) -> float:
    """numerator / denominator clipped to +-COT_BOUND; a zero divisor follows numpy (signed infinity)."""
    if denominator == 0.0:
        return math.copysign(COT_BOUND, numerator) * math.copysign(1.0, denominator)
    ratio = numerator / denominator
    return ratio if -COT_BOUND <= ratio <= COT_BOUND else math.copysign(COT_BOUND, ratio)


def _bounded_ratio_array(numerator, denominator: np.ndarray) -> np.ndarray:
    """Vectorised `_bounded_ratio_scalar`."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.divide(numerator, denominator)
    return np.clip(ratio, -COT_BOUND, COT_BOUND, out=ratio)


def _wrap(angle, rint):
    """Wrap to [-pi, pi] with a rounding (cheaper than a modulo on arrays)."""
    return angle - TWO_PI * rint(angle / TWO_PI)


def _cotangents(tan12, tan23, bounded_ratio):
    """T12, T23 (Algorithm 6.1 step 2, bounded) and T31 by eq. 6.23."""
    t12 = bounded_ratio(1.0, tan12)
    t23 = bounded_ratio(1.0, tan23)
    # eq. 6.23; phi_31 = 0 or pi makes T12 + T23 vanish and T31 hit the bound like the others.
    return t12, t23, bounded_ratio(1.0 - t12 * t23, t12 + t23)


def _power_centre(x1p, y1p, x3p, y3p, t12, t23, t31):
    """Steps 3-6 of Algorithm 6.1 relative to B2: (numerator of x_R - x2, numerator of y_R - y2, D), from
    the differences of the modified centres (eq. 6.20-6.21), eq. 6.16-6.18 up to footnote 4's factor 2."""
    dx_12_23 = (x1p - x3p) + t12 * y1p + t23 * y3p  # x'_12 - x'_23
    dy_12_23 = (y1p - y3p) - t12 * x1p - t23 * x3p  # y'_12 - y'_23
    dx_23_31 = -x1p - t23 * y3p - t31 * (y3p - y1p)  # x'_23 - x'_31
    dy_23_31 = -y1p + t23 * x3p + t31 * (x3p - x1p)  # y'_23 - y'_31
    k31 = (x1p * x3p + y1p * y3p) + t31 * (x1p * y3p - x3p * y1p)  # eq. 6.22 for k'_31
    d = dx_12_23 * dy_23_31 - dy_12_23 * dx_23_31
    return k31 * dy_12_23, -k31 * dx_12_23, d


def _combined_heading(beacon_headings, rint):
    """Circular mean of the three headings of eq. 6.24, wrapped to [-pi, pi]: they agree but for rounding,
    which the mean halves near the critical circle."""
    h1, h2, h3 = beacon_headings
    return _wrap(h1 + (_wrap(h2 - h1, rint) + _wrap(h3 - h1, rint)) / 3.0, rint)


def _offset_in_map(cos_h, sin_h, offset_x, offset_y):
    """The turret offset (base_link) rotated into the map frame."""
    return cos_h * offset_x - sin_h * offset_y, sin_h * offset_x + cos_h * offset_y


def triangulate(
    beacons_xy: ArrayLike,
    bearings_rad: ArrayLike,
    turret_offset_m: Sequence[float] = (0.0, 0.0),
) -> ToTalFix:
    """ToTal (Algorithm 6.1) for one triplet (any order; bearings CCW in the sensor frame), heading from all
    three beacons (eq. 6.24); x, y the robot centre given `turret_offset_m`, else the turret centre;
    inverse_abs_d is 1/|D| (m^-2), the reliability measure (thesis 6.3.5)."""
    rows = beacons_xy.tolist() if isinstance(beacons_xy, np.ndarray) else beacons_xy
    angles = bearings_rad.tolist() if isinstance(bearings_rad, np.ndarray) else bearings_rad
    # Plain unpacking, no float() calls: ints and floats both work and this path must stay fast.
    (x1, y1), (x2, y2), (x3, y3) = rows
    phi1, phi2, phi3 = angles
    if not all(map(math.isfinite, (x1, y1, x2, y2, x3, y3, phi1, phi2, phi3))):
        return _no_fix(REASON_NON_FINITE)
    t12, t23, t31 = _cotangents(math.tan(phi2 - phi1), math.tan(phi3 - phi2), _bounded_ratio_scalar)
    num_x, num_y, d = _power_centre(x1 - x2, y1 - y2, x3 - x2, y3 - y2, t12, t23, t31)
    # Two infinite cotangents: robot on the line of collinear beacons, where bounding gives no limit.
    saturated = (abs(t12) >= COT_BOUND) + (abs(t23) >= COT_BOUND) + (abs(t31) >= COT_BOUND)
    if not abs(d) > MIN_ABS_D_M2 or saturated >= 2:
        return _no_fix(REASON_CRITICAL)
    xr = x2 + num_x / d
    yr = y2 + num_y / d
    if not (math.isfinite(xr) and math.isfinite(yr)):
        return _no_fix(REASON_CRITICAL)
    heading = _combined_heading(
        (
            math.atan2(y1 - yr, x1 - xr) - phi1,
            math.atan2(y2 - yr, x2 - xr) - phi2,
            math.atan2(y3 - yr, x3 - xr) - phi3,
        ),
        round,
    )
    offset_x, offset_y = turret_offset_m
    if offset_x or offset_y:
        ox, oy = _offset_in_map(math.cos(heading), math.sin(heading), offset_x, offset_y)
        xr, yr = xr - ox, yr - oy
    return ToTalFix(xr, yr, heading, 1.0 / abs(d), True, "")


def _no_fix(reason: str) -> ToTalFix:
    return ToTalFix(0.0, 0.0, 0.0, NO_FIX_INVERSE_ABS_D, False, reason)


def triangulate_many(
    beacons_xy: ArrayLike,
    bearings_rad: ArrayLike,
    turret_offset_m: Sequence[float] = (0.0, 0.0),
) -> ToTalBatch:
    """Vectorised `triangulate`: bearings_rad (N, 3); beacons_xy (3, 2) shared or (N, 3, 2) per row; a
    non-finite input gives ok False like D = 0."""
    bearings = np.asarray(bearings_rad, dtype=float)
    beacons = np.asarray(beacons_xy, dtype=float)
    if bearings.ndim != 2 or bearings.shape[1] != 3 or beacons.shape not in ((3, 2), (len(bearings), 3, 2)):
        raise ValueError(
            f"expected bearings (N, 3) and beacons (3, 2) or (N, 3, 2), got "
            f"{bearings.shape} and {beacons.shape}"
        )
    offset = tuple(float(v) for v in turret_offset_m)
    outputs = [np.empty(len(bearings)) for _ in range(4)] + [np.empty(len(bearings), dtype=bool)]
    # Blocks that fit in the CPU cache: numpy's temporaries then cost about a third of full-size ones.
    for start in range(0, len(bearings), BLOCK_SIZE):
        rows = slice(start, start + BLOCK_SIZE)
        block_beacons = beacons if beacons.ndim == 2 else beacons[rows]
        results = _triangulate_block(block_beacons, bearings[rows], offset)
        for output, values in zip(outputs, results, strict=True):
            output[rows] = values
    return ToTalBatch(*outputs)


def _triangulate_block(beacons: np.ndarray, bearings: np.ndarray, offset: tuple[float, float]) -> tuple:
    """Algorithm 6.1 on one block of rows: (x, y, heading, inverse_abs_d, ok)."""
    x1, y1, x2, y2, x3, y3 = (np.ascontiguousarray(beacons[..., i, j]) for i in range(3) for j in range(2))
    phi1, phi2, phi3 = np.ascontiguousarray(bearings.T)
    with np.errstate(divide="ignore", invalid="ignore"):
        t12, t23, t31 = _cotangents(np.tan(phi2 - phi1), np.tan(phi3 - phi2), _bounded_ratio_array)
        num_x, num_y, d = _power_centre(x1 - x2, y1 - y2, x3 - x2, y3 - y2, t12, t23, t31)
        saturated = (
            (np.abs(t12) >= COT_BOUND).view(np.uint8)
            + (np.abs(t23) >= COT_BOUND).view(np.uint8)
            + (np.abs(t31) >= COT_BOUND).view(np.uint8)
        )
        ok = (np.abs(d) > MIN_ABS_D_M2) & (saturated < 2)
        xr = x2 + num_x / d
        yr = y2 + num_y / d
        heading = _combined_heading(
            (
                np.arctan2(y1 - yr, x1 - xr) - phi1,
                np.arctan2(y2 - yr, x2 - xr) - phi2,
                np.arctan2(y3 - yr, x3 - xr) - phi3,
            ),
            np.rint,
        )
        inverse_abs_d = 1.0 / np.abs(d)
    ok &= np.isfinite(xr) & np.isfinite(yr) & np.isfinite(heading)
    if offset != (0.0, 0.0):
        ox, oy = _offset_in_map(np.cos(heading), np.sin(heading), *offset)
        xr, yr = xr - ox, yr - oy
    failed = ~ok
    if failed.any():  # masked stores only when needed: np.where on every block costs 20 ns per pose
        xr[failed], yr[failed], heading[failed], inverse_abs_d[failed] = 0.0, 0.0, 0.0, NO_FIX_INVERSE_ABS_D
    return xr, yr, heading, inverse_abs_d, ok


def expected_bearings(
    beacons_xy: ArrayLike, pose: Sequence[float], turret_offset_m: Sequence[float] = (0.0, 0.0)
) -> np.ndarray:
    """Noise-free bearings (rad, wrapped to (-pi, pi]) of the beacons, (3, 2) or (k, 2), seen from a robot
    pose (x, y, theta), the inverse of `triangulate`; a pose of arrays (N,) gives (N, k)."""
    beacons = np.asarray(beacons_xy, dtype=float)
    x, y, theta = (np.asarray(p, dtype=float)[..., None] for p in pose)
    offset_x, offset_y = (float(v) for v in turret_offset_m)
    ox, oy = _offset_in_map(np.cos(theta), np.sin(theta), offset_x, offset_y)
    # A scalar pose gives shape (1,) here, so the result is (k,); arrays (N,) give (N, k).
    return wrap_to_pi(np.arctan2(beacons[:, 1] - (y + oy), beacons[:, 0] - (x + ox)) - theta)
