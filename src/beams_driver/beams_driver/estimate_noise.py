"""estimate_noise: a sensor's natural variance from bags of a still robot; the published variances checked.

Record the robot standing still for about 60 s at each of a few poses spread over the table (near and far
beacons: the natural variance grows with the window, thesis section 5.5), one bag of /beams/bearings per pose,
then

estimate_noise pose1_bag pose2_bag pose3_bag -o noise.yaml --plot noise.png

It prints, per pose and beacon, the observed spread against the published and the fitted variance (ratio, 95%
chi-square band, verdict against 0.8-1.25), and writes the fit as a driver parameter file and a plot. Bad
input is one line and exit status 2. The codes and the receiver are the driver's (`--driver-params`, default
its defaults)."""

import argparse
import math
import pathlib
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from beams_common.calibration.calibration_file import atomic_write_text
from beams_common.config.command_line import command, reason
from beams_common.config.parameters import ParameterTable, load_parameter_file
from beams_driver.edge_source import named_sources, source_kind
from beams_driver.noise_estimation import (
    MAX_DRIFT_RAD,
    MAX_STD_RAD,
    MIN_SAMPLES,
    SLOPE_Z_THRESHOLD,
    BeaconSpread,
    NaturalVarianceFit,
    NoiseEstimationError,
    StaticRecording,
    VarianceCheck,
    beacon_spread,
    fit_natural_variance,
    parameter_file_text,
    predicted_variance_rad2,
    recordings_from_bearings,
    variance_check,
)
from beams_driver.parameters import DRIVER_PARAMETERS, codes_of, variance_model_of
from beams_driver.variance import VarianceModel

BEARINGS_TOPIC = "/beams/bearings"
BEARINGS_TYPE = "beams_msgs/msg/BeaconBearingArray"
DEG = math.radians(1.0)


@dataclass(frozen=True)
class NoiseReport:
    """The estimation over every recording: spreads, the fit, the checks before and after it."""

    spreads: list[BeaconSpread]
    fit: NaturalVarianceFit
    published: list[VarianceCheck]
    fitted: list[VarianceCheck]


def driver_models(values: Mapping[str, Any]) -> tuple[VarianceModel, Any]:
    """(the exact variance model of the driver's codes and receiver, a function of a fit giving the
    model the driver publishes with once configured with it)."""
    codes = codes_of(values)
    kind = source_kind(values["source"])
    own = {spec.name for spec in kind.parameters}
    source_values = ParameterTable("driver_node", kind.parameters, kind.together).validate(
        {k: v for k, v in values.items() if k in own}
    )
    receiver = kind.receiver(source_values, codes)
    exact = {**values, "variance_mode": "exact"}

    def configured(fit: NaturalVarianceFit) -> VarianceModel:
        return variance_model_of({**exact, **fit.parameters()}, codes, receiver)

    return variance_model_of(exact, codes, receiver), configured


def driver_values(path: pathlib.Path | None) -> dict[str, Any]:
    """The driver's parameters (a parameter file's, validated with the driver's and its source's tables)."""
    if path is None:
        return DRIVER_PARAMETERS.defaults()
    return load_parameter_file(path, DRIVER_PARAMETERS + _all_source_parameters())


def _all_source_parameters() -> ParameterTable:
    """Every named source's parameters, so that a driver file for any of them reads."""
    specs: dict[str, Any] = {}
    for name in named_sources():
        for spec in source_kind(name).parameters:
            specs.setdefault(spec.name, spec)
    return ParameterTable("driver_node", tuple(specs.values()))


