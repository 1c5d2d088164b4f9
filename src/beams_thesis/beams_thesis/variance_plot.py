"""Draw the bearing variance against the angular window for a code list (figures 4.9-4.13) to PNG.

Theory (closed form for the family, exact enumeration otherwise) as a line, the section-4.3 simulation
(one beacon, fixed window, a turret period coprime with the code) as circles, both normalised by the
bound p0 phi0^2 / 6 against phi_W / phi0: the tool to design or extend a code family.

    ros2 run beams_thesis variance_plot --codes 101111111110 111110111110 --output variance.png
    ros2 run beams_thesis variance_plot --family 5 --period-ticks 998400   # the real, non-coprime period
"""

import argparse
import math
import pathlib
import sys
from collections.abc import Sequence

import numpy as np

from beams_common.config.command_line import command
from beams_driver.codes import BIT_TIME_S, BeaconCode, code_family, codes_from_strings
from beams_driver.variance import VarianceModel
from beams_sim.sensor_sim import fixed_window_bearing_errors

TICK_S = 100e-9
COPRIME_PERIOD_TICKS = 998401


def simulated_normalized_variance(
    code: BeaconCode, window_s: np.ndarray, period_ticks: int, min_burst_s: float = 0.0
) -> np.ndarray:
    """Variance / bound of the section-4.3 simulation, one turn per distinct code shift (eq. 4.82)."""
    code_ticks = round(code.duration_s / TICK_S)
    turns = code_ticks // math.gcd(code_ticks, period_ticks)
    errors, detected = fixed_window_bearing_errors(
        code, window_s, period_ticks * TICK_S, turns, tick_s=TICK_S, min_burst_s=min_burst_s
    )
    count = np.maximum(detected.sum(axis=1), 1)
    mean = errors.sum(axis=1) / count
    variance = (errors**2).sum(axis=1) / count - mean**2
    return np.where(detected.any(axis=1), variance, np.nan) / code.variance_bound_s2


def plot_variance(
    codes: Sequence[BeaconCode],
    output: pathlib.Path,
    *,
    max_window_over_phi0: float = 13.0,
    period_ticks: int = COPRIME_PERIOD_TICKS,
    min_burst_fraction: float = 0.0,
) -> pathlib.Path:
    """Write one panel per code (theory line, simulation circles) to a PNG file; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    model = VarianceModel(codes, min_burst_fraction=min_burst_fraction, turret_speed_rad_s=1.0)
    figure, axes = plt.subplots(len(codes), 1, figsize=(8, 2.4 * len(codes)), sharex=True, squeeze=False)
    for axis, code in zip(axes[:, 0], codes, strict=True):
        phi0_s = min(code.gap_bits) * code.bit_time_s
        min_burst_s = min_burst_fraction * phi0_s
        bound = model.bound_rad2(code)  # with omega = 1 rad/s, angles are times
        x_theory = np.linspace(0.0, max_window_over_phi0, 2000)
        axis.plot(x_theory, model.variance(code, x_theory * phi0_s) / bound, "-", label="theory")
        x_sim = np.round(np.linspace(0.02, max_window_over_phi0, 131) * phi0_s / TICK_S) * TICK_S / phi0_s
        simulated = simulated_normalized_variance(code, x_sim * phi0_s, period_ticks, min_burst_s)
        axis.plot(
            x_sim,
            simulated * code.variance_bound_s2 / bound,
            "o",
            markersize=3,
            fillstyle="none",
            label="simulation",
        )
        axis.set_ylabel("var / bound")
        axis.set_title(f"code {code.code_id}: {code}  (turret period {period_ticks} x 100 ns)", fontsize=9)
        axis.grid(True, alpha=0.3)
        axis.legend(loc="lower right", fontsize=8)
    axes[-1, 0].set_xlabel("angular window phi_W / phi0")
    figure.tight_layout()
    output = pathlib.Path(output)
    figure.savefig(output, dpi=110)
    plt.close(figure)
    return output


@command("variance_plot")
def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point (console script `variance_plot`)."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--codes", nargs="+", metavar="BITS", help="custom codes as 0/1 strings")
    source.add_argument(
        "--family", type=int, default=5, metavar="NC", help="the family C_1..C_Nc (default 5)"
    )
    parser.add_argument("--bit-time-us", type=float, default=BIT_TIME_S * 1e6, help="bit time (us)")
    parser.add_argument("--max-window", type=float, default=13.0, help="largest phi_W / phi0 (default 13)")
    parser.add_argument(
        "--period-ticks", type=int, default=COPRIME_PERIOD_TICKS, help="turret period (100 ns ticks)"
    )
    parser.add_argument(
        "--min-burst-fraction", type=float, default=0.0, help="undetected burst / T0 (5.6: 0.56)"
    )
    parser.add_argument("--output", type=pathlib.Path, default=pathlib.Path("variance.png"), help="PNG file")
    options = parser.parse_args(argv)
    bit_time_s = options.bit_time_us * 1e-6
    codes = (
        codes_from_strings(options.codes, bit_time_s)
        if options.codes
        else code_family(options.family, bit_time_s)
    )
    path = plot_variance(
        codes,
        options.output,
        max_window_over_phi0=options.max_window,
        period_ticks=options.period_ticks,
        min_burst_fraction=options.min_burst_fraction,
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
