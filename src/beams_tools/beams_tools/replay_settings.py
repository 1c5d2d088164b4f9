"""What the replay takes from the nodes' parameters: validated by their own tables (a parameter file the
node would refuse is refused here with the same reason), mapped by the functions the nodes use."""

from __future__ import annotations

import os
import pathlib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from beams_common.config.geometry_parameters import geometry_of
from beams_common.config.parameters import ROS_NODE_PARAMETERS, ParameterTable, load_parameter_file
from beams_common.geometry.beacon_map import BeaconMap
from beams_ekf.parameters import EKF_PARAMETERS, filter_settings
from beams_ekf.settings import FilterSettings
from beams_tools.robot_processes import PARAMS_FILE
from beams_triangulation.parameters import TRIANGULATION_PARAMETERS
from beams_triangulation.pipeline import TriangulationSettings, triangulation_settings


def installed_params_file() -> pathlib.Path | None:
    """beams_bringup's installed parameter file, the replay's default (ament index, or BEAMS_INSTALL_BASE),
    None when absent."""
    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.append(pathlib.Path(get_package_share_directory("beams_bringup")) / "config" / PARAMS_FILE)
    except Exception:  # no ament index (a plain checkout): try the workspace's install tree
        pass
    install_base = os.environ.get("BEAMS_INSTALL_BASE")
    if install_base:
        candidates.append(
            pathlib.Path(install_base) / "beams_bringup" / "share" / "beams_bringup" / "config" / PARAMS_FILE
        )
    return next((path for path in candidates if path.exists()), None)


# -- settings -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReplaySettings:
    """What the two nodes take from their parameters (`settings_from_parameters({}, {})`: their defaults)."""

    triangulation_map: BeaconMap
    triangulation_offset_m: tuple[float, float]
    triangulation: TriangulationSettings
    ekf_map: BeaconMap
    ekf_offset_m: tuple[float, float]
    ekf: FilterSettings
    # ekf_node's validated parameter values (its status: rates, integrity risk, alert limits)
    ekf_values: Mapping[str, Any]


def load_node_parameters(path: pathlib.Path | None, table: ParameterTable) -> dict[str, Any]:
    """The parameters a ROS parameter file gives the table's node, validated exactly as the node validates
    them (ParameterError naming the parameter otherwise); the node's defaults for None."""
    return table.validate({}) if path is None else load_parameter_file(path, table)


def settings_from_parameters(triangulation: Mapping[str, Any], ekf: Mapping[str, Any]) -> ReplaySettings:
    """Settings from the two nodes' parameter values by name (a missing one takes its default), validated
    by the nodes' own tables and mapped by the functions the nodes use."""
    triangulation = TRIANGULATION_PARAMETERS.validate(triangulation, ignore=ROS_NODE_PARAMETERS)
    ekf = EKF_PARAMETERS.validate(ekf, ignore=ROS_NODE_PARAMETERS)
    tri_geometry, ekf_geometry = geometry_of(triangulation), geometry_of(ekf)
    return ReplaySettings(
        triangulation_map=tri_geometry.beacon_map,
        triangulation_offset_m=tri_geometry.turret_offset_m,
        triangulation=triangulation_settings(triangulation),
        ekf_map=ekf_geometry.beacon_map,
        ekf_offset_m=ekf_geometry.turret_offset_m,
        ekf=filter_settings(ekf),
        ekf_values=ekf,
    )
