"""Error maps of a beacon layout (thesis section 6.4.1, figure 6.5), and the `error_map` command: the std of
the position (eq. 6.25) and orientation (eq. 6.26) errors of ToTal under Gaussian bearing noise at every point
of a grid, with the mean 1/|D|, drawn or predicted from the pose covariance.

error_map --beacons "-0.062,-0.062;-0.062,2.062;3.062,1.0" --area 0,3,0,2 --sigma-deg 0.1 -o map.png"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from beams_common.config.command_line import command
from beams_common.geometry.angles import wrap_to_pi
from beams_triangulation.pose_covariance import distance_error_std_m, pose_covariance_many
from beams_triangulation.total import MIN_ABS_D_M2, expected_bearings, triangulate_many

EUROBOT_LAYOUT = "-0.062,-0.062;-0.062,2.062;3.062,1.0"
#: Rows per vectorised ToTal call in the Monte Carlo (bounded memory: about 100 MB of temporaries).
_ROWS_PER_CALL = 500_000


@dataclass(frozen=True)
class ErrorMaps:
    """Per-point maps (same shape as the grid): position error std (m), heading error std (rad), 1/|D|."""

    x: np.ndarray
    y: np.ndarray
    position_std_m: np.ndarray
    heading_std_rad: np.ndarray
    inverse_abs_d: np.ndarray


def grid(area: Sequence[float], step_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres of a regular grid over area (x_min, x_max, y_min, y_max), step in m."""
    x_min, x_max, y_min, y_max = area
    xs = np.arange(x_min + step_m / 2, x_max, step_m)
    ys = np.arange(y_min + step_m / 2, y_max, step_m)
    return np.meshgrid(xs, ys)


def monte_carlo_maps(
    beacons_xy: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    sigma_rad: float,
    draws: int,
    rng: np.random.Generator,
    heading_rad: float = 0.0,
) -> ErrorMaps:
    """Section 6.4.1: `draws` noisy bearing triplets per point (sigma_rad on each), std of eq. 6.25-6.26.

    The robot orientation is fixed (the thesis uses 0 deg); 1/|D| is averaged over the draws.
    """
    points = np.column_stack([x.ravel(), y.ravel()])
    exact = expected_bearings(beacons_xy, (points[:, 0], points[:, 1], np.full(len(points), heading_rad)))
    position_std, heading_std, mean_inverse_d = (np.empty(len(points)) for _ in range(3))
    per_call = max(1, _ROWS_PER_CALL // draws)
    for start in range(0, len(points), per_call):
        rows = slice(start, start + per_call)
        count = len(points[rows])
        noisy = exact[rows, None, :] + rng.normal(0.0, sigma_rad, (count, draws, 3))
        batch = triangulate_many(beacons_xy, noisy.reshape(-1, 3))
        distance = np.hypot(
            batch.x.reshape(count, draws) - points[rows, 0:1],
            batch.y.reshape(count, draws) - points[rows, 1:2],
        )
        heading_error = wrap_to_pi(batch.heading.reshape(count, draws) - heading_rad)
        position_std[rows] = distance.std(axis=1)
        heading_std[rows] = heading_error.std(axis=1)
        # A no-fix draw counts as the largest 1/|D| ToTal can report (capped so the sum cannot overflow).
        capped = np.minimum(batch.inverse_abs_d, 1.0 / MIN_ABS_D_M2)
        mean_inverse_d[rows] = capped.reshape(count, draws).mean(axis=1)
    shape = x.shape
    return ErrorMaps(
        x, y, position_std.reshape(shape), heading_std.reshape(shape), mean_inverse_d.reshape(shape)
    )


def predicted_maps(
    beacons_xy: np.ndarray, x: np.ndarray, y: np.ndarray, sigma_rad: float, heading_rad: float = 0.0
) -> ErrorMaps:
    """The same maps from the propagated covariance (first order, no drawing), and the exact 1/|D|."""
    heading = np.full(x.size, heading_rad)
    covariance = pose_covariance_many(beacons_xy, (x.ravel(), y.ravel(), heading), [sigma_rad**2] * 3)
    fixes = triangulate_many(beacons_xy, expected_bearings(beacons_xy, (x.ravel(), y.ravel(), heading)))
    return ErrorMaps(
        x,
        y,
        distance_error_std_m(covariance).reshape(x.shape),
        np.sqrt(covariance[:, 2, 2]).reshape(x.shape),
        fixes.inverse_abs_d.reshape(x.shape),
    )


def draw_maps(beacons_xy: np.ndarray, columns: Sequence[tuple[str, ErrorMaps]], path: str) -> None:
    """Figure 6.5: one column per noise level, rows position std, orientation std, 1/|D|; log colour
    scale with the largest 1% of each map clipped (the errors are unbounded at the critical circle), and
    the smallest 1% too (1/|D| vanishes on the beacon lines)."""
    import matplotlib

    matplotlib.use("Agg")  # files only: the command must work without a display
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    rows = (
        ("position error std (m)", "position_std_m", 1.0),
        ("orientation error std (deg)", "heading_std_rad", 180.0 / np.pi),
        ("1/|D| (1/m^2)", "inverse_abs_d", 1.0),
    )
    figure, axes = plt.subplots(3, len(columns), figsize=(4.2 * len(columns), 10.5), squeeze=False)
    for column, (title, maps) in enumerate(columns):
        for row, (label, field, scale) in enumerate(rows):
            axis = axes[row, column]
            values = getattr(maps, field) * scale
            finite = values[np.isfinite(values) & (values > 0)]
            low, high = np.percentile(finite, [1.0, 99.0]) if finite.size else (1e-9, 1.0)
            image = axis.pcolormesh(
                maps.x,
                maps.y,
                np.clip(values, low, high),
                shading="nearest",
                norm=LogNorm(vmin=max(low, high * 1e-9), vmax=high),
                cmap="viridis",
            )
            axis.plot(
                beacons_xy[:, 0], beacons_xy[:, 1], "o", markerfacecolor="white", markeredgecolor="black"
            )
            axis.set_aspect("equal")
            axis.set_title(f"{title}\n{label}", fontsize=9)
            figure.colorbar(image, ax=axis, fraction=0.046, pad=0.04)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _parse_beacons(text: str) -> np.ndarray:
    try:
        beacons = np.array([[float(v) for v in pair.split(",")] for pair in text.split(";")])
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"beacons must read 'x1,y1;x2,y2;x3,y3': {error}") from None
    if beacons.shape != (3, 2) or not np.all(np.isfinite(beacons)):
        raise argparse.ArgumentTypeError(f"beacons must be three finite 'x,y' pairs, got {text!r}")
    return beacons


