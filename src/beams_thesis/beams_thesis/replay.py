"""Offline replay of odometry and bearings through a `Localiser`, in arrival order, against ground truth: the
EKF's accuracy and consistency figures. Every input goes through the Localiser's intakes as ekf_node's do."""

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from itertools import groupby

import numpy as np
from scipy.stats import chi2

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.bearing import Bearing
from beams_common.geometry.pose2d import Pose2D
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake
from beams_common.status.health import Status
from beams_ekf.ekf_health import EkfHealth
from beams_ekf.localiser import Localiser, revolution_of
from beams_ekf.parameters import EKF_PARAMETERS
from beams_thesis.synthetic import BearingEvent

# the two-sided 95 % chi-square band (3 dof) of one consistent NEES sample
NEES_BAND = (float(chi2.ppf(0.025, df=3)), float(chi2.ppf(0.975, df=3)))


@dataclass(frozen=True)
class PoseEvent:
    """A ToTal fix as triangulation_node publishes it: arrives at `arrival_s`, refers to `stamp_s`."""

    arrival_s: float
    stamp_s: float
    pose: Pose2D
    covariance: np.ndarray


@dataclass
class ReplayResult:
    """The estimate after each revolution's bearings, with the truth at the same instant."""

    times_s: np.ndarray
    estimates: np.ndarray  # (k, 3)
    covariances: np.ndarray  # (k, 3, 3)
    truths: np.ndarray  # (k, 3)
    counts: dict[str, int] = field(default_factory=dict)
    # (k, 2) horizontal (m) and heading (rad) protection levels at the default integrity risk
    protection_levels: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    # (k,) True where ekf_node's status (its defaults, the arrivals as its receiving clock) says tracking
    tracking: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def errors(self) -> np.ndarray:
        """(k, 3) estimate - truth, heading wrapped."""
        errors = self.estimates - self.truths
        errors[:, 2] = [wrap_to_pi(float(a)) for a in errors[:, 2]]
        return errors

    def nees(self) -> np.ndarray:
        """(k,) normalised estimation error squared, e' P^-1 e."""
        errors = self.errors()
        return np.einsum("ki,kij,kj->k", errors, np.linalg.inv(self.covariances), errors)


@dataclass(frozen=True)
class Accuracy:
    """RMS position and heading errors and the NEES consistency of a replay."""

    rms_position_m: float
    rms_heading_rad: float
    max_position_m: float
    nees_mean: float
    # share of the instants whose NEES lies inside the two-sided 95% chi-square (3 dof) band
    nees_in_band: float
    samples: int


def replay(
    localiser: Localiser,
    odometry_times_s: np.ndarray,
    odometry_poses: np.ndarray,
    bearings: Iterable[BearingEvent],
    truth_at: Callable[[float], Pose2D],
    initial_pose: Pose2D,
    initial_covariance: np.ndarray,
    fixes: Iterable[PoseEvent] = (),
) -> ReplayResult:
    """Feed odometry (arriving at its stamp), bearings and ToTal's fixes (arriving at `arrival_s`; at
    one instant the bearings first, as one revolution) in arrival order, after an operator's
    `initial_pose` at the first odometry stamp. Each estimate gets ekf_node's protection level and status
    (`EkfHealth.judge`, as ekf_node's, the arrival times as the receiving clock)."""
    start = planar_pose_intake(
        PoseSource.OPERATOR, float(odometry_times_s[0]), initial_pose, initial_covariance
    )
    localiser.on_pose(start)
    events = [(b.arrival_s, 0, b) for b in bearings] + [(f.arrival_s, 1, f) for f in fixes]
    events.sort(key=lambda event: event[:2])
    by_arrival = [(a, [event[2] for event in group]) for a, group in groupby(events, key=lambda e: e[0])]
    times, estimates, covariances, truths, levels, tracking = [], [], [], [], [], []
    health = EkfHealth(EKF_PARAMETERS.defaults(), float(odometry_times_s[0]))
    k = 0
    for arrival_s, arrived in by_arrival:
        while k < len(odometry_times_s) and odometry_times_s[k] <= arrival_s:
            localiser.on_odometry(float(odometry_times_s[k]), tuple(odometry_poses[k]))
            health.on_odometry(float(odometry_times_s[k]))
            k += 1
        revolution = [
            Bearing(
                b.stamp_s, b.beacon_id, b.bearing_rad, b.variance_rad2, b.angular_window_rad, b.calibrated
            )
            for b in arrived
            if isinstance(b, BearingEvent)
        ]
        if revolution:
            health.on_bearings(arrival_s)
            localiser.on_bearings(revolution_of(localiser, revolution))
        for fix in (f for f in arrived if isinstance(f, PoseEvent)):  # as ekf_node takes beams/pose
            localiser.on_pose(planar_pose_intake(PoseSource.TOTAL, fix.stamp_s, fix.pose, fix.covariance))
        estimate = localiser.estimate()
        if estimate is not None:
            times.append(estimate.stamp_s)
            estimates.append(estimate.pose)
            covariances.append(estimate.covariance)
            truths.append(truth_at(estimate.stamp_s))
            level, _, verdict = health.judge(arrival_s, localiser, estimate)
            levels.append((level.horizontal_m, level.heading_rad))
            tracking.append(verdict.status is Status.TRACKING)
    arrays = (np.array(values) for values in (times, estimates, covariances, truths))
    counts, levels_array = dict(localiser.stats.counts), np.array(levels).reshape(-1, 2)
    return ReplayResult(*arrays, counts, levels_array, np.array(tracking, dtype=bool))


def accuracy(result: ReplayResult, settle_s: float = 1.0) -> Accuracy:
    """Figures over the instants after `settle_s` (the initial transient excluded)."""
    keep = result.times_s >= result.times_s[0] + settle_s
    errors = result.errors()[keep]
    nees = result.nees()[keep]
    low, high = NEES_BAND
    position = np.hypot(errors[:, 0], errors[:, 1])
    return Accuracy(
        rms_position_m=float(np.sqrt(np.mean(position**2))),
        rms_heading_rad=float(np.sqrt(np.mean(errors[:, 2] ** 2))),
        max_position_m=float(position.max()),
        nees_mean=float(nees.mean()),
        nees_in_band=float(np.mean((nees >= low) & (nees <= high))),
        samples=int(keep.sum()),
    )