def read_bearings(path: pathlib.Path, topic: str = BEARINGS_TOPIC) -> list[tuple[int, float, float, float]]:
    """(beacon id, bearing, variance, window) of every bearing on the topic, in stamp order, from a
    rosbag2 bag (MCAP or sqlite3; the message definitions recorded in the bag)."""
    from rosbags.highlevel import AnyReader

    wanted = "/" + topic.lstrip("/")
    rows: list[tuple[float, int, float, float, float]] = []
    try:
        with AnyReader([path]) as reader:
            connections = [c for c in reader.connections if c.topic == wanted]
            if not connections or any(c.msgtype != BEARINGS_TYPE for c in connections):
                found = sorted(f"{c.topic} ({c.msgtype})" for c in reader.connections)
                raise NoiseEstimationError(f"{path}: no {wanted} of type {BEARINGS_TYPE} (found: {found})")
            for connection, _, raw in reader.messages(connections=connections):
                for b in reader.deserialize(raw, connection.msgtype).bearings:
                    stamp = b.header.stamp.sec + 1e-9 * b.header.stamp.nanosec
                    rows.append((stamp, b.beacon_id, b.bearing, b.variance, b.angular_window))
    except NoiseEstimationError:
        raise
    except Exception as error:  # rosbags and its storages raise many types
        raise NoiseEstimationError(f"{path}: not a readable rosbag2 bag ({reason(error)})") from None
    rows.sort(key=lambda row: row[0])
    return [row[1:] for row in rows]


def estimate(
    recordings: Sequence[StaticRecording],
    values: Mapping[str, Any],
    *,
    max_std_rad: float,
    max_drift_rad: float,
    slope_z_threshold: float,
) -> NoiseReport:
    """Spreads, the natural variance's fit and the checks of the published and the fitted variances."""
    spreads = [beacon_spread(r, max_std_rad, max_drift_rad) for r in recordings]
    exact, configured = driver_models(values)
    fit = fit_natural_variance(spreads, exact, slope_z_threshold)
    model = configured(fit)
    return NoiseReport(
        spreads=spreads,
        fit=fit,
        published=[variance_check(s, s.mean_published_variance_rad2) for s in spreads],
        fitted=[variance_check(s, predicted_variance_rad2(model, s)) for s in spreads],
    )


def _check_text(check: VarianceCheck) -> str:
    return f"{check.ratio:5.2f} [{check.band[0]:.2f}, {check.band[1]:.2f}] {check.verdict:<11}"


def report_table(report: NoiseReport) -> str:
    """Per pose and beacon: samples, window, observed and published std, ratios and verdicts; the fit."""
    header = (
        f"{'recording':<20} {'beacon':>6} {'samples':>7} {'window deg':>10} {'observed std deg':>16} "
        f"{'published std deg':>17}  {'published ratio [95%]  verdict':<31}  fitted ratio [95%]  verdict"
    )
    lines = [header]
    for spread, published, fitted in zip(report.spreads, report.published, report.fitted, strict=True):
        lines.append(
            f"{spread.label[-20:]:<20} {spread.beacon_id:>6} {spread.samples:>7} "
            f"{spread.mean_window_rad / DEG:>10.2f} {math.sqrt(spread.observed_variance_rad2) / DEG:>16.4f} "
            f"{math.sqrt(spread.mean_published_variance_rad2) / DEG:>17.4f}  {_check_text(published):<31}  "
            f"{_check_text(fitted)}"
        )
    lines.append(fit_summary(report.fit))
    return "\n".join(lines)


def fit_summary(fit: NaturalVarianceFit) -> str:
    """One line: the natural variance, and its slope in the window when the data shows one."""
    text = (
        f"natural variance {fit.natural_variance_rad2:.3e} rad^2 (+- {fit.natural_standard_error_rad2:.1e}, "
        f"std {math.sqrt(fit.natural_variance_rad2) / DEG:.4f} deg) at window "
        f"{fit.reference_window_rad / DEG:.2f} deg"
    )
    if fit.window_dependent:
        return text + (
            f", slope {fit.slope_rad2_per_rad:.3e} rad^2/rad (+- {fit.slope_standard_error:.1e}, "
            f"{fit.slope_z:.1f} sigma): window-dependent"
        )
    return text + f"; no significant slope in the window ({fit.slope_z:.1f} sigma): constant"


