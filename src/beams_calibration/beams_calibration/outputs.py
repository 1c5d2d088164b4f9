"""The outputs of a calibration (the file and two PNG figures) written all or nothing, each staged beside its
target (`calibration_file.StagedFile`) and swapped in only when all are written, and the check that decides
whether to write them; the node and the `calibrate` command both go through here.
"""

import contextlib
import math
import os
from pathlib import Path

from beams_calibration.calibrate import CalibrationResult, configuration_rms
from beams_common.calibration.calibration_file import StagedFile, calibration_text

# Tolerances on "worse" (m, rad): the fit stops at a relative criterion, a tie is not a regression.
RMS_TOLERANCE_M = 1e-5
RMS_TOLERANCE_RAD = 1e-5


def rms_regression(result: CalibrationResult, eta_m_per_rad: float) -> str:
    """Why a calibration must not be applied ('' when it may): it makes the position (eq. 7.10), orientation
    (eq. 7.11) or err_RMS (eq. 7.12) worse than none, which on a sound dataset all drop (table 7.5)."""
    before, after = result.before, result.after
    criterion = (
        configuration_rms(result.errors_before, eta_m_per_rad),
        configuration_rms(result.errors_after, eta_m_per_rad),
    )
    worse = []
    if after.position_rms_m > before.position_rms_m + RMS_TOLERANCE_M:
        worse.append(f"position {before.position_rms_m * 1e3:.2f} -> {after.position_rms_m * 1e3:.2f} mm")
    if after.orientation_rms_rad > before.orientation_rms_rad + RMS_TOLERANCE_RAD:
        worse.append(
            f"orientation {math.degrees(before.orientation_rms_rad):.3f} -> "
            f"{math.degrees(after.orientation_rms_rad):.3f} deg"
        )
    if criterion[1] > criterion[0] + RMS_TOLERANCE_M:
        worse.append(f"err_RMS (eq. 7.12) {criterion[0] * 1e3:.2f} -> {criterion[1] * 1e3:.2f} mm")
    if not worse:
        return ""
    return (
        f"the calibration makes the RMS worse ({', '.join(worse)}): check the dataset's poses "
        "(list_configurations)"
    )


def write_outputs(
    result: CalibrationResult, calibration_file: Path | None, plots_directory: Path | None
) -> list[Path]:
    """Write the calibration file and the figures (None: not written), all or nothing: the paths written,
    or OSError with every target, `.bak` and directory as it was."""
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
