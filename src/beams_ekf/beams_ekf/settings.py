"""What the EKF takes from ekf_node's parameters: the Localiser's timing and re-initialisation settings
and the filter's (process noise, state blocks, gate, initial pose sigma).

Each setting's default, range and description is its ParameterSpec's (here, or in its state block's
module); `beams_ekf.parameters` gathers the specs in ekf_node's table and builds the settings from the
validated values (`filter_settings`).
"""

from dataclasses import dataclass, field

import numpy as np

from beams_common.config.parameters import ParameterSpec, ParameterTable
from beams_common.intake.plausibility import MAX_POSE_SIGMA_M, MotionLimits
from beams_ekf.beacon_states import BEACON_STATE_SPECS, BeaconStates, beacon_states_of
from beams_ekf.bearing_ekf import BEARING_EKF_SPECS, ProcessNoise, process_noise_of
from beams_ekf.odometry_errors import ODOMETRY_ERROR_SPECS, OdometryErrorStates, odometry_error_states_of
from beams_ekf.power_bias_states import POWER_BIAS_SPECS, PowerBiasStates, power_bias_states_of
from beams_ekf.state_blocks import block_field, registered_blocks
from beams_ekf.turret_offset_states import TURRET_OFFSET_SPECS, TurretOffsetStates, turret_offset_states_of

# ranges shared by several parameters
_UP_TO_1E3, _ONE_TO_1000, _ZERO_TO_1000 = (
    {"minimum": 0.0, "maximum": 1.0e3},
    {"minimum": 1, "maximum": 1000},
    {"minimum": 0, "maximum": 1000},
)
# the settings' own parameters (LocaliserConfig's are its fields of the same names), beside the filter's
# (bearing_ekf.BEARING_EKF_SPECS) and the blocks'
SETTINGS_SPECS = ParameterTable(
    "ekf_node",
    (
        ParameterSpec(
            "odometry_history_s", 1.0, "Odometry kept to apply late bearings (s).", minimum=0.1, maximum=10.0
        ),
        ParameterSpec(
            "max_odometry_extrapolation_s",
            0.05,
            "Bearings up to this far (s) past the newest odometry are applied at once; "
            "later ones wait for odometry.",
            minimum=0.0,
            maximum=1.0,
        ),
        ParameterSpec(
            "odometry_gap_s",
            0.25,
            "Odometry silence (s) treated as a gap (covariance grows).",
            minimum=0.001,
            maximum=10.0,
        ),
        ParameterSpec(
            "gap_position_variance_m2_per_s",
            1.0e-3,
            "Position variance added per second of gap.",
            **_UP_TO_1E3,
        ),
        ParameterSpec(
            "gap_heading_variance_rad2_per_s",
            1.0e-3,
            "Heading variance added per second of gap.",
            **_UP_TO_1E3,
        ),
        ParameterSpec(
            "kidnap_gated_bearings",
            6,
            "Gated bearings, among the last kidnap_window_bearings, that make the filter "
            "lost (a ToTal pose elsewhere then re-initialises it).",
            **_ONE_TO_1000,
        ),
        ParameterSpec(
            "kidnap_window_bearings",
            12,
            "Number of recent bearings judged for kidnap_gated_bearings.",
            **_ONE_TO_1000,
        ),
        ParameterSpec(
            "kidnap_probability",
            0.999,
            "Chi-square (3 dof) probability beyond which a ToTal pose is inconsistent with "
            "the estimate (their covariances summed), i.e. 'elsewhere'.",
            minimum=0.5,
            maximum=0.999999,
        ),
        ParameterSpec(
            "kidnap_distance_m",
            0.25,
            "Distance (m) from the estimate that always makes a ToTal pose 'elsewhere'.",
            **_UP_TO_1E3,
        ),
        ParameterSpec(
            "kidnap_heading_rad",
            0.35,
            "Heading difference (rad) that always makes a ToTal pose 'elsewhere'.",
            **_UP_TO_1E3,
        ),
        ParameterSpec(
            "time_jump_confirmations",
            2,
            "Consecutive odometry messages stamped in the past that make a time jump "
            "(a bag loop: the filter resets); fewer are stray messages, dropped.",
            minimum=1,
            maximum=100,
        ),
        ParameterSpec(
            "lost_nis_window_bearings",
            30,
            "Bearings whose NIS (normalised innovation squared) the lost test sums; 0 switches the test off.",
            **_ZERO_TO_1000,
        ),
        ParameterSpec(
            "lost_nis_probability",
            1.0 - 1.0e-6,
            "Chi-square probability beyond which the summed NIS makes the filter lost "
            "(the next ToTal pose re-initialises it).",
            minimum=0.5,
            maximum=1.0 - 1e-12,
        ),
        # 9: three revolutions of the three beacons. A pose 0.5 m off cannot have a revolution's three
        # bearings inside its gate (they fix a pose on their own), and 6 gated of the last 12 re-initialise
        # from ToTal; three revolutions leave three updates of each beacon to pull a slightly wrong pose
        # in. Counted in bearings, not in calls: a revolution can reach the filter in two parts.
        ParameterSpec(
            "confirming_bearings",
            9,
            "Accepted bearings in a row (from two beacons at least; 9: three revolutions of three beacons) "
            "that confirm the estimate after a break of its continuity (an operator's pose, an odometry "
            "jump or silence, a time jump, a re-initialisation after a kidnap or a lost test): the status "
            "is degraded until then; 0 switches the check off.",
            **_ZERO_TO_1000,
        ),
        # 2: one gated bearing of a beacon happens once a minute at the 0.999 gate; two in a row, while
        # another beacon's bearings pass between them, is a beacon that disagrees (moved, reflected, biased)
        ParameterSpec(
            "exclusion_gated_bearings",
            2,
            "Gated bearings of one beacon in a row, another beacon's accepted between them, that exclude "
            "that beacon (its bearings judged, not applied; the status degraded, ToTal's poses, which use "
            "it, no longer re-initialise); 0 switches the exclusion off.",
            **_ZERO_TO_1000,
        ),
        # 30: three seconds of one beacon's bearings, enough for the mean test to see a bias of a third of
        # the innovation's sigma
        ParameterSpec(
            "readmission_bearings",
            30,
            "Bearings of an excluded beacon in a row within the gate, their normalised residuals of zero "
            "mean (3 sigma), that readmit it.",
            **_ONE_TO_1000,
        ),
        ParameterSpec(
            "use_total_pose",
            True,
            "Initialise (and re-initialise after a kidnapping) from ToTal's accepted poses on beams/pose.",
            runtime=True,
        ),
        ParameterSpec(
            "default_pose_sigma",
            [0.05, 0.05, 0.1],
            "Standard deviations (m, m, rad) of a pose without a usable covariance (at most the table's "
            "size: a larger prior wedged the filter).",
            minimum=1e-6,
            maximum=MAX_POSE_SIGMA_M,
            length=3,
            runtime=True,
        ),
    ),
)
_DEFAULT = SETTINGS_SPECS.default


