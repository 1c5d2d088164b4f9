"""calibration_node's parameters: one spec each. The capture and fit settings are read by each service
call, so they may change at runtime; the dataset file and the a-priori beacon map are checked against each
other at start-up and stay read-only. The capture (`dataset`) and Algorithm 7.1 (`calibrate`) take their
defaults from here."""

from beams_common.config.geometry_parameters import beacon_map_check, beacon_map_specs
from beams_common.config.parameters import ParameterSpec, ParameterTable

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
            0.8,
            "A beacon decoded in fewer revolutions than this fraction counts as missing.",
            minimum=0.01,
            maximum=1.0,
            runtime=True,
        ),
        ParameterSpec(
            "max_spread_deg",
            0.3,
            "Bearing spread (deg, one revolution) above which the robot is deemed to have moved.",
            minimum=1e-3,
            maximum=10.0,
            runtime=True,
        ),
        ParameterSpec(
            "eta_m_per_rad",
            1.0,
            "eta of eq. 7.12 (m/rad; section 7.3.1: 1 m/rad).",
            minimum=1e-3,
            maximum=1e3,
            runtime=True,
        ),
        ParameterSpec(
            "threshold", 0.1, "t of Algorithm 7.1 (section 7.3.5).", minimum=1e-6, maximum=1.0, runtime=True
        ),
        ParameterSpec(
            "max_iterations", 10, "Bound on the loop of Algorithm 7.1.", minimum=1, maximum=100, runtime=True
        ),
        ParameterSpec(
            "leave_one_out", True, "Compute the leave-one-position-out error (12 extra fits).", runtime=True
        ),
        ParameterSpec(
            "min_configurations",
            12,
            "Fewest configurations a calibration accepts.",
            minimum=3,
            maximum=100000,
            runtime=True,
        ),
    ),
    (beacon_map_check(),),
)
