"""The turret offset (thesis section 7.3.3: the turret's centre in base_link) as EKF states.

The configured offset (`turret_offset_m`, or a calibration file's) is a measurement by hand; the states
are its correction (dx, dy) (m), zero-mean with `prior_sigma_m`. A moving robot's bearings and odometry
observe it strongly (docs/self_calibration.md: to 0.1 mm of a 1 cm prior in 60 s); a still robot cannot
(a turret offset is then a position offset).
"""

from dataclasses import dataclass

import numpy as np

from beams_common.parameters import ParameterSpec

OFFSET_SIZE = 2


@dataclass(frozen=True)
class TurretOffsetStates:
    """The correction (dx, dy) (m) of the configured turret offset, in base_link."""

    prior_sigma_m: float = 0.01

    def __post_init__(self) -> None:
        if not (np.isfinite(self.prior_sigma_m) and self.prior_sigma_m > 0.0):
            raise ValueError(f"turret offset prior sigma must be > 0, got {self.prior_sigma_m}")

    @property
    def prior_mean(self) -> np.ndarray:
        return np.zeros(OFFSET_SIZE)

    @property
    def prior_covariance(self) -> np.ndarray:
        return self.prior_sigma_m**2 * np.eye(OFFSET_SIZE)


TURRET_OFFSET_PARAMETERS = (
    ParameterSpec(
        "turret_offset_sigma_m",
        0.0,
        "Prior standard deviation (m) of the configured turret offset (thesis 7.3.3); > 0 estimates its "
        "correction while the robot drives (self-calibration, written by ~/save_calibration); 0: the "
        "offset is taken as exact.",
        minimum=0.0,
        maximum=0.1,
    ),
)


def turret_offset_states_of(values: dict) -> TurretOffsetStates | None:
    """The states of ekf_node's parameter values; None when turret_offset_sigma_m is 0 (the default)."""
    sigma = float(values.get("turret_offset_sigma_m", TURRET_OFFSET_PARAMETERS[0].default))
    return TurretOffsetStates(sigma) if sigma > 0.0 else None
