"""The turret offset (thesis section 7.3.3: the turret's centre in base_link) as EKF states.

The configured offset (`turret_offset_m`, or a calibration file's) is a measurement by hand; the states
are its correction (dx, dy) (m), zero-mean with `prior_sigma_m`. A moving robot's bearings and odometry
observe it strongly (docs/self_calibration.md: to 0.1 mm of a 1 cm prior in 60 s); a still robot cannot
(a turret offset is then a position offset).
"""

from collections.abc import Mapping
from dataclasses import dataclass
from math import cos, sin
from typing import Any

import numpy as np

from beams_common.config.parameters import ParameterSpec, ParameterTable
from beams_ekf.state_blocks import BearingPart, Sighting, StateBlock

TURRET_OFFSET_SPECS = ParameterTable(
    "ekf_node",
    (
        ParameterSpec(
            "turret_offset_sigma_m",
            0.0,
            "Prior standard deviation (m) of the configured turret offset (thesis 7.3.3); > 0 estimates its "
            "correction while the robot drives (self-calibration, written by ~/save_calibration); 0: the "
            "offset is taken as exact.",
            minimum=0.0,
            maximum=0.1,
        ),
    ),
)


@dataclass(frozen=True)
class TurretOffsetStates(StateBlock):
    """The correction (dx, dy) (m) of the configured turret offset, in base_link."""

    prior_sigma_m: float = 0.01
    size = 2

    @property
    def prior_covariance(self) -> np.ndarray:
        return self.prior_sigma_m**2 * np.eye(self.size)

    def shift(self, mean: np.ndarray, sighting: Sighting) -> None:
        """The correction, in base_link, turned into the lever's frame (the robot then)."""
        lx, ly, lth = sighting.lever
        lc, ls = cos(lth), sin(lth)
        dx, dy = float(mean[0]), float(mean[1])
        sighting.lever = (lx + lc * dx - ls * dy, ly + ls * dx + lc * dy, lth)

    def bearing(self, mean: np.ndarray, sighting: Sighting, memory: Any) -> BearingPart:
        """dh/d(lever x, y) is dh/d(turret) turned by the heading, then by the lever's angle."""
        d_pose, theta = sighting.d_pose, sighting.pose[2]
        c, s = cos(theta), sin(theta)
        d_lever = np.array([d_pose[0] * c + d_pose[1] * s, -d_pose[0] * s + d_pose[1] * c])
        lc, ls = cos(sighting.lever[2]), sin(sighting.lever[2])
        return BearingPart(d_lever @ np.array([[lc, -ls], [ls, lc]]))


def turret_offset_states_of(values: Mapping[str, Any]) -> TurretOffsetStates | None:
    """The states of ekf_node's validated parameter values; None when turret_offset_sigma_m is 0."""
    sigma = float(values["turret_offset_sigma_m"])
    return TurretOffsetStates(sigma) if sigma > 0.0 else None
