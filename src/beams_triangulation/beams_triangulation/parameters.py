"""triangulation_node's parameters: one spec each, for the node and for the offline replay; the settings
classes (`gating.GateConfig`, `pipeline.TriangulationSettings`) take their defaults from it."""

from beams_common.config.geometry_parameters import GEOMETRY_CHECKS, GEOMETRY_SPECS
from beams_common.config.parameters import ParameterSpec, ParameterTable
from beams_common.intake.plausibility import MOTION_SPECS, STAMP_SPECS
from beams_common.status.health import BEARING_RATE_SPECS, ODOMETRY_RATE_SPEC, rates_check
from beams_common.status.protection_level import INTEGRITY_SPECS

TRIANGULATION_PARAMETERS = ParameterTable(
    "triangulation_node",
    (
        *GEOMETRY_SPECS,
        ParameterSpec(
            "max_inverse_abs_d",
            2.0,
            "Gate on ToTal's reliability measure 1/|D| (m^-2, thesis section 6.3).",
            minimum=1e-9,
            maximum=1e12,
            runtime=True,
        ),
        ParameterSpec(
            "max_position_std_m",
            0.05,
            "Gate on the propagated position std sqrt(var x + var y) (m).",
            minimum=1e-9,
            maximum=1e3,
            runtime=True,
        ),
        ParameterSpec(
            "use_odometry",
            True,
            "Bring each revolution's bearings to one instant with `odom`; a revolution the "
            "odometry does not cover is then published rejected.",
        ),
        ParameterSpec(
            "odometry_history_s",
            2.0,
            "Odometry kept for compensation (s).",
            minimum=0.1,
            maximum=60.0,
        ),
        ParameterSpec(
            "max_odometry_extrapolation_s",
            0.05,
            "How far past the newest odometry a bearing may be and still be compensated (s).",
            minimum=0.0,
            maximum=1.0,
        ),
        ParameterSpec("map_frame", "map", "Frame of the published poses.", runtime=True),
        ParameterSpec(
            "publish_markers",
            True,
            "Publish RViz markers (built only while something subscribes).",
            runtime=True,
        ),
        *MOTION_SPECS,
        *STAMP_SPECS,
        *BEARING_RATE_SPECS,
        ODOMETRY_RATE_SPEC,
        *INTEGRITY_SPECS,
    ),
    (*GEOMETRY_CHECKS, rates_check),
)
