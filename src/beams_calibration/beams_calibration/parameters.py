"""calibration_node's parameters: one spec each. The capture and fit settings are read by each service
call, so they may change at runtime; the dataset file and the a-priori beacon map are checked against each
other at start-up and stay read-only."""

import math
from collections.abc import Mapping
from typing import Any

from beams_calibration.calibrate import DEFAULT_ETA_M_PER_RAD, DEFAULT_THRESHOLD, CoverageRequirements
from beams_calibration.dataset import DEFAULT_MAX_SPREAD_RAD, DEFAULT_MIN_SEEN_FRACTION
from beams_common.geometry_parameters import beacon_map_check, beacon_map_specs
from beams_common.parameters import ParameterSpec, ParameterTable

CALIBRATION_PARAMETERS = ParameterTable(
    "calibration_node",
    (
        ParameterSpec("dataset_file", "calibration_dataset.yaml", "Dataset file (YAML) to append to."),
        ParameterSpec("calibration_file_out", "calibration.yaml", "Calibration file written.", runtime=True),
        ParameterSpec(
            "plots_directory",
            "",
            "Directory for the PNG figures of each calibration; empty for none.",
            runtime=True,
        ),
        *beacon_map_specs(what="A-priori beacon", runtime=False),
        ParameterSpec(
            "default_revolutions",
            100,
            "Revolutions averaged when a request asks 0.",
            minimum=1,
            maximum=10000,
            runtime=True,
        ),
        ParameterSpec(
            "min_seen_fraction",
            DEFAULT_MIN_SEEN_FRACTION,
            "A beacon decoded in fewer revolutions than this fraction counts as missing.",
            minimum=0.01,
            maximum=1.0,
            runtime=True,
        ),
        ParameterSpec(
            "max_spread_deg",
            math.degrees(DEFAULT_MAX_SPREAD_RAD),
            "Bearing spread (deg, one revolution) above which the robot is deemed to have moved.",
            minimum=1e-3,
            maximum=10.0,
            runtime=True,
        ),
        ParameterSpec(
            "eta_m_per_rad",
            DEFAULT_ETA_M_PER_RAD,
            "eta of eq. 7.12 (m/rad).",
            minimum=1e-3,
            maximum=1e3,
            runtime=True,
        ),
        ParameterSpec(
            "threshold", DEFAULT_THRESHOLD, "t of Algorithm 7.1.", minimum=1e-6, maximum=1.0, runtime=True
        ),
        ParameterSpec(
            "max_iterations", 10, "Bound on the loop of Algorithm 7.1.", minimum=1, maximum=100, runtime=True
        ),
        ParameterSpec(
            "leave_one_out", True, "Compute the leave-one-position-out error (12 extra fits).", runtime=True
        ),
        ParameterSpec(
            "min_configurations",
            CoverageRequirements().min_configurations,
            "Fewest configurations a calibration accepts.",
            minimum=3,
            maximum=100000,
            runtime=True,
        ),
    ),
    (beacon_map_check(),),
)


def coverage_requirements(values: Mapping[str, Any]) -> CoverageRequirements:
    """What the calibration demands of a dataset, from the validated parameters."""
    return CoverageRequirements(min_configurations=values["min_configurations"])
