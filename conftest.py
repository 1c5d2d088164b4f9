"""Every test is marked with its tier by where it lives, so a new test is marked by its folder:

    src/<package>/test/      unit      (pure modules, one package; no DDS)
    test/unit/               unit      (pure modules across packages)
    test/scenario/           scenario  (offline simulated matches, replays, command-line tools on bags)
    test/dds/                dds       (installed nodes as processes, over DDS)
    test/thesis/             thesis    (the thesis's figures and tables reproduced)
    test/static/             static    (the source and the docs: layering, generated docs in sync)

`make test-fast` is `-m "not dds"`; test/static/test_test_tiers.py fails on a test file outside a tier.

The longest files run first (FILE_SECONDS): `make test` hands whole files to its pytest-xdist workers in
collection order (`--dist loadfile --no-loadscope-reorder`), so the minutes-long files start at once and
the short ones fill in at the end, and the workers finish together. The files over SLOW_S are marked
`slow` as well: `-m "dds and not slow"` leaves them out while working on the nodes.

numpy's OpenBLAS runs one thread per process (unless the environment says otherwise): with two pytest
workers or node processes on 2 cores its own threads only competed with them (the tiers without DDS took
twice as long on 2 workers with one thread per core each).
"""

import os
import pathlib

import pytest
from hypothesis import settings

# Timing is the benches' business, not the tests': on 2 shared cores an example may take 0.5 s (a first
# call's imports, the load), past hypothesis' 200 ms deadline, and a test would fail for it alone.
settings.register_profile("beams", deadline=None)
settings.load_profile("beams")

# before any test module (or node process, which inherits it) loads numpy
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

ROOT = pathlib.Path(__file__).resolve().parent
TIERS = ("unit", "scenario", "dds", "thesis", "static")
# Seconds each long test file took (`--junitxml`, its test times summed by file; the DDS files in one
# process on 2026-11-24, the others on 2 workers on 2026-11-27, 2 shared cores at load average 4 to 7;
# test_command_line_tools, test_calibration_file_schemas, test_self_calibration_beacons and
# test_estimate_noise_cli on 2 workers on 2026-11-28 at load average 3 to 5.5;
# test_calibration_guided_session, test_service_concurrency and test_parameter_refusals alone on
# 2026-11-28, idle),
# by file name so that a file moved between packages keeps its figure. A file not listed runs after these
# in collection order: add it when it takes 8 s or more.
FILE_SECONDS = {
    "test_fault_campaign.py": 165,
    "test_self_calibration.py": 164,
    "test_command_line_tools.py": 127,
    "test_parameter_refusals.py": 110,
    "test_system_faults.py": 95,
    "test_ekf_message_validation.py": 84,
    "test_plain_defaults.py": 81,
    "test_ekf_lost_detection.py": 74,
    "test_calibration_algorithm.py": 69,
    "test_self_calibration_beacons.py": 67,
    "test_estimate_noise_cli.py": 62,
    "test_system_bad_inputs.py": 60,
    "test_respawn.py": 52,
    "test_system_multi_robot.py": 51,
    "test_calibration_guided_session.py": 50,
    "test_nees_band.py": 48,
    "test_tools_bag_replay.py": 44,
    "test_executables.py": 43,
    "test_calibration_node.py": 37,
    "test_sim_time.py": 37,
    "test_calibration_thesis_results.py": 37,
    "test_driver_decoder.py": 36,
    "test_plausibility_nodes.py": 35,
    "test_driver_noise_estimation.py": 35,
    "test_calibration_file_schemas.py": 32,
    "test_ekf_odometry_error_states.py": 32,
    "test_system_hosts.py": 31,
    "test_system_plausibility.py": 31,
    "test_driver_serial_protocol.py": 31,
    "test_second_publisher.py": 30,
    "test_driver_lifecycle.py": 29,
    "test_ekf_node.py": 28,
    "test_standby.py": 28,
    "test_common_validation.py": 25,
    "test_service_concurrency.py": 25,
    "test_calibration_outputs.py": 24,
    "test_driver_node.py": 24,
    "test_virtual_turret.py": 24,
    "test_firmware_hil.py": 23,
    "test_ekf_hardware_consistency.py": 23,
    "test_triangulation_error_analysis.py": 23,
    "test_ekf_calibration_reload.py": 20,
    "test_bag_replay.py": 19,
    "test_parameters.py": 18,
    "test_protection_level_match.py": 17,
    "test_driver_serial_integrity.py": 17,
    "test_protection_level_status.py": 16,
    "test_generated_fields.py": 14,
    "test_common_pose_intake.py": 13,
    "test_docs_in_sync.py": 13,
    "test_triangulation_node.py": 12,
    "test_driver_serial_source.py": 12,
    "test_calibration_dataset.py": 12,
    "test_common_parameters.py": 12,
    "test_driver_serial_replug.py": 11,
    "test_rate_status.py": 11,
    "test_triangulation_match.py": 11,
    "test_layering.py": 11,
    "test_ekf_localiser.py": 10,
    "test_status_topic.py": 9,
    "test_driver_hardware_model.py": 9,
    "test_edge_source_plugin.py": 8,
    "test_driver_serial_versions.py": 8,
    "test_common_standby.py": 3,
    "test_node_names.py": 1,
}
# A DDS file of this or more (its tests together) is `slow`: the DDS files that run real-time matches or
# sessions of a minute or more (the fault campaign, the guided session, the faults, the plain defaults,
# the bad inputs).
SLOW_S = 60.0


def tier_of(path: pathlib.Path) -> str | None:
    """The tier of a test file by its folder, None outside every tier folder."""
    try:
        parts = path.resolve().relative_to(ROOT).parts
    except ValueError:
        return None
    if len(parts) >= 4 and parts[0] == "src" and parts[2] == "test":
        return "unit"
    if len(parts) >= 3 and parts[0] == "test" and parts[1] in TIERS:
        return parts[1]
    return None


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        tier = tier_of(item.path)
        if tier is not None:
            item.add_marker(tier)
        if tier == "dds" and FILE_SECONDS.get(item.path.name, 0.0) >= SLOW_S:
            item.add_marker("slow")
    # longest file first; a stable sort: a file's tests, and the unlisted files, keep their order
    items.sort(key=lambda item: -FILE_SECONDS.get(item.path.name, 0.0))
