"""ekf_node's parameters: one spec each (name, default, range, description, runtime flag), for the node
and for the offline replay; `filter_settings` builds the settings from the validated values.

The defaults are the settings classes' (`beams_ekf.settings`), read here once.
"""

from collections.abc import Mapping
from typing import Any

from beams_common.geometry_parameters import GEOMETRY_CHECKS, GEOMETRY_SPECS
from beams_common.health import BEARING_RATE_SPECS, ODOMETRY_RATE_SPEC, rates_check
from beams_common.parameters import ROS_NODE_PARAMETERS, ParameterSpec, ParameterTable
from beams_common.plausibility import MAX_POSE_SIGMA_M, MOTION_SPECS, STAMP_SPECS, motion_limits_of
from beams_ekf.beacon_states import BEACON_STATE_PARAMETERS, beacon_states_of
from beams_ekf.bearing_ekf import ProcessNoise
from beams_ekf.odometry_errors import OdometryErrorStates
from beams_ekf.power_bias_states import POWER_BIAS_PARAMETERS, power_bias_states_of
from beams_ekf.settings import FilterSettings, LocaliserConfig
from beams_ekf.turret_offset_states import TURRET_OFFSET_PARAMETERS, turret_offset_states_of

_DEFAULTS = FilterSettings()
_NOISE = _DEFAULTS.process_noise
_ERRORS = _DEFAULTS.odometry_errors or OdometryErrorStates()
_TIMING = _DEFAULTS.localiser
# variances per unit travelled: from none to far more than any wheel
_MAX_VARIANCE_RATE = 1.0e3
# prior standard deviations of the odometry error states
_SIGMA_RANGE = {"minimum": 1e-6, "maximum": 1.0}

# changeable while the filter runs (runtime=True): they enter the next prediction and the next
# bearing's gate; the others shape the Localiser's history and monitors, built at start-up
FILTER_SPECS = (
    ParameterSpec(
        "translation_variance_m2_per_m",
        _NOISE.translation_m2_per_m,
        "Odometry position variance per metre travelled.",
        minimum=0.0,
        maximum=_MAX_VARIANCE_RATE,
        runtime=True,
    ),
    ParameterSpec(
        "rotation_variance_rad2_per_rad",
        _NOISE.rotation_rad2_per_rad,
        "Odometry heading variance per radian turned.",
        minimum=0.0,
        maximum=_MAX_VARIANCE_RATE,
        runtime=True,
    ),
    ParameterSpec(
        "rotation_variance_rad2_per_m",
        _NOISE.rotation_rad2_per_m,
        "Odometry heading variance per metre travelled.",
        minimum=0.0,
        maximum=_MAX_VARIANCE_RATE,
        runtime=True,
    ),
    ParameterSpec(
        "cross_track_variance_m2_per_m",
        _NOISE.cross_track_m2_per_m,
        "Odometry cross-track variance per metre travelled.",
        minimum=0.0,
        maximum=_MAX_VARIANCE_RATE,
        runtime=True,
    ),
    ParameterSpec(
        "odometry_error_states",
        _DEFAULTS.odometry_errors is not None,
        "Estimate the odometry's systematic errors (distance scale, rotation scale, "
        "heading drift per metre) as filter states.",
    ),
    ParameterSpec(
        "odometry_scale_sigma",
        _ERRORS.scale_sigma,
        "Prior standard deviation of the odometry's distance scale.",
        **_SIGMA_RANGE,
    ),
    ParameterSpec(
        "odometry_rotation_scale_sigma",
        _ERRORS.rotation_scale_sigma,
        "Prior standard deviation of the odometry's rotation scale (wheel base).",
        **_SIGMA_RANGE,
    ),
    ParameterSpec(
        "odometry_heading_drift_sigma_rad_per_m",
        _ERRORS.heading_drift_sigma_rad_per_m,
        "Prior standard deviation of the heading drift per metre driven (unequal wheel radii, rad/m).",
        **_SIGMA_RANGE,
    ),
    ParameterSpec(
        "gate_probability",
        _DEFAULTS.gate_probability,
        "Chi-square (1 dof) probability of the per-bearing validation gate.",
        minimum=0.5,
        maximum=0.999999,
        runtime=True,
    ),
    ParameterSpec(
        "odometry_history_s",
        _TIMING.odometry_history_s,
        "Odometry kept to apply late bearings (s).",
        minimum=0.1,
        maximum=10.0,
    ),
    ParameterSpec(
        "max_odometry_extrapolation_s",
        _TIMING.max_odometry_extrapolation_s,
        "Bearings up to this far (s) past the newest odometry are applied at once; "
        "later ones wait for odometry.",
        minimum=0.0,
        maximum=1.0,
    ),
    ParameterSpec(
        "odometry_gap_s",
        _TIMING.odometry_gap_s,
        "Odometry silence (s) treated as a gap (covariance grows).",
        minimum=0.001,
        maximum=10.0,
    ),
    ParameterSpec(
        "gap_position_variance_m2_per_s",
        _TIMING.gap_position_variance_m2_per_s,
        "Position variance added per second of gap.",
        minimum=0.0,
        maximum=_MAX_VARIANCE_RATE,
    ),
    ParameterSpec(
        "gap_heading_variance_rad2_per_s",
        _TIMING.gap_heading_variance_rad2_per_s,
        "Heading variance added per second of gap.",
        minimum=0.0,
        maximum=_MAX_VARIANCE_RATE,
    ),
    ParameterSpec(
        "kidnap_gated_bearings",
        _TIMING.kidnap_gated_bearings,
        "Gated bearings, among the last kidnap_window_bearings, that make the filter "
        "lost (a ToTal pose elsewhere then re-initialises it).",
        minimum=1,
        maximum=1000,
    ),
    ParameterSpec(
        "kidnap_window_bearings",
        _TIMING.kidnap_window_bearings,
        "Number of recent bearings judged for kidnap_gated_bearings.",
        minimum=1,
        maximum=1000,
    ),
    ParameterSpec(
        "kidnap_probability",
        _TIMING.kidnap_probability,
        "Chi-square (3 dof) probability beyond which a ToTal pose is inconsistent with "
        "the estimate (their covariances summed), i.e. 'elsewhere'.",
        minimum=0.5,
        maximum=0.999999,
    ),
    ParameterSpec(
        "kidnap_distance_m",
        _TIMING.kidnap_distance_m,
        "Distance (m) from the estimate that always makes a ToTal pose 'elsewhere'.",
        minimum=0.0,
        maximum=1.0e3,
    ),
    ParameterSpec(
        "kidnap_heading_rad",
        _TIMING.kidnap_heading_rad,
        "Heading difference (rad) that always makes a ToTal pose 'elsewhere'.",
        minimum=0.0,
        maximum=1.0e3,
    ),
    ParameterSpec(
        "time_jump_confirmations",
        _TIMING.time_jump_confirmations,
        "Consecutive odometry messages stamped in the past that make a time jump "
        "(a bag loop: the filter resets); fewer are stray messages, dropped.",
        minimum=1,
        maximum=100,
    ),
    ParameterSpec(
        "lost_nis_window_bearings",
        _TIMING.lost_nis_window_bearings,
        "Bearings whose NIS (normalised innovation squared) the lost test sums; 0 switches the test off.",
        minimum=0,
        maximum=1000,
    ),
    ParameterSpec(
        "lost_nis_probability",
        _TIMING.lost_nis_probability,
        "Chi-square probability beyond which the summed NIS makes the filter lost "
        "(the next ToTal pose re-initialises it).",
        minimum=0.5,
        maximum=1.0 - 1e-12,
    ),
    ParameterSpec(
        "confirming_bearings",
        _TIMING.confirming_bearings,
        "Accepted bearings in a row (from two beacons at least; 9: three revolutions of three beacons) "
        "that confirm the estimate after a break of its continuity (an operator's pose, an odometry jump "
        "or silence, a time jump, a re-initialisation after a kidnap or a lost test): the status is "
        "degraded until then; 0 switches the check off.",
        minimum=0,
        maximum=1000,
    ),
    ParameterSpec(
        "use_total_pose",
        _DEFAULTS.use_total_pose,
        "Initialise (and re-initialise after a kidnapping) from ToTal's accepted poses on beams/pose.",
        runtime=True,
    ),
    ParameterSpec(
        "default_pose_sigma",
        list(_DEFAULTS.default_pose_sigma),
        "Standard deviations (m, m, rad) of a pose without a usable covariance (at most the table's size: "
        "a larger prior wedged the filter).",
        minimum=1e-6,
        maximum=MAX_POSE_SIGMA_M,
        length=3,
        runtime=True,
    ),
)


