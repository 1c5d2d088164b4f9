"""Angle helpers shared by the BeAMS packages (REP-103: radians, counter-clockwise positive)."""

import numpy as np
from numpy.typing import ArrayLike


def wrap_to_pi(angle: ArrayLike) -> np.ndarray | float:
    """Wrap angles to (-pi, pi]; scalars stay Python floats."""
    wrapped = np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), 2.0 * np.pi)
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped
