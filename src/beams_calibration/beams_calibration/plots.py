"""PNG figures of a calibration: figure 7.13 (positions around each reference) and the two correction
functions (figures 7.11, 7.12); matplotlib imported only to draw, so the node runs without it.
"""

import math
import os
from pathlib import Path

import numpy as np

from beams_calibration.calibrate import CalibrationResult, position_groups
from beams_common.calibration.calibration_file import StagedFile

# Figure 7.13: each panel is 15 mm wide with a graduation every 2 mm.
PANEL_HALF_SIDE_M = 0.0075


def _new_figure(width_in: float, height_in: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width_in, height_in), dpi=100)
    FigureCanvasAgg(figure)
    return figure


def positions_figure(result: CalibrationResult):
    """Figure 7.13: around each reference position (cross), the computed positions before (stars)
    and after (circles) calibration; panels 15 mm square, 2 mm graduations, mm offsets."""
    groups = position_groups(result.poses)
    columns = min(4, len(groups))
    rows = math.ceil(len(groups) / columns)
    figure = _new_figure(3.0 * columns, 3.0 * rows + 0.6)
    ticks_mm = np.arange(-6, 7, 2)
    for index, members in enumerate(groups):
        axes = figure.add_subplot(rows, columns, index + 1)
        reference = result.poses[members[0], :2]
        for errors, marker, label in (
            (result.errors_before, "*", "before"),
            (result.errors_after, "o", "after"),
        ):
            # error = truth - estimate, so the estimate sits at -error from the reference.
            offsets_mm = -errors[members, :2] / 1e-3
            axes.plot(
                offsets_mm[:, 0], offsets_mm[:, 1], marker, linestyle="none", fillstyle="none", label=label
            )
        axes.plot([0.0], [0.0], "k+", markersize=12)
        limit = PANEL_HALF_SIDE_M / 1e-3
        axes.set(xlim=(-limit, limit), ylim=(-limit, limit), xticks=ticks_mm, yticks=ticks_mm, aspect="equal")
        axes.grid(True, linewidth=0.3)
        axes.set_title(f"({reference[0]:.3f}, {reference[1]:.3f}) m", fontsize=9)
        axes.tick_params(labelsize=7)
        if index == 0:
            axes.legend(fontsize=7, loc="upper right")
    figure.suptitle(
        f"Positions around each reference (mm): RMS {result.before.position_rms_m * 1e3:.2f} mm before, "
        f"{result.after.position_rms_m * 1e3:.2f} mm after calibration"
    )
    figure.tight_layout()
    return figure


def corrections_figure(result: CalibrationResult):
    """Figures 7.11 and 7.12: the power-bias correction against the window and the rotation-bias
    correction against the turret angle (deg), with the dataset's windows and bearings marked."""
    figure = _new_figure(10.0, 4.0)
    power_axes = figure.add_subplot(1, 2, 1)
    windows = result.windows_rad.ravel()
    grid = np.linspace(windows.min(), windows.max(), 200)
    power_axes.plot(np.degrees(grid), np.degrees(result.correction.power_bias(grid)))
    power_axes.plot(np.degrees(windows), np.degrees(result.correction.power_bias(windows)), "|", color="grey")
    a, b, c, d = result.correction.power_bias_coefficients
    power_axes.set_title(f"power bias\n(a={a:.2f}, b={b:.2f}, c={c:.2f}, d={d:.3f})", fontsize=9)
    power_axes.set(xlabel="angular window (deg)", ylabel="correction (deg)")
    power_axes.grid(True, linewidth=0.3)
    rotation_axes = figure.add_subplot(1, 2, 2)
    angles = np.linspace(-np.pi, np.pi, 361)
    rotation_axes.plot(np.degrees(angles), np.degrees(result.correction.rotation_bias(angles)))
    bearings = result.bearings_rad.ravel()
    rotation_axes.plot(
        np.degrees(bearings), np.degrees(result.correction.rotation_bias(bearings)), "|", color="grey"
    )
    coefficients = ", ".join(
        f"{name}={value:.2e}"
        for name, value in zip("ABCD", result.correction.rotation_bias_coefficients, strict=True)
    )
    rotation_axes.set_title(f"rotation bias\n({coefficients})", fontsize=9)
    rotation_axes.set(xlabel="turret angle (deg)", ylabel="correction (deg)", xlim=(-180, 180))
    rotation_axes.grid(True, linewidth=0.3)
    figure.tight_layout()
    return figure


# The figures of a calibration and their file names in the plots directory.
FIGURES = (
    ("calibration_positions.png", positions_figure),
    ("calibration_corrections.png", corrections_figure),
)


def stage_plots(result: CalibrationResult, directory: str | os.PathLike) -> list[StagedFile]:
    """Both figures drawn and written beside their targets in `directory`, not yet in place (see
    `calibration_file.StagedFile`); the directory must exist."""
    staged: list[StagedFile] = []
    try:
        for name, draw in FIGURES:
            figure = draw(result)
            target = Path(directory) / name
            staged.append(StagedFile(target, lambda handle, f=figure: f.savefig(handle, format="png")))
    except BaseException:
        for item in staged:
            item.discard()
        raise
    return staged
