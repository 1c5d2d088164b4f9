"""The gates on a ToTal pose (1/|D|, thesis 6.3.5, eq. 6.27, and the propagated position std: both met on 94%
of the Eurobot table at 0.1 deg, `error_map`; 1/|D| holds when the variances are wrong), and the triplet to
trust among more than three beacons. A rejected pose keeps its numbers with the reason."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from beams_triangulation.parameters import TRIANGULATION_PARAMETERS
from beams_triangulation.pose_covariance import pose_covariance, pose_covariance_many, position_std_m
from beams_triangulation.total import ToTalFix, triangulate_many

REASON_NO_TRIPLET = "no beacon triplet gives a fix: robot on the critical circumference of every triplet"
REASON_NOT_COMPENSATED = "odometry does not cover the revolution: bearings not motion-compensated"


@dataclass(frozen=True)
class GateConfig:
    """The two acceptance gates: 1/|D| (m^-2) and sqrt(var x + var y) (m)."""

    max_inverse_abs_d: float = TRIANGULATION_PARAMETERS.default("max_inverse_abs_d")
    max_position_std_m: float = TRIANGULATION_PARAMETERS.default("max_position_std_m")

    def __post_init__(self) -> None:
        TRIANGULATION_PARAMETERS.require(**vars(self))  # its fields are the two gate parameters


@dataclass(slots=True)
class PoseEstimate:
    """A ToTal pose with its covariance and the gate's verdict (not frozen: that costs 2 us, a fifth)."""

    x: float
    y: float
    heading: float
    covariance: np.ndarray
    inverse_abs_d: float
    beacon_ids: tuple[int, int, int]
    accepted: bool
    reason: str

    @property
    def position_std_m(self) -> float:
        """sqrt(var x + var y) (m), the quantity the position gate compares."""
        return math.sqrt(self.covariance[0, 0] + self.covariance[1, 1])


@dataclass(frozen=True)
class NoPose:
    """Why one revolution gave no pose at all (too few beacons, bad input, robot on the critical circle);
    bad_input: the message itself was wrong (unknown or duplicated id, NaN, negative variance)."""

    reason: str
    bad_input: bool = False


def gate(inverse_abs_d: float, covariance: np.ndarray, config: GateConfig) -> tuple[bool, str]:
    """(accepted, reason): the 1/|D| gate first (the thesis's criterion), then the propagated std."""
    if not inverse_abs_d < config.max_inverse_abs_d:
        return False, f"1/|D| = {inverse_abs_d:.3g} m^-2 above the gate {config.max_inverse_abs_d:g}"
    # Python floats: a covariance near the largest float sums to inf (refused below), not a numpy warning
    std = math.sqrt(float(covariance[0, 0]) + float(covariance[1, 1]))
    if not std < config.max_position_std_m:
        return False, f"position std {std:.3g} m above the gate {config.max_position_std_m:g} m"
    return True, ""


def best_triplet(
    beacons_xy: np.ndarray, bearings_rad: np.ndarray, variances_rad2: np.ndarray, by: str = "covariance"
) -> tuple[int, int, int] | None:
    """Indices of the triplet to trust among more than three beacons, or None when none gives a fix: every
    triplet solved at once, by="covariance" (default) the smallest propagated position std, by="inverse_abs_d"
    the largest |D| (eq. 6.27). On the Eurobot table with a fourth beacon at (3.062, -0.062) and 0.1 deg noise
    the first measures better (RMS 8.3 mm against 10.4 mm): 1/|D| also vanishes on the line through two
    beacons, where the error does not."""
    triplets = np.array(list(itertools.combinations(range(len(bearings_rad)), 3)))
    batch = triangulate_many(beacons_xy[triplets], bearings_rad[triplets])
    if not batch.ok.any():
        return None
    if by == "inverse_abs_d":
        score = batch.inverse_abs_d
    else:
        covariance = pose_covariance_many(
            beacons_xy[triplets], (batch.x, batch.y, batch.heading), variances_rad2[triplets]
        )
        score = np.where(batch.ok, np.nan_to_num(position_std_m(covariance), nan=np.inf), np.inf)
    return tuple(int(i) for i in triplets[int(np.argmin(score))])


def gated_estimate(
    fix: ToTalFix,
    beacons_xy: np.ndarray,
    variances_rad2: Sequence[float],
    beacon_ids: tuple[int, int, int],
    config: GateConfig,
    turret_offset_m: Sequence[float] = (0.0, 0.0),
) -> PoseEstimate:
    """Covariance and gate decision for one ToTal fix (the scalar path the benchmark times)."""
    covariance = pose_covariance(beacons_xy, (fix.x, fix.y, fix.heading), variances_rad2, turret_offset_m)
    accepted, reason = gate(fix.inverse_abs_d, covariance, config)
    return PoseEstimate(
        fix.x, fix.y, fix.heading, covariance, fix.inverse_abs_d, beacon_ids, accepted, reason
    )