def _parse_floats(count: int):
    def parse(text: str) -> list[float]:
        values = [float(v) for v in text.split(",")]
        if len(values) != count:
            raise argparse.ArgumentTypeError(f"expected {count} comma-separated numbers, got {text!r}")
        return values

    return parse


@command("error_map")
def main(argv: Sequence[str] | None = None) -> int:
    """Command line: draw figure 6.5 for a beacon layout to a PNG."""
    parser = argparse.ArgumentParser(prog="error_map", description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--beacons",
        type=_parse_beacons,
        default=_parse_beacons(EUROBOT_LAYOUT),
        help="three beacons 'x1,y1;x2,y2;x3,y3' in m (default: the Eurobot layout)",
    )
    parser.add_argument(
        "--area",
        type=_parse_floats(4),
        default=[-0.5, 3.5, -0.5, 2.5],
        help="x_min,x_max,y_min,y_max in m, e.g. --area=-2,2,-2,2 (default: the table and a 0.5 m border)",
    )
    parser.add_argument(
        "--step", type=float, default=0.02, help="grid step in m (default 0.02, the thesis's)"
    )
    parser.add_argument(
        "--sigma-deg",
        type=_parse_floats(1),
        action="append",
        help="bearing noise std in deg; repeat for several columns (default 0.01, 0.1 and 1)",
    )
    parser.add_argument(
        "--draws",
        type=int,
        default=0,
        help="Monte Carlo draws per point as in the thesis (1000 there); 0 (default) "
        "predicts the maps from the covariance instead, in a fraction of a second",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("-o", "--output", default="error_map.png", help="PNG file to write")
    args = parser.parse_args(argv)
    if not (args.step > 0 and args.draws >= 0):
        parser.error("--step must be positive and --draws non-negative")
    sigmas = [s[0] for s in args.sigma_deg] if args.sigma_deg else [0.01, 0.1, 1.0]
    x, y = grid(args.area, args.step)
    rng = np.random.default_rng(args.seed)
    columns = []
    for sigma_deg in sigmas:
        sigma = np.deg2rad(sigma_deg)
        if args.draws:
            maps = monte_carlo_maps(args.beacons, x, y, sigma, args.draws, rng)
        else:
            maps = predicted_maps(args.beacons, x, y, sigma)
        columns.append((f"sigma = {sigma_deg:g} deg", maps))
    draw_maps(args.beacons, columns, args.output)
    print(
        f"wrote {args.output}: {x.size} points, sigma {sigmas} deg, "
        f"{'Monte Carlo ' + str(args.draws) + ' draws' if args.draws else 'predicted from the covariance'}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
