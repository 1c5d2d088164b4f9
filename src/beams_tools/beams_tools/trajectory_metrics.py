"""How well a run positioned the robot, for `replay_bag` (offline) and `beams_bringup.demo` (live) alike. A
track is a (k, 5) array of rows (segment, stamp s, x m, y m, theta rad) in the map frame; `segment` counts the
time jumps (a bag played in a loop), rows of different segments are never compared."""

from __future__ import annotations

import math
import pathlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.pose2d import Pose2D, compose, inverse

# Plot style of each track name (matplotlib format strings); other names get a thin line.
STYLES = {"truth": "k-", "odometry": "C1--", "ToTal": "C0.", "EKF": "C2-"}


@dataclass
class Track:
    """Poses of one source: rows (segment, stamp ns, x, y, theta), in the order they came."""

    rows: list[tuple[int, int, float, float, float]] = field(default_factory=list)

    def add(self, segment: int, stamp_ns: int, pose: Pose2D) -> None:
        self.rows.append((segment, stamp_ns, float(pose[0]), float(pose[1]), float(pose[2])))

    def array(self) -> np.ndarray:
        """(k, 5) float array: segment, stamp (s), x, y, theta."""
        return np.array([(s, t * 1e-9, x, y, th) for s, t, x, y, th in self.rows], dtype=float).reshape(-1, 5)

    def by_stamp(self) -> dict[int, Pose2D]:
        """Pose by stamp (ns); with a bag loop, the last pass wins."""
        return {t: (x, y, th) for _, t, x, y, th in self.rows}


@dataclass
class RunTracks:
    """The tracks of one run: the simulator's truth, wheel odometry (odom frame), ToTal's accepted poses
    and the EKF's estimates."""

    truth: Track = field(default_factory=Track)
    odometry: Track = field(default_factory=Track)
    total: Track = field(default_factory=Track)
    ekf: Track = field(default_factory=Track)

    def in_map(self, odometry_anchor: str) -> dict[str, np.ndarray]:
        """Every track in the map frame by name (truth, odometry, ToTal, EKF), the odometry placed at the
        first pose of the track named odometry_anchor ("truth" or "ekf", see `odometry_in_map`)."""
        anchor = getattr(self, odometry_anchor).array()
        return {
            "truth": self.truth.array(),
            "odometry": odometry_in_map(self.odometry.array(), anchor),
            "ToTal": self.total.array(),
            "EKF": self.ekf.array(),
        }


def errors_against_truth(track: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and |heading| (rad) errors of a track against the truth of the same segment,
    interpolated at the track's stamps (rows outside the truth's span are left out)."""
    positions, headings = [], []
    for segment in np.unique(track[:, 0]):
        rows, reference = track[track[:, 0] == segment], truth[truth[:, 0] == segment]
        if len(reference) < 2:
            continue
        rows = rows[(rows[:, 1] >= reference[0, 1]) & (rows[:, 1] <= reference[-1, 1])]
        x = np.interp(rows[:, 1], reference[:, 1], reference[:, 2])
        y = np.interp(rows[:, 1], reference[:, 1], reference[:, 3])
        heading = np.interp(rows[:, 1], reference[:, 1], np.unwrap(reference[:, 4]))
        positions.append(np.hypot(rows[:, 2] - x, rows[:, 3] - y))
        headings.append(np.abs(wrap_to_pi(rows[:, 4] - heading)))
    if not positions:
        return np.empty(0), np.empty(0)
    return np.concatenate(positions), np.concatenate(headings)


def odometry_in_map(odometry: np.ndarray, anchor: np.ndarray) -> np.ndarray:
    """The odometry track (odom frame) placed in the map frame at the anchor track's first pose of each
    segment, from that instant on: dead reckoning from there, what the robot would believe without BeAMS
    (the anchor is the truth in the demo, the EKF's first estimate in the replay)."""
    placed = []
    for segment in np.unique(anchor[:, 0]):
        rows = odometry[odometry[:, 0] == segment]
        if len(rows) == 0:
            continue
        start = anchor[anchor[:, 0] == segment][0]
        reference = rows[np.argmin(np.abs(rows[:, 1] - start[1]))]
        # map <- odom: the anchor pose composed with the inverse of the odometry pose at the same instant
        map_from_odom = compose(tuple(start[2:5]), inverse(tuple(reference[2:5])))
        later = rows[rows[:, 1] >= reference[1]]
        placed += [(segment, t, *compose(map_from_odom, (x, y, th))) for _, t, x, y, th in later]
    return np.array(placed, dtype=float).reshape(-1, 5)


def rms(values: np.ndarray) -> float:
    """Root mean square (NaN for no value)."""
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else math.nan


def rms_table(tracks: Iterable[tuple[str, np.ndarray]], truth: np.ndarray) -> list[str]:
    """Markdown rows: each named track's pose count and RMS position (mm) and heading (deg) errors."""
    lines = ["| source | poses | RMS position (mm) | RMS heading (deg) |", "|---|---|---|---|"]
    for name, track in tracks:
        position, heading = errors_against_truth(track, truth)
        lines.append(
            f"| {name} | {len(position)} | {1000 * rms(position):.1f} | {math.degrees(rms(heading)):.3f} |"
        )
    return lines


def plot_trajectories(tracks: Mapping[str, np.ndarray], path: pathlib.Path, title: str) -> None:
    """The tracks (name -> rows) on the 3 m x 2 m table, in the map frame, to a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(9, 6.5))
    for name, rows in tracks.items():
        if len(rows):
            axes.plot(rows[:, 2], rows[:, 3], STYLES.get(name, "-"), label=name, markersize=2, linewidth=1)
    axes.add_patch(plt.Rectangle((0, 0), 3, 2, fill=False, color="grey"))
    axes.set_aspect("equal")
    axes.set_xlabel("x (m, map)")
    axes.set_ylabel("y (m, map)")
    axes.set_title(title)
    axes.legend(loc="upper right")
    figure.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(figure)