@dataclass(frozen=True)
class LocaliserConfig:
    """Timing and re-initialisation parameters (defaults suit 50 Hz odometry and a 10 Hz turret), each
    described by its spec (SETTINGS_SPECS) but the two commented."""

    odometry_history_s: float = _DEFAULT("odometry_history_s")
    max_odometry_extrapolation_s: float = _DEFAULT("max_odometry_extrapolation_s")
    odometry_gap_s: float = _DEFAULT("odometry_gap_s")
    gap_position_variance_m2_per_s: float = _DEFAULT("gap_position_variance_m2_per_s")
    gap_heading_variance_rad2_per_s: float = _DEFAULT("gap_heading_variance_rad2_per_s")
    # a gap never inflates more than this long (the table bounds how lost the robot can be)
    max_gap_inflation_s: float = 10.0
    kidnap_gated_bearings: int = _DEFAULT("kidnap_gated_bearings")
    kidnap_window_bearings: int = _DEFAULT("kidnap_window_bearings")
    kidnap_probability: float = _DEFAULT("kidnap_probability")
    kidnap_distance_m: float = _DEFAULT("kidnap_distance_m")
    kidnap_heading_rad: float = _DEFAULT("kidnap_heading_rad")
    # odometry stamps going back by more than this, in time_jump_confirmations consecutive messages,
    # reset the filter (a bag loop); smaller steps, and a single stray old message, are dropped
    time_jump_tolerance_s: float = 0.0
    time_jump_confirmations: int = _DEFAULT("time_jump_confirmations")
    lost_nis_window_bearings: int = _DEFAULT("lost_nis_window_bearings")
    lost_nis_probability: float = _DEFAULT("lost_nis_probability")
    confirming_bearings: int = _DEFAULT("confirming_bearings")
    exclusion_gated_bearings: int = _DEFAULT("exclusion_gated_bearings")
    readmission_bearings: int = _DEFAULT("readmission_bearings")

    def __post_init__(self) -> None:
        if self.kidnap_gated_bearings > self.kidnap_window_bearings:
            gated, window = self.kidnap_gated_bearings, self.kidnap_window_bearings
            raise ValueError(
                f"need kidnap_gated_bearings <= kidnap_window_bearings, got {gated} and {window}"
            )


@dataclass(frozen=True)
class FilterSettings:
    """What ekf_node takes from its parameters (besides the beacon geometry); the state blocks past the
    pose are the `block_field`s, in the state's order (registering a block is its line here).

    By default the filter estimates the odometry's systematic errors, so its process noise is the wheels'
    random noise alone (`ProcessNoise.wheel_noise`); without them it must also cover them as white noise.
    """

    process_noise: ProcessNoise = field(
        default_factory=lambda: process_noise_of(BEARING_EKF_SPECS.defaults())
    )
    odometry_errors: OdometryErrorStates | None = field(
        **block_field(ODOMETRY_ERROR_SPECS, odometry_error_states_of)
    )
    gate_probability: float = BEARING_EKF_SPECS.default("gate_probability")
    localiser: LocaliserConfig = field(default_factory=LocaliserConfig)
    use_total_pose: bool = _DEFAULT("use_total_pose")
    default_pose_sigma: tuple[float, float, float] = tuple(_DEFAULT("default_pose_sigma"))
    # the robot's maximum speed and yaw rate: an odometry increment beyond them is a jump
    motion_limits: MotionLimits = field(default_factory=MotionLimits)
    # the power bias of uncalibrated bearings (estimated or considered); None: white noise
    power_bias: PowerBiasStates | None = field(**block_field(POWER_BIAS_SPECS, power_bias_states_of))
    # the turret offset's correction (self-calibration); None: the configured offset is exact
    turret_offset: TurretOffsetStates | None = field(
        **block_field(TURRET_OFFSET_SPECS, turret_offset_states_of)
    )
    # some beacons' coordinate corrections (self-calibration); None: the map is exact
    beacon_states: BeaconStates | None = field(**block_field(BEACON_STATE_SPECS, beacon_states_of))

    @property
    def blocks(self) -> tuple:
        """The state blocks past the pose, in order (None: off)."""
        return tuple(getattr(self, name) for name, _, _ in registered_blocks(type(self)))

    @property
    def default_pose_covariance(self) -> np.ndarray:
        """The 3x3 covariance of default_pose_sigma."""
        return np.diag(np.square(self.default_pose_sigma))
