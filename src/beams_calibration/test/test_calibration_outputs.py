"""A calibration's outputs written all or nothing, a worse calibration refused, an implausible capture
pose refused (issue 15's false successes)."""

import math
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_calibration import calibrate_command
from beams_calibration.calibrate import CalibrationResult, calibrate
from beams_calibration.dataset import (
    Dataset,
    capture_pose_problem,
    save_dataset,
)
from beams_calibration.outputs import rms_regression, write_outputs
from beams_common.calibration.bearing_correction import THESIS_CORRECTION
from beams_common.calibration.calibration_file import load_calibration
from beams_common.config.command_line import EXIT_REFUSED
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.intake.plausibility import TABLE_MARGIN_M
from beams_thesis import thesis_setup

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _dataset() -> Dataset:
    """Every other position of table 7.2 with the thesis's biases, noise-free."""
    return thesis_setup.geometric_dataset(
        thesis_setup.reference_poses(thesis_setup.REFERENCE_POSITIONS[::2]),
        correction=THESIS_CORRECTION,
        turret_offset_m=(0.001, -0.001),
        prior_map=thesis_setup.PRIOR_BEACONS,
    )


@pytest.fixture(scope="module")
def result() -> CalibrationResult:
    return calibrate(_dataset(), leave_one_out=False)


def _files(directory: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()
    }


def test_a_sound_calibration_is_not_a_regression(result: CalibrationResult):
    assert result.after.position_rms_m < 0.1 * result.before.position_rms_m
    assert rms_regression(result, 1.0) == ""


def test_a_calibration_that_makes_the_rms_worse_is_refused(result: CalibrationResult):
    """Issue 15: a configuration at x = 1e6, y = -1e6, theta = 100 rad in the dataset; the fit answered
    success although the RMS got worse (6 deg -> 93 deg). It is now named and excluded as a blunder; a
    result worse than no calibration is still refused."""
    dataset = _dataset()
    wrong = replace(dataset.configurations[0], x_m=1e6, y_m=-1e6, theta_rad=100.0)
    outcome = calibrate(dataset.with_configuration(wrong), leave_one_out=False)
    assert len(outcome.warnings) == 1
    assert outcome.warnings[0].startswith("configuration 25 (1000000.000 m, -1000000.000 m, 5729.6 deg) ")
    assert "excluded as a blunder" in outcome.warnings[0] and rms_regression(outcome, 1.0) == ""
    assert outcome.after.position_rms_m < 0.1 * outcome.before.position_rms_m
    worse = replace(
        result,
        stages=(result.after, result.before),
        errors_before=result.errors_after,
        errors_after=result.errors_before,
    )
    assert "makes the RMS worse" in rms_regression(worse, 1.0)


def test_outputs_are_written_together_and_the_previous_calibration_kept(result, tmp_path: Path):
    output = tmp_path / "calibration.yaml"
    output.write_text("previous")
    written = write_outputs(result, output, tmp_path / "plots")
    assert sorted(p.name for p in written) == [
        "calibration.yaml",
        "calibration_corrections.png",
        "calibration_positions.png",
    ]
    assert (tmp_path / "calibration.yaml.bak").read_text() == "previous"
    assert load_calibration(output).turret_offset_m == pytest.approx(result.turret_offset_m)
    assert (tmp_path / "plots" / "calibration_positions.png").read_bytes().startswith(PNG_SIGNATURE)
    assert not [p for p in tmp_path.rglob("*.tmp")]


def test_an_unwritable_plots_directory_changes_no_file(result, tmp_path: Path):
    """Issue 15: calibrate with an unwritable plots_directory wrote the calibration file and moved the
    previous one to .bak, then answered success: false. Now nothing is written or moved."""
    output = tmp_path / "calibration.yaml"
    output.write_text("previous")
    (tmp_path / "calibration.yaml.bak").write_text("older")
    (tmp_path / "a_file").write_text("not a directory")
    before = _files(tmp_path)
    with pytest.raises(OSError):
        write_outputs(result, output, tmp_path / "a_file" / "plots")
    assert _files(tmp_path) == before


def test_an_unwritable_calibration_file_leaves_no_figure(result, tmp_path: Path):
    (tmp_path / "a_file").write_text("not a directory")
    with pytest.raises(OSError):
        write_outputs(result, tmp_path / "a_file" / "calibration.yaml", tmp_path / "plots")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]  # the plots directory removed too


def test_the_command_with_unwritable_plots_changes_no_file(tmp_path: Path, capsys):
    dataset = tmp_path / "dataset.yaml"
    save_dataset(_dataset(), dataset)
    output = tmp_path / "calibration.yaml"
    output.write_text("previous")
    (tmp_path / "a_file").write_text("not a directory")
    before = _files(tmp_path)
    arguments = [str(dataset), "-o", str(output), "--plots", str(tmp_path / "a_file"), "--no-leave-one-out"]
    assert calibrate_command.main(arguments) == EXIT_REFUSED
    assert "a_file" in capsys.readouterr().err
    assert _files(tmp_path) == before


# --- capture plausibility ----------------------------------------------------------------------------

LOW = EUROBOT_BEACON_MAP.xy.min(axis=0) - TABLE_MARGIN_M
HIGH = EUROBOT_BEACON_MAP.xy.max(axis=0) + TABLE_MARGIN_M


def test_the_issue_capture_pose_is_refused():
    reason = capture_pose_problem(1e6, -1e6, 100.0, EUROBOT_BEACON_MAP)
    assert "outside the beacons' table" in reason
    assert "beyond one turn" in capture_pose_problem(1.5, 1.0, 100.0, EUROBOT_BEACON_MAP)
    assert "not finite" in capture_pose_problem(math.nan, 1.0, 0.0, EUROBOT_BEACON_MAP)


@settings(max_examples=2000, deadline=None)
@given(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.floats(allow_nan=True, allow_infinity=True, width=64),
)
def test_a_capture_pose_is_accepted_exactly_inside_the_beacons_table(x, y, theta):
    inside = (
        all(map(math.isfinite, (x, y, theta)))
        and LOW[0] <= x <= HIGH[0]
        and LOW[1] <= y <= HIGH[1]
        and abs(theta) <= 2 * math.pi
    )
    assert (capture_pose_problem(x, y, theta, EUROBOT_BEACON_MAP) == "") == inside


@settings(max_examples=500, deadline=None)
@given(st.floats(0.0, 3.0), st.floats(0.0, 2.0), st.floats(-math.pi, 2 * math.pi))
def test_every_pose_on_the_eurobot_table_is_plausible(x, y, theta):
    assert capture_pose_problem(x, y, theta, EUROBOT_BEACON_MAP) == ""
