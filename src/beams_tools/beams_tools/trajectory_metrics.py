"""How well a run positioned the robot, for `replay_bag` (offline) and `beams_bringup.demo` (live) alike. A
track is a (k, 5) array of rows (segment, stamp s, x m, y m, theta rad) in the map frame; `segment` counts the
time jumps (a bag played in a loop), rows of different segments are never compared. The EKF's status and
protection level over time (`IntegrityTrack`) go beside it: the run's figure (`plot_run`) draws the error
against the truth, the 3-sigma envelope and the protection level over a band coloured by the status."""

from __future__ import annotations

import itertools
import math
import pathlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.pose2d import Pose2D, compose, inverse
from beams_common.status.protection_level import major_sigma_m

# Plot style of each track name (matplotlib format strings); other names get a thin line.
STYLES = {"truth": "k-", "odometry": "C1--", "ToTal": "C0.", "EKF": "C2-"}
# The status band's colour of each status (beams_common.status.health.Status values).
STATUS_COLOURS = {"tracking": "tab:green", "degraded": "tab:orange", "lost": "tab:red", "waiting": "0.75"}


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
class IntegrityTrack:
    """The EKF's status and horizontal protection level as it judged them: rows (segment, stamp ns, level
    m, status)."""

    rows: list[tuple[int, int, float, str]] = field(default_factory=list)
    # the level above which the status is degraded ("unavailable for navigation")
    alert_limit_m: float = math.nan

    def add(self, segment: int, stamp_ns: int, horizontal_level_m: float, status: str) -> None:
        self.rows.append((segment, stamp_ns, float(horizontal_level_m), str(status)))


@dataclass
class RunTracks:
    """The tracks of one run: the simulator's truth, wheel odometry (odom frame), ToTal's accepted poses
    and the EKF's estimates with their (x, y, yaw) covariances and its status."""

    truth: Track = field(default_factory=Track)
    odometry: Track = field(default_factory=Track)
    total: Track = field(default_factory=Track)
    ekf: Track = field(default_factory=Track)
    ekf_covariances: list[np.ndarray] = field(default_factory=list)
    ekf_integrity: IntegrityTrack = field(default_factory=IntegrityTrack)

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
    _, position, heading = _aligned_errors(track, truth)
    return position, heading


def _aligned_errors(track: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(index of the track's row, position error m, |heading error| rad) for each row inside the span of
    its segment's truth."""
    indices, positions, headings = [], [], []
    for segment in np.unique(track[:, 0]):
        reference = truth[truth[:, 0] == segment]
        if len(reference) < 2:
            continue
        index = np.flatnonzero(track[:, 0] == segment)
        index = index[(track[index, 1] >= reference[0, 1]) & (track[index, 1] <= reference[-1, 1])]
        rows = track[index]
        x = np.interp(rows[:, 1], reference[:, 1], reference[:, 2])
        y = np.interp(rows[:, 1], reference[:, 1], reference[:, 3])
        heading = np.interp(rows[:, 1], reference[:, 1], np.unwrap(reference[:, 4]))
        indices.append(index)
        positions.append(np.hypot(rows[:, 2] - x, rows[:, 3] - y))
        headings.append(np.abs(wrap_to_pi(rows[:, 4] - heading)))
    if not positions:
        return np.empty(0, dtype=int), np.empty(0), np.empty(0)
    return np.concatenate(indices), np.concatenate(positions), np.concatenate(headings)


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


def plot_run(run: RunTracks, odometry_anchor: str, path: pathlib.Path, title: str) -> None:
    """The run to a PNG: its tracks on the 3 m x 2 m table (map frame, the odometry placed at the first
    pose of `odometry_anchor`, `RunTracks.in_map`) and, below, the EKF against time: its position error
    (where there is a truth), the 3-sigma of its covariance's major axis and its horizontal protection
    level, over a band coloured by its status: what a user looks at first when a match went wrong."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tracks = run.in_map(odometry_anchor)
    figure, (table, timeline) = plt.subplots(2, 1, figsize=(9, 10), height_ratios=(2, 1))
    for name, rows in tracks.items():
        if len(rows):
            table.plot(rows[:, 2], rows[:, 3], STYLES.get(name, "-"), label=name, markersize=2, linewidth=1)
    table.add_patch(plt.Rectangle((0, 0), 3, 2, fill=False, color="grey"))
    table.set(aspect="equal", xlabel="x (m, map)", ylabel="y (m, map)", title=title)
    table.legend(loc="upper right")
    _draw_integrity(timeline, run, tracks)
    figure.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(figure)


def status_spans(times_s: np.ndarray, statuses: list[str]) -> list[tuple[float, float, str]]:
    """(from s, to s, status) for each run of equal statuses; a run ends where the next begins, the last
    at the last instant."""
    if not statuses:
        return []
    changes = [0, *(i for i in range(1, len(statuses)) if statuses[i] != statuses[i - 1]), len(statuses)]
    return [
        (float(times_s[begin]), float(times_s[min(end, len(statuses) - 1)]), statuses[begin])
        for begin, end in itertools.pairwise(changes)
    ]


def _draw_integrity(axes, run: RunTracks, tracks: Mapping[str, np.ndarray]) -> None:
    """The EKF's error, 3-sigma and protection level (mm) against the time since its first estimate, on
    its status band (the first segment)."""
    ekf = tracks["EKF"]
    if len(run.ekf_covariances) == len(ekf):  # the envelope's column beside the rows
        ekf = np.column_stack([ekf, major_sigma_m(np.array(run.ekf_covariances).reshape(-1, 3, 3))])
    ekf = ekf[ekf[:, 0] == ekf[0, 0]] if len(ekf) else ekf  # a bag played in a loop repeats its times
    judged = np.array([row[:3] for row in run.ekf_integrity.rows], dtype=float).reshape(-1, 3)
    first = judged[:, 0] == judged[0, 0] if len(judged) else np.zeros(0, dtype=bool)
    statuses = [row[3] for row, kept in zip(run.ekf_integrity.rows, first, strict=True) if kept]
    judged = judged[first]
    start_s = ekf[0, 1] if len(ekf) else (judged[0, 1] * 1e-9 if len(judged) else 0.0)
    index, position_m, _ = _aligned_errors(ekf[:, :5], tracks["truth"])
    axes.plot(ekf[index, 1] - start_s, 1000 * position_m, "k-", linewidth=0.8, label="error")
    if ekf.shape[1] == 6:
        axes.plot(ekf[:, 1] - start_s, 3000 * ekf[:, 5], "C0--", linewidth=0.8, label="3-sigma")
    times_s = judged[:, 1] * 1e-9 - start_s
    axes.step(times_s, 1000 * judged[:, 2], "C3-", where="post", linewidth=0.8, label="protection level")
    if math.isfinite(run.ekf_integrity.alert_limit_m):
        axes.axhline(1000 * run.ekf_integrity.alert_limit_m, color="C3", linestyle=":", label="alert limit")
    for begin_s, end_s, status in status_spans(times_s, statuses):
        axes.axvspan(begin_s, end_s, color=STATUS_COLOURS.get(status, "white"), alpha=0.25, linewidth=0)
    for status, colour in STATUS_COLOURS.items():  # the legend's entries
        axes.axvspan(0, 0, color=colour, alpha=0.25, label=status)
    axes.set(yscale="log", xlabel="time since the EKF's first estimate (s)", ylabel="EKF horizontal (mm)")
    axes.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=5, fontsize="small")