def _settings_of(values: Mapping[str, Any]) -> FilterSettings:
    """The settings of every filter parameter's value by name (ValueError for values the settings refuse
    together, such as kidnap_gated_bearings above kidnap_window_bearings)."""
    noise = ProcessNoise(
        translation_m2_per_m=float(values["translation_variance_m2_per_m"]),
        rotation_rad2_per_rad=float(values["rotation_variance_rad2_per_rad"]),
        rotation_rad2_per_m=float(values["rotation_variance_rad2_per_m"]),
        cross_track_m2_per_m=float(values["cross_track_variance_m2_per_m"]),
    )
    errors = None
    if values["odometry_error_states"]:
        errors = OdometryErrorStates(
            scale_sigma=float(values["odometry_scale_sigma"]),
            rotation_scale_sigma=float(values["odometry_rotation_scale_sigma"]),
            heading_drift_sigma_rad_per_m=float(values["odometry_heading_drift_sigma_rad_per_m"]),
        )
    timing = LocaliserConfig(
        odometry_history_s=float(values["odometry_history_s"]),
        max_odometry_extrapolation_s=float(values["max_odometry_extrapolation_s"]),
        odometry_gap_s=float(values["odometry_gap_s"]),
        gap_position_variance_m2_per_s=float(values["gap_position_variance_m2_per_s"]),
        gap_heading_variance_rad2_per_s=float(values["gap_heading_variance_rad2_per_s"]),
        kidnap_gated_bearings=int(values["kidnap_gated_bearings"]),
        kidnap_window_bearings=int(values["kidnap_window_bearings"]),
        kidnap_probability=float(values["kidnap_probability"]),
        kidnap_distance_m=float(values["kidnap_distance_m"]),
        kidnap_heading_rad=float(values["kidnap_heading_rad"]),
        time_jump_confirmations=int(values["time_jump_confirmations"]),
        lost_nis_window_bearings=int(values["lost_nis_window_bearings"]),
        lost_nis_probability=float(values["lost_nis_probability"]),
        confirming_bearings=int(values["confirming_bearings"]),
    )
    return FilterSettings(
        noise,
        errors,
        float(values["gate_probability"]),
        timing,
        bool(values["use_total_pose"]),
        tuple(float(v) for v in values["default_pose_sigma"]),
        motion_limits_of(values),
        power_bias=power_bias_states_of(values),
        turret_offset=turret_offset_states_of(values),
        beacon_states=beacon_states_of(values),
    )


def _filter_settings_check(values: Mapping[str, Any]) -> str | None:
    try:
        _settings_of(values)
    except ValueError as error:
        return str(error)
    return None


EKF_PARAMETERS = ParameterTable(
    "ekf_node",
    (
        *GEOMETRY_SPECS,
        *FILTER_SPECS,
        *MOTION_SPECS,
        *STAMP_SPECS,
        *BEARING_RATE_SPECS,
        ODOMETRY_RATE_SPEC,
        *POWER_BIAS_PARAMETERS,
        *TURRET_OFFSET_PARAMETERS,
        *BEACON_STATE_PARAMETERS,
        ParameterSpec("map_frame", "map", "Frame of the estimate (REP-105)."),
        ParameterSpec("base_frame", "base_link", "The robot's frame (child)."),
        ParameterSpec("odom_frame", "odom", "The odometry's frame (child of the map -> odom transform)."),
        ParameterSpec("publish_tf", True, "Publish the map -> odom transform on /tf."),
        ParameterSpec(
            "publish_rate_hz", 20.0, "Rate of the published estimate (Hz).", minimum=0.1, maximum=1000.0
        ),
    ),
    (*GEOMETRY_CHECKS, _filter_settings_check, rates_check),
)


def filter_settings(parameters: Mapping[str, Any]) -> FilterSettings:
    """The filter settings of ekf_node's parameter values by name (a missing one takes its default);
    ParameterError (a ValueError) for a value the node refuses, alone or with the others."""
    return _settings_of(EKF_PARAMETERS.validate(parameters, ignore=ROS_NODE_PARAMETERS))
