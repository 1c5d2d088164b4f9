"""ekf_node's parameters: one spec each, for the node and for the offline replay."""

from collections.abc import Mapping
from typing import Any

from beams_common.geometry_parameters import GEOMETRY_CHECKS, GEOMETRY_SPECS
from beams_common.parameters import ParameterSpec, ParameterTable
from beams_ekf.localiser import FilterSettings, filter_parameter_defaults, filter_settings
from beams_ekf.power_bias_states import POWER_BIAS_PARAMETERS
from beams_ekf.turret_offset_states import TURRET_OFFSET_PARAMETERS

# The filter's parameters: (name, description, minimum, maximum); defaults from FilterSettings.
_FILTER_PARAMETERS = (
    ("translation_variance_m2_per_m", "Odometry position variance per metre travelled.", 0.0, 1.0e3),
    ("rotation_variance_rad2_per_rad", "Odometry heading variance per radian turned.", 0.0, 1.0e3),
    ("rotation_variance_rad2_per_m", "Odometry heading variance per metre travelled.", 0.0, 1.0e3),
    ("cross_track_variance_m2_per_m", "Odometry cross-track variance per metre travelled.", 0.0, 1.0e3),
    (
        "odometry_error_states",
        "Estimate the odometry's systematic errors (distance scale, rotation scale, "
        "heading drift per metre) as filter states.",
        None,
        None,
    ),
    ("odometry_scale_sigma", "Prior standard deviation of the odometry's distance scale.", 1e-6, 1.0),
    (
        "odometry_rotation_scale_sigma",
        "Prior standard deviation of the odometry's rotation scale (wheel base).",
        1e-6,
        1.0,
    ),
    (
        "odometry_heading_drift_sigma_rad_per_m",
        "Prior standard deviation of the heading drift per metre driven (unequal wheel radii, rad/m).",
        1e-6,
        1.0,
    ),
    ("gate_probability", "Chi-square (1 dof) probability of the per-bearing validation gate.", 0.5, 0.999999),
    ("odometry_history_s", "Odometry kept to apply late bearings (s).", 0.1, 10.0),
    (
        "max_odometry_extrapolation_s",
        "Bearings up to this far (s) past the newest odometry are applied at once; "
        "later ones wait for odometry.",
        0.0,
        1.0,
    ),
    ("odometry_gap_s", "Odometry silence (s) treated as a gap (covariance grows).", 0.001, 10.0),
    ("gap_position_variance_m2_per_s", "Position variance added per second of gap.", 0.0, 1.0e3),
    ("gap_heading_variance_rad2_per_s", "Heading variance added per second of gap.", 0.0, 1.0e3),
    (
        "kidnap_gated_bearings",
        "Gated bearings, among the last kidnap_window_bearings, that make the filter "
        "lost (a ToTal pose elsewhere then re-initialises it).",
        1,
        1000,
    ),
    ("kidnap_window_bearings", "Number of recent bearings judged for kidnap_gated_bearings.", 1, 1000),
    (
        "kidnap_probability",
        "Chi-square (3 dof) probability beyond which a ToTal pose is inconsistent with "
        "the estimate (their covariances summed), i.e. 'elsewhere'.",
        0.5,
        0.999999,
    ),
    (
        "kidnap_distance_m",
        "Distance (m) from the estimate that always makes a ToTal pose 'elsewhere'.",
        0.0,
        1.0e3,
    ),
    (
        "kidnap_heading_rad",
        "Heading difference (rad) that always makes a ToTal pose 'elsewhere'.",
        0.0,
        1.0e3,
    ),
    (
        "time_jump_confirmations",
        "Consecutive odometry messages stamped in the past that make a time jump "
        "(a bag loop: the filter resets); fewer are stray messages, dropped.",
        1,
        100,
    ),
    (
        "lost_nis_window_bearings",
        "Bearings whose NIS (normalised innovation squared) the lost test sums; 0 switches the test off.",
        0,
        1000,
    ),
    (
        "lost_nis_probability",
        "Chi-square probability beyond which the summed NIS makes the filter lost "
        "(the next ToTal pose re-initialises it).",
        0.5,
        1.0 - 1e-12,
    ),
    (
        "use_total_pose",
        "Initialise (and re-initialise after a kidnapping) from ToTal's accepted poses on beams/pose.",
        None,
        None,
    ),
    (
        "default_pose_sigma",
        "Standard deviations (m, m, rad) of a pose without a usable covariance.",
        1e-6,
        100.0,
    ),
)
# changeable while the filter runs: they enter the next prediction and the next bearing's gate
_RUNTIME_FILTER_PARAMETERS = {
    "translation_variance_m2_per_m",
    "rotation_variance_rad2_per_rad",
    "rotation_variance_rad2_per_m",
    "cross_track_variance_m2_per_m",
    "gate_probability",
    "default_pose_sigma",
    "use_total_pose",
}
_DEFAULTS = filter_parameter_defaults()


def _filter_spec(name: str, description: str, low: float | None, high: float | None) -> ParameterSpec:
    length = 3 if name == "default_pose_sigma" else None
    return ParameterSpec(
        name,
        _DEFAULTS[name],
        description,
        minimum=low,
        maximum=high,
        length=length,
        runtime=name in _RUNTIME_FILTER_PARAMETERS,
    )


def _filter_settings_check(values: Mapping[str, Any]) -> str | None:
    try:
        filter_settings(values)
    except ValueError as error:
        return str(error)
    return None


EKF_PARAMETERS = ParameterTable(
    "ekf_node",
    (
        *GEOMETRY_SPECS,
        *(_filter_spec(*row) for row in _FILTER_PARAMETERS),
        *POWER_BIAS_PARAMETERS,
        *TURRET_OFFSET_PARAMETERS,
        ParameterSpec("map_frame", "map", "Frame of the estimate (REP-105)."),
        ParameterSpec("base_frame", "base_link", "The robot's frame (child)."),
        ParameterSpec("odom_frame", "odom", "The odometry's frame (child of the map -> odom transform)."),
        ParameterSpec("publish_tf", True, "Publish the map -> odom transform on /tf."),
        ParameterSpec(
            "publish_rate_hz", 20.0, "Rate of the published estimate (Hz).", minimum=0.1, maximum=1000.0
        ),
    ),
    (*GEOMETRY_CHECKS, _filter_settings_check),
)


def ekf_settings(parameters: Mapping[str, Any]) -> FilterSettings:
    """The filter settings of ekf_node's parameter values by name (a missing one takes its default);
    ParameterError (a ValueError) for a value the node refuses, alone or with the others."""
    return filter_settings(EKF_PARAMETERS.validate(parameters))