def plot_report(report: NoiseReport, path: pathlib.Path) -> None:
    """Natural variance estimates against the window with the fit; observed against published variance."""
    import matplotlib

    matplotlib.use("Agg")
    import numpy as np
    from matplotlib import pyplot as plt

    fit = report.fit
    windows_deg = fit.windows_rad / DEG
    figure, (left, right) = plt.subplots(1, 2, figsize=(12, 4.8))
    left.errorbar(
        windows_deg,
        fit.estimates_rad2,
        yerr=fit.estimate_errors_rad2,
        fmt="o",
        label="s^2 - exact code variance",
    )
    grid = np.linspace(fit.windows_rad.min(), fit.windows_rad.max(), 50)
    left.plot(grid / DEG, fit.at(grid), "k-", label="fitted natural variance")
    left.set_xlabel("angular window (deg)")
    left.set_ylabel("natural variance (rad^2)")
    left.set_title("natural variance (thesis 5.5)")
    left.legend()
    ratios = [[c.ratio for c in checks] for checks in (report.published, report.fitted)]
    low = [[c.ratio - c.band[0] for c in checks] for checks in (report.published, report.fitted)]
    high = [[c.band[1] - c.ratio for c in checks] for checks in (report.published, report.fitted)]
    positions = np.arange(len(report.spreads))
    for k, name in enumerate(("published", "with the fit")):
        right.errorbar(positions + 0.15 * k, ratios[k], yerr=[low[k], high[k]], fmt="o", label=name)
    right.axhspan(0.8, 1.25, color="green", alpha=0.15, label="0.8-1.25")
    right.set_xticks(
        positions, [f"{s.label[-10:]}\nbeacon {s.beacon_id}" for s in report.spreads], fontsize=7
    )
    right.set_ylabel("observed / predicted variance")
    right.set_title("variance check (95% chi-square band)")
    right.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="estimate_noise", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("bags", nargs="+", type=pathlib.Path, help="rosbag2 bags, one still pose each")
    parser.add_argument("-o", "--output", type=pathlib.Path, help="driver parameter file to write (YAML)")
    parser.add_argument("--plot", type=pathlib.Path, help="PNG figure to write")
    parser.add_argument("--driver-params", type=pathlib.Path, help="the driver's parameter file (codes)")
    parser.add_argument("--topic", default=BEARINGS_TOPIC, help=f"bearings topic (default {BEARINGS_TOPIC})")
    parser.add_argument(
        "--min-samples", type=int, default=MIN_SAMPLES, help="fewest bearings of a beacon used"
    )
    parser.add_argument(
        "--max-std-deg", type=float, default=MAX_STD_RAD / DEG, help="spread of a still robot (deg)"
    )
    parser.add_argument(
        "--max-drift-deg", type=float, default=MAX_DRIFT_RAD / DEG, help="drift of a still robot (deg)"
    )
    parser.add_argument(
        "--slope-z", type=float, default=SLOPE_Z_THRESHOLD, help="significance of a window slope (sigma)"
    )
    return parser


@command("estimate_noise")
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `estimate_noise` console script; returns the exit status."""
    options = _parser().parse_args(argv)
    values = driver_values(options.driver_params)
    recordings = [
        recording
        for bag in options.bags
        for recording in recordings_from_bearings(
            str(bag), read_bearings(bag, options.topic), options.min_samples
        )
    ]
    report = estimate(
        recordings,
        values,
        max_std_rad=options.max_std_deg * DEG,
        max_drift_rad=options.max_drift_deg * DEG,
        slope_z_threshold=options.slope_z,
    )
    print(report_table(report))
    if options.output is not None:
        comment = [f"estimate_noise {' '.join(str(b) for b in options.bags)}", fit_summary(report.fit)]
        atomic_write_text(options.output, parameter_file_text(report.fit, comment), keep_backup=False)
        print(f"wrote {options.output} (driver_node --ros-args --params-file {options.output})")
    if options.plot is not None:
        plot_report(report, options.plot)
        print(f"wrote {options.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
