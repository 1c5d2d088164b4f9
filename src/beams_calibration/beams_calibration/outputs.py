"""The outputs of a calibration written all or nothing, and the checks that decide whether to write them.

A calibration writes up to three files (the calibration file and the two PNG figures). Each is written
in full beside its target first (`calibration_file.StagedFile`); only when every one is written are
they swapped in, the previous calibration file kept as `.bak`. A failure before that (an unwritable
plots directory, a full disk) leaves every file, and the `.bak`, as it was. The calibration node and
the offline `calibrate` command both write through `write_outputs` and refuse through `rms_regression`.
"""

import contextlib
import os
from pathlib import Path

from beams_calibration.calibrate import CalibrationResult, configuration_rms
from beams_driver.calibration_file import StagedFile, calibration_text

# Tolerance on "worse" (m): the fit stops at a relative criterion, a tie is not a regression.
RMS_TOLERANCE_M = 1e-6


def rms_regression(result: CalibrationResult, eta_m_per_rad: float) -> str:
    """Why a calibration must not be applied: it makes the position RMS (eq. 7.10) or the configuration
    RMS err_RMS that Algorithm 7.1 minimises (eq. 7.12) worse than no calibration; '' when it does not.

    A calibration can only lower err_RMS on its own dataset (no calibration is one of the models it
    tries), so a rise means the dataset holds a wrong configuration (a pose typed wrong, a robot moved).
    """
    before = configuration_rms(result.errors_before, eta_m_per_rad)
    after = configuration_rms(result.errors_after, eta_m_per_rad)
    position_before, position_after = result.before.position_rms_m, result.after.position_rms_m
    if after > before + RMS_TOLERANCE_M or position_after > position_before + RMS_TOLERANCE_M:
        return (
            f"the calibration makes the RMS worse: position {position_before * 1e3:.2f} -> "
            f"{position_after * 1e3:.2f} mm, err_RMS (eq. 7.12) {before * 1e3:.2f} -> {after * 1e3:.2f} mm; "
            "check the dataset's poses (list_configurations), or force it"
        )
    return ""


def write_outputs(
    result: CalibrationResult, calibration_file: Path | None, plots_directory: Path | None
) -> list[Path]:
    """Write the calibration file and the figures (either may be None: not written), all or nothing.

    Returns the paths written. Raises OSError (every target, directory and `.bak` left as it was, and
    the directories this call created removed) when one of them cannot be written.
    """
    from beams_calibration.plots import stage_plots  # matplotlib only when figures are asked for

    created: list[Path] = []
    staged: list[StagedFile] = []
    try:
        if plots_directory is not None:
            created += _make_directories(Path(plots_directory))
            staged += stage_plots(result, plots_directory)
        if calibration_file is not None:
            text = calibration_text(result.to_sensor_calibration())
            created += _make_directories(Path(calibration_file).parent)
            staged.append(StagedFile(calibration_file, lambda handle: handle.write(text.encode("utf-8"))))
    except BaseException:
        for item in staged:
            item.discard()
        for directory in reversed(created):
            with contextlib.suppress(OSError):
                directory.rmdir()
        raise
    for item in staged:
        item.commit(keep_backup=calibration_file is not None and item.target == Path(calibration_file))
    return [item.target for item in staged]


def _make_directories(directory: Path) -> list[Path]:
    """Create `directory` and its missing parents; the ones created, outermost first."""
    missing = [path for path in (directory, *directory.parents) if not path.exists()]
    os.makedirs(directory, exist_ok=True)
    return list(reversed(missing))
