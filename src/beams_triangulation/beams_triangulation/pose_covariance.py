"""Pose covariance of a ToTal fix: first-order propagation of the three bearing variances (thesis B.3), the
derivatives exact by implicit differentiation of alpha_i(x, y) - theta - phi_i = 0: d(x, y, theta) =
A^-1 d(phi), rows A_i = (d alpha_i/dx, d alpha_i/dy, -1), singular where D vanishes; + - * / only."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike


def _bearing_gradient(beacon_x, beacon_y, x, y):
    """(d alpha/dx, d alpha/dy) of the direction alpha = atan2(beacon_y - y, beacon_x - x)."""
    dx = beacon_x - x
    dy = beacon_y - y
    r2 = dx * dx + dy * dy
    return dy / r2, -dx / r2


def _jacobian_rows(beacons, x, y, offset_map):
    """Rows (J_x, J_y, J_theta) of the pose w.r.t. (phi1, phi2, phi3) at the turret centre (x, y), moved to
    the robot centre p_R = p_T - R(theta) o by offset_map (the turret offset in the map frame)."""
    (b1x, b1y), (b2x, b2y), (b3x, b3y) = beacons
    a1x, a1y = _bearing_gradient(b1x, b1y, x, y)
    a2x, a2y = _bearing_gradient(b2x, b2y, x, y)
    a3x, a3y = _bearing_gradient(b3x, b3y, x, y)
    m11, m12, m21, m22 = a1x - a2x, a1y - a2y, a3x - a2x, a3y - a2y
    det = m11 * m22 - m12 * m21
    # Inverse of [[m11, m12], [m21, m22]] applied to (dphi1 - dphi2, dphi3 - dphi2).
    jx1, jx2, jx3 = m22 / det, (m12 - m22) / det, -m12 / det
    jy1, jy2, jy3 = -m21 / det, (m21 - m11) / det, m11 / det
    # Second bearing equation: dtheta = a2 . dp - dphi2.
    jt = (a2x * jx1 + a2y * jy1, a2x * jx2 + a2y * jy2 - 1.0, a2x * jx3 + a2y * jy3)
    ox, oy = offset_map
    # d(R(theta) o)/dtheta = (-oy_map, ox_map): the robot centre swings around the turret.
    jx = (jx1 + oy * jt[0], jx2 + oy * jt[1], jx3 + oy * jt[2])
    jy = (jy1 - ox * jt[0], jy2 - ox * jt[1], jy3 - ox * jt[2])
    return jx, jy, jt


def _covariance_entries(rows, variances):
    """The six distinct entries (xx, xy, xt, yy, yt, tt) of J diag(variances) J^T (written out: hot path)."""
    (x1, x2, x3), (y1, y2, y3), (t1, t2, t3) = rows
    v1, v2, v3 = variances
    xv1, xv2, xv3 = x1 * v1, x2 * v2, x3 * v3
    yv1, yv2, yv3 = y1 * v1, y2 * v2, y3 * v3
    return (
        xv1 * x1 + xv2 * x2 + xv3 * x3,
        xv1 * y1 + xv2 * y2 + xv3 * y3,
        xv1 * t1 + xv2 * t2 + xv3 * t3,
        yv1 * y1 + yv2 * y2 + yv3 * y3,
        yv1 * t1 + yv2 * t2 + yv3 * t3,
        t1 * t1 * v1 + t2 * t2 * v2 + t3 * t3 * v3,
    )


def _turret_position(x, y, cos_h, sin_h, offset):
    """Turret centre and the offset in the map frame, from the robot pose."""
    ox = cos_h * offset[0] - sin_h * offset[1]
    oy = sin_h * offset[0] + cos_h * offset[1]
    return x + ox, y + oy, (ox, oy)


def pose_covariance(
    beacons_xy: ArrayLike,
    pose: Sequence[float],
    variances_rad2: Sequence[float],
    turret_offset_m: Sequence[float] = (0.0, 0.0),
) -> np.ndarray:
    """3x3 covariance of a fix (`total.triangulate`'s, same turret offset) from the bearings' variances
    (rad^2); Inf-free only off the critical circle (`gating`)."""
    # Plain Python floats: arithmetic on numpy scalars would double the cost of this hot path.
    rows = beacons_xy.tolist() if isinstance(beacons_xy, np.ndarray) else beacons_xy
    variances = [float(v) for v in variances_rad2]
    x, y, heading = pose
    if turret_offset_m[0] or turret_offset_m[1]:
        tx, ty, offset_map = _turret_position(x, y, math.cos(heading), math.sin(heading), turret_offset_m)
    else:  # the common case, without the trigonometry
        tx, ty, offset_map = x, y, (0.0, 0.0)
    try:
        xx, xy, xt, yy, yt, tt = _covariance_entries(_jacobian_rows(rows, tx, ty, offset_map), variances)
    except ZeroDivisionError:  # robot at a beacon or exactly on the critical circle
        return np.full((3, 3), math.inf)
    # fromiter of a flat tuple: half the cost of np.array on nested lists, on a path timed in microseconds.
    return np.fromiter((xx, xy, xt, xy, yy, yt, xt, yt, tt), float, 9).reshape(3, 3)


def pose_covariance_many(
    beacons_xy: ArrayLike,
    poses: Sequence[np.ndarray],
    variances_rad2: ArrayLike,
    turret_offset_m: Sequence[float] = (0.0, 0.0),
) -> np.ndarray:
    """Vectorised `pose_covariance`: poses (x, y, heading) of shape (N,), beacons_xy (3, 2) or (N, 3, 2),
    variances_rad2 (3,) or (N, 3); result (N, 3, 3)."""
    beacons = np.asarray(beacons_xy, dtype=float)
    x, y, heading = (np.asarray(p, dtype=float) for p in poses)
    variances = np.broadcast_to(np.asarray(variances_rad2, dtype=float), (*x.shape, 3))
    tx, ty, offset_map = _turret_position(x, y, np.cos(heading), np.sin(heading), turret_offset_m)
    beacon_columns = [(beacons[..., i, 0], beacons[..., i, 1]) for i in range(3)]
    with np.errstate(divide="ignore", invalid="ignore"):
        rows = _jacobian_rows(beacon_columns, tx, ty, offset_map)
        xx, xy, xt, yy, yt, tt = _covariance_entries(rows, np.moveaxis(variances, -1, 0))
    return np.stack([np.stack([xx, xy, xt], -1), np.stack([xy, yy, yt], -1), np.stack([xt, yt, tt], -1)], -2)


def position_std_m(covariance: np.ndarray) -> np.ndarray | float:
    """sqrt(var x + var y): the RMS position error the covariance predicts (m); works on (..., 3, 3)."""
    value = np.sqrt(covariance[..., 0, 0] + covariance[..., 1, 1])
    return float(value) if np.ndim(value) == 0 else value


def distance_error_std_m(covariance: np.ndarray) -> np.ndarray | float:
    """Predicted standard deviation of the distance error |p - p_true| (eq. 6.25), the thesis's figure.

    For a zero-mean Gaussian position error with eigenvalues l1 >= l2, E|e| = sqrt(2 l1 / pi) E(1 - l2/l1)
    (E the complete elliptic integral of the second kind), and var|e| = l1 + l2 - (E|e|)^2.
    """
    from scipy.special import ellipe  # only the error analysis needs it: keep node start-up light

    block = np.asarray(covariance)[..., :2, :2]
    trace = block[..., 0, 0] + block[..., 1, 1]
    gap = np.sqrt((block[..., 0, 0] - block[..., 1, 1]) ** 2 + 4.0 * block[..., 0, 1] ** 2)
    largest = 0.5 * (trace + gap)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(largest > 0.0, np.clip(1.0 - (trace - largest) / largest, 0.0, 1.0), 0.0)
    mean = np.sqrt(2.0 * largest / np.pi) * ellipe(ratio)
    value = np.sqrt(np.maximum(trace - mean * mean, 0.0))
    return float(value) if np.ndim(value) == 0 else value
