"""ekf_node's parameters: one table of the specs (name, default, range, description, runtime flag) that
the settings' modules declare (the pose's, the state blocks', the filter's and the Localiser's), for the
node and for the offline replay; `filter_settings` builds the settings from the validated values.
"""

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

from beams_common.config.geometry_parameters import GEOMETRY_CHECKS, GEOMETRY_SPECS
from beams_common.config.parameters import ROS_NODE_PARAMETERS, ParameterSpec, ParameterTable
from beams_common.intake.plausibility import MOTION_SPECS, STAMP_SPECS, motion_limits_of
from beams_common.status.health import BEARING_RATE_SPECS, ODOMETRY_RATE_SPEC, rates_check
from beams_common.status.protection_level import INTEGRITY_SPECS
from beams_ekf.bearing_ekf import BEARING_EKF_SPECS, process_noise_of
from beams_ekf.settings import SETTINGS_SPECS, FilterSettings, LocaliserConfig
from beams_ekf.state_blocks import registered_blocks

_BLOCKS = registered_blocks(FilterSettings)
_LOCALISER = [f.name for f in fields(LocaliserConfig) if f.name in SETTINGS_SPECS.names]


def _settings_of(values: Mapping[str, Any]) -> FilterSettings:
    """The settings of every filter parameter's value by name (ValueError for values the settings refuse
    together, such as kidnap_gated_bearings above kidnap_window_bearings)."""
    return FilterSettings(
        process_noise=process_noise_of(values),
        gate_probability=float(values["gate_probability"]),
        localiser=LocaliserConfig(**{n: SETTINGS_SPECS[n].item_type(values[n]) for n in _LOCALISER}),
        use_total_pose=bool(values["use_total_pose"]),
        default_pose_sigma=tuple(float(v) for v in values["default_pose_sigma"]),
        motion_limits=motion_limits_of(values),
        **{name: states_of(values) for name, _, states_of in _BLOCKS},
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
        *BEARING_EKF_SPECS.specs,
        *SETTINGS_SPECS.specs,
        *MOTION_SPECS,
        *STAMP_SPECS,
        *BEARING_RATE_SPECS,
        ODOMETRY_RATE_SPEC,
        *INTEGRITY_SPECS,
        *(spec for _, specs, _ in _BLOCKS for spec in specs.specs),
        ParameterSpec("map_frame", "map", "Frame of the estimate (REP-105)."),
        ParameterSpec("base_frame", "base_link", "The robot's frame (child)."),
        ParameterSpec("odom_frame", "odom", "The odometry's frame (child of the map -> odom transform)."),
        ParameterSpec(
            "publish_tf",
            True,
            "Publish the map -> odom transform on /tf, once per estimate stamp (tf2 ignores a repeated one).",
        ),
        ParameterSpec(
            "publish_rate_hz",
            20.0,
            "Least rate of the published estimate (Hz): one after each revolution's bearings, and one a "
            "period after the last as odometry moves it.",
            minimum=0.1,
            maximum=1000.0,
        ),
        ParameterSpec(
            "checkpoint_file",
            "~/.ros/beams/{node}_checkpoint.yaml",
            "Where the learnt states (pose excluded, with the geometry they were learnt against) and the "
            "runtime-set parameters are kept for a restart (beams_ekf.checkpoint): written every "
            "checkpoint_period_s and at a clean stop, read at start. {node}: the node's fully qualified name "
            "(one file per node); ~/.ros: $ROS_HOME when set, where ROS keeps a robot's state; empty: off.",
        ),
        ParameterSpec(
            "checkpoint_period_s",
            20.0,
            "Period (s) of the checkpoint's writes; a kill -9 loses what was learnt since the last one.",
            minimum=1.0,
            maximum=3600.0,
        ),
    ),
    (*GEOMETRY_CHECKS, _filter_settings_check, rates_check),
)


def filter_settings(parameters: Mapping[str, Any]) -> FilterSettings:
    """The filter settings of ekf_node's parameter values by name (a missing one takes its default);
    ParameterError (a ValueError) for a value the node refuses, alone or with the others."""
    return _settings_of(EKF_PARAMETERS.validate(parameters, ignore=ROS_NODE_PARAMETERS))
