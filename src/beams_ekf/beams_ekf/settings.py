"""What the EKF takes from ekf_node's parameters: the Localiser's timing and re-initialisation settings
and the filter's (process noise, odometry error states, gate, initial pose sigma).

The defaults written here are the parameters' defaults: `beams_ekf.parameters` gives each parameter its
one ParameterSpec (name, range, description, runtime flag) with the default read from these classes, and
builds the settings from the validated values (`filter_settings`).
"""

from dataclasses import dataclass, field

import numpy as np

from beams_common.plausibility import MotionLimits
from beams_ekf.beacon_states import BeaconStates
from beams_ekf.bearing_ekf import ProcessNoise
from beams_ekf.consistency import CONFIRMING_BEARINGS
from beams_ekf.odometry_errors import OdometryErrorStates
from beams_ekf.power_bias_states import PowerBiasStates
from beams_ekf.turret_offset_states import TurretOffsetStates


@dataclass(frozen=True)
class LocaliserConfig:
    """Timing and re-initialisation parameters (defaults suit 50 Hz odometry and a 10 Hz turret)."""

    odometry_history_s: float = 1.0
    max_odometry_extrapolation_s: float = 0.05
    # an odometry step longer than this is a gap: the covariance grows with its duration
    odometry_gap_s: float = 0.25
    gap_position_variance_m2_per_s: float = 1.0e-3
    gap_heading_variance_rad2_per_s: float = 1.0e-3
    # a gap never inflates more than this long (the table bounds how lost the robot can be)
    max_gap_inflation_s: float = 10.0
    # the filter is "lost" when at least kidnap_gated_bearings of the last kidnap_window_bearings new
    # bearings were gated out (a consistent filter gates 1 - gate_probability of them); a lost filter
    # takes ToTal's fix when the fix is elsewhere: inconsistent with the estimate (chi-square, 3 dof,
    # at kidnap_probability, the two covariances summed) or farther than the distance/heading below
    kidnap_gated_bearings: int = 6
    kidnap_window_bearings: int = 12
    kidnap_probability: float = 0.999
    kidnap_distance_m: float = 0.25
    kidnap_heading_rad: float = 0.35
    # odometry stamps going back by more than this, in time_jump_confirmations consecutive messages,
    # reset the filter (a bag loop); smaller steps, and a single stray old message, are dropped
    time_jump_tolerance_s: float = 0.0
    time_jump_confirmations: int = 2
    # lost detection (NisMonitor): the NIS of the last lost_nis_window_bearings new bearings, summed,
    # beyond the chi-square quantile at lost_nis_probability (0: the monitor is off)
    lost_nis_window_bearings: int = 30
    lost_nis_probability: float = 1.0 - 1.0e-6
    # after a break of the estimate's continuity (an operator's pose, an odometry jump or silence, a time
    # jump, a re-initialisation after a kidnap or a lost test), the accepted bearings in a row that
    # confirm it (`consistency.PoseConfirmation`; 0: the check is off)
    confirming_bearings: int = CONFIRMING_BEARINGS

    def __post_init__(self) -> None:
        if self.lost_nis_window_bearings < 0 or not 0.0 < self.lost_nis_probability < 1.0:
            raise ValueError(
                f"need lost_nis_window_bearings >= 0 and lost_nis_probability in (0, 1), got "
                f"{self.lost_nis_window_bearings} and {self.lost_nis_probability}"
            )
        if not (
            self.odometry_history_s > 0.0
            and self.max_odometry_extrapolation_s >= 0.0
            and self.odometry_gap_s > 0.0
        ):
            raise ValueError(
                "odometry_history_s and odometry_gap_s must be > 0, max_odometry_extrapolation_s >= 0"
            )
        if not 1 <= self.kidnap_gated_bearings <= self.kidnap_window_bearings:
            raise ValueError(
                f"need 1 <= kidnap_gated_bearings <= kidnap_window_bearings, got "
                f"{self.kidnap_gated_bearings} and {self.kidnap_window_bearings}"
            )
        if self.confirming_bearings < 0:
            raise ValueError(f"confirming_bearings must be >= 0, got {self.confirming_bearings}")
        if self.time_jump_confirmations < 1:
            raise ValueError(f"time_jump_confirmations must be >= 1, got {self.time_jump_confirmations}")
        if not 0.0 < self.kidnap_probability < 1.0:
            raise ValueError(f"kidnap_probability must be in (0, 1), got {self.kidnap_probability}")


# The wheels' random error, variance per metre rolled, of the simulated robot (sim_world's OdometryDrift:
# noise 1 mm/sqrt(m) is 1.0e-6; the random part of the half-normal slip, 0.005^2 (1 - 2/pi) of a step's
# squared length, adds at most 0.09e-6 at the 1 cm steps of 0.5 m/s and 50 Hz), and its wheel base (m).
WHEEL_VARIANCE_M2_PER_M = 1.1e-6
WHEEL_BASE_M = 0.3


@dataclass(frozen=True)
class FilterSettings:
    """What ekf_node takes from its parameters (besides the beacon geometry).

    By default the filter estimates the odometry's systematic errors (`odometry_errors`), so its process
    noise is the wheels' random noise alone (`ProcessNoise.wheel_noise`); without those states the
    process noise must also cover the systematic errors as white noise (ProcessNoise's own defaults).
    """

    process_noise: ProcessNoise = field(
        default_factory=lambda: ProcessNoise.wheel_noise(WHEEL_VARIANCE_M2_PER_M, WHEEL_BASE_M)
    )
    odometry_errors: OdometryErrorStates | None = field(default_factory=OdometryErrorStates)
    # chi-square (1 dof) probability of the per-bearing gate
    gate_probability: float = 0.999
    localiser: LocaliserConfig = field(default_factory=LocaliserConfig)
    # initialise (and re-initialise after a kidnapping) from ToTal's accepted poses
    use_total_pose: bool = True
    # standard deviations (m, m, rad) of a pose without a usable covariance
    default_pose_sigma: tuple[float, float, float] = (0.05, 0.05, 0.1)
    # the robot's maximum speed and yaw rate: an odometry increment beyond them is a jump
    motion_limits: MotionLimits = field(default_factory=MotionLimits)
    # the power bias of uncalibrated bearings as states (estimated or considered); None: white noise
    power_bias: PowerBiasStates | None = field(default_factory=PowerBiasStates)
    # the turret offset's correction as states (self-calibration); None: the configured offset is exact
    turret_offset: TurretOffsetStates | None = None
    # some beacons' coordinate corrections as states (self-calibration); None: the map is exact
    beacon_states: BeaconStates | None = None

    def __post_init__(self) -> None:
        if len(self.default_pose_sigma) != 3:
            raise ValueError(
                f"default_pose_sigma needs 3 values (x, y, yaw), got {list(self.default_pose_sigma)}"
            )

    @property
    def default_pose_covariance(self) -> np.ndarray:
        """The 3x3 covariance of default_pose_sigma."""
        return np.diag(np.square(self.default_pose_sigma))
