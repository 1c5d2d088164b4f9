"""Angle helpers shared by the BeAMS packages (REP-103: radians, counter-clockwise positive)."""

import math

import numpy as np
from numpy.typing import ArrayLike

_TWO_PI = 2.0 * math.pi


def wrap_to_pi(angle: ArrayLike) -> np.ndarray | float:
    """Wrap angles to (-pi, pi]; a Python scalar gives a float (without numpy: hot paths call this)."""
    if isinstance(angle, float | int):
        return math.pi - (math.pi - angle) % _TWO_PI
    wrapped = np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), _TWO_PI)
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped
