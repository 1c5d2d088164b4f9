"""The offline `calibrate` command and its PNG figures, on a noise-free dataset of the thesis's setup."""

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from beams_calibration import calibrate_command
from beams_calibration.dataset import load_dataset, save_dataset
from beams_common.calibration.calibration_file import load_calibration, node_refusal
from beams_common.config.command_line import EXIT_REFUSED
from beams_common.geometry.beacon_map import BeaconMap
from beams_thesis import thesis_setup

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# A 3 mm beacon error and a turret offset, no angle bias: the fit must find both.
MOVED = thesis_setup.PRIOR_BEACONS.xy + np.array([[0.003, 0.0], [0.0, -0.002], [0.0, 0.0]])


@pytest.fixture
def dataset_path(tmp_path: Path) -> Path:
    truth = BeaconMap.from_lists((1, 2, 3), MOVED[:, 0], MOVED[:, 1])
    # Every other position of table 7.2 (6 x 4 configurations): enough, and quicker.
    dataset = thesis_setup.geometric_dataset(
        thesis_setup.reference_poses(thesis_setup.REFERENCE_POSITIONS[::2]),
        truth,
        turret_offset_m=(0.001, -0.001),
        prior_map=thesis_setup.PRIOR_BEACONS,
    )
    path = tmp_path / "dataset.yaml"
    save_dataset(dataset, path)
    return path


def test_command_writes_calibration_report_and_figures(dataset_path: Path, tmp_path: Path, capsys):
    output = tmp_path / "out" / "calibration.yaml"
    status = calibrate_command.main(
        [str(dataset_path), "-o", str(output), "--plots", str(tmp_path / "plots"), "--no-leave-one-out"]
    )
    printed = capsys.readouterr().out
    assert status == 0
    assert "global optimisation" in printed and "no calibration" in printed and "turret offset" in printed
    assert "s] iteration 1: beacons: err_RMS" in printed  # progress lines with elapsed time
    calibration = load_calibration(output)
    np.testing.assert_allclose(calibration.beacon_map.xy, MOVED, atol=2e-4)
    np.testing.assert_allclose(calibration.turret_offset_m, (0.001, -0.001), atol=1e-4)
    before, after = calibration.rms[0], calibration.rms[-1]
    assert before.position_rms_m > 1e-3 and after.position_rms_m < 0.1e-3
    assert after.orientation_rms_rad < math.radians(0.01)
    for name in ("calibration_positions.png", "calibration_corrections.png"):
        data = (tmp_path / "plots" / name).read_bytes()
        assert data.startswith(PNG_SIGNATURE) and len(data) > 20_000


def test_dry_run_with_table_7_5_writes_nothing(dataset_path: Path, tmp_path: Path, capsys):
    output = tmp_path / "calibration.yaml"
    arguments = [str(dataset_path), "-o", str(output), "--dry-run", "--no-leave-one-out", "--table-7-5"]
    assert calibrate_command.main(arguments) == 0
    assert not output.exists()
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("table 7.5 line")]
    assert [row.split(":")[0] for row in rows] == [f"table 7.5 line {n}" for n in range(1, 12)]
    positions_mm = [float(row.split()[-6]) for row in rows]
    # The global calibration (line 11) is the best line, as in the thesis.
    assert positions_mm[10] <= min(positions_mm) + 1e-3
    # Methods that cannot move the beacons (lines 2, 3, 4, 7) keep millimetres of error.
    assert min(positions_mm[k] for k in (1, 2, 3, 6)) > 1.0
    # Beacons only: every pose is off by exactly the unmodelled turret offset, |(1, -1)| mm.
    assert positions_mm[4] == pytest.approx(math.sqrt(2.0), abs=0.02)


def test_a_blunder_is_named_excluded_and_the_file_is_one_a_node_takes(
    dataset_path: Path, tmp_path: Path, capsys
):
    """One bearing of configuration 5 off by 1 rad (issue 27: the command wrote a file every node refused): a
    WARNING names it, the fit is the clean one's (a 0.02 rad one: test_calibration_algorithm)."""
    dataset = load_dataset(dataset_path)
    blundered = dataset.configurations[4]
    wrong = blundered.observations[1]
    observations = (blundered.observations[0], replace(wrong, bearing_rad=wrong.bearing_rad + 1.0))
    configurations = list(dataset.configurations)
    configurations[4] = replace(blundered, observations=(*observations, *blundered.observations[2:]))
    save_dataset(replace(dataset, configurations=tuple(configurations)), dataset_path)
    output = tmp_path / "calibration.yaml"
    assert calibrate_command.main([str(dataset_path), "-o", str(output), "--no-leave-one-out"]) == 0
    warnings = [line for line in capsys.readouterr().out.splitlines() if line.startswith("WARNING:")]
    assert (
        len(warnings) == 1
        and warnings[0].startswith("WARNING: configuration 5 ")
        and "blunder" in warnings[0]
    )
    calibration = load_calibration(output)
    assert node_refusal(calibration, thesis_setup.PRIOR_BEACONS, (0.0, 0.0)) == ""
    np.testing.assert_allclose(calibration.beacon_map.xy, MOVED, atol=2e-4)
    assert calibration.rms[-1].position_rms_m < 0.1e-3


def test_refusals_exit_with_status_2(tmp_path: Path, capsys):
    assert calibrate_command.main([str(tmp_path / "missing.yaml")]) == EXIT_REFUSED
    assert "does not exist" in capsys.readouterr().err
    small = tmp_path / "small.yaml"
    save_dataset(thesis_setup.geometric_dataset(thesis_setup.reference_poses()[:5]), small)
    assert calibrate_command.main([str(small), "-o", str(tmp_path / "c.yaml")]) == EXIT_REFUSED
    assert "calibration refused: 5 usable configurations" in capsys.readouterr().err
    assert not (tmp_path / "c.yaml").exists()
