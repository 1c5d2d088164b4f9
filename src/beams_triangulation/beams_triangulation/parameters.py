"""triangulation_node's parameters: one spec each, for the node and for the offline replay."""

from collections.abc import Mapping
from typing import Any

from beams_common.geometry_parameters import GEOMETRY_CHECKS, GEOMETRY_SPECS
from beams_common.health import BEARING_RATE_SPECS, ODOMETRY_RATE_SPEC, rates_check
from beams_common.parameters import ParameterSpec, ParameterTable
from beams_common.plausibility import MOTION_SPECS, STAMP_SPECS, motion_limits_of
from beams_triangulation.gating import GateConfig
from beams_triangulation.pipeline import TriangulationSettings

_DEFAULTS = TriangulationSettings()

TRIANGULATION_PARAMETERS = ParameterTable(
    "triangulation_node",
    (
        *GEOMETRY_SPECS,
        ParameterSpec(
            "max_inverse_abs_d",
            _DEFAULTS.gates.max_inverse_abs_d,
            "Gate on ToTal's reliability measure 1/|D| (m^-2, thesis section 6.3).",
            minimum=1e-9,
            maximum=1e12,
            runtime=True,
        ),
        ParameterSpec(
            "max_position_std_m",
            _DEFAULTS.gates.max_position_std_m,
            "Gate on the propagated position std sqrt(var x + var y) (m).",
            minimum=1e-9,
            maximum=1e3,
            runtime=True,
        ),
        ParameterSpec(
            "use_odometry",
            _DEFAULTS.use_odometry,
            "Bring each revolution's bearings to one instant with `odom`; a revolution the "
            "odometry does not cover is then published rejected.",
        ),
        ParameterSpec(
            "odometry_history_s",
            _DEFAULTS.odometry_history_s,
            "Odometry kept for compensation (s).",
            minimum=0.1,
            maximum=60.0,
        ),
        ParameterSpec(
            "max_odometry_extrapolation_s",
            _DEFAULTS.max_odometry_extrapolation_s,
            "How far past the newest odometry a bearing may be and still be compensated (s).",
            minimum=0.0,
            maximum=1.0,
        ),
        ParameterSpec("map_frame", "map", "Frame of the published poses.", runtime=True),
        ParameterSpec("publish_markers", True, "Publish RViz markers.", runtime=True),
        *MOTION_SPECS,
        *STAMP_SPECS,
        *BEARING_RATE_SPECS,
        ODOMETRY_RATE_SPEC,
    ),
    (*GEOMETRY_CHECKS, rates_check),
)


def triangulation_settings(parameters: Mapping[str, Any]) -> TriangulationSettings:
    """The settings of triangulation_node's parameter values by name (a missing one takes its default);
    ParameterError (a ValueError) for a value the node refuses, alone or with the others."""
    values = TRIANGULATION_PARAMETERS.validate(parameters)
    return TriangulationSettings(
        gates=GateConfig(float(values["max_inverse_abs_d"]), float(values["max_position_std_m"])),
        use_odometry=bool(values["use_odometry"]),
        odometry_history_s=float(values["odometry_history_s"]),
        max_odometry_extrapolation_s=float(values["max_odometry_extrapolation_s"]),
        motion_limits=motion_limits_of(values),
    )
