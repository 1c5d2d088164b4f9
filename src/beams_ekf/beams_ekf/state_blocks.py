"""The EKF's state as a list of blocks: the pose of thesis fig. 8.1, then what self-calibration learns.

A block is one module (a `StateBlock`, its ParameterSpecs, the block of their values), registered by its
one line in `settings.FilterSettings`; `bearing_ekf.BearingEkf` lays the blocks out one after the other
and slices the state by their sizes (docs/state_blocks.md).
"""

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np

from beams_common.config.parameters import ParameterTable
from beams_common.geometry.pose2d import Pose2D

BeaconsXy = Mapping[int, tuple[float, float]]


@dataclass(slots=True)
class Sighting:
    """One bearing as the blocks see it, h(x) = atan2(yb - ys, xb - xs) - theta - ptheta: the turret
    at `lever` in the robot frame (`bearing_ekf.turret_pose`), `d_pose` = dh/d(x, y, theta) once h is
    evaluated (dh/d(x, y) = dh/d(turret) = -dh/d(beacon)), `window_rad` > 0 for a bearing no calibration
    corrected; `pose_only`: it carries an error no block models yet (it then teaches no learnt block)."""

    beacon_id: int
    pose: Pose2D
    lever: Pose2D
    beacon_xy: tuple[float, float]
    window_rad: float = 0.0
    d_pose: np.ndarray | None = None
    pose_only: bool = False


class BearingPart(NamedTuple):
    """A block's part of a bearing: dh/d(its states) (size,), what it adds to h (None: nothing), and
    whether the bearing updates its states (False: Schmidt-Kalman, their gain rows zero)."""

    jacobian: np.ndarray
    shift: float | None = None
    learns: bool = True


class StateBlock:
    """A part of the EKF state (its `prior_covariance` a property); each hook's default does nothing (a
    constant that no bearing sees)."""

    size = 0
    learnt = True  # a re-initialisation keeps its states and covariance (the pose's: not)

    @property
    def prior_mean(self) -> np.ndarray:
        return np.zeros(self.size)

    def new_memory(self) -> Any:
        """What it remembers of the bearings besides its states (per filter, forgotten with them)."""
        return None

    def problem(self, beacon_ids: Iterable[int]) -> str | None:
        """Why the block cannot run with a beacon map of these ids, or None."""
        return None

    def stale(self, old_xy: BeaconsXy, new_xy: BeaconsXy) -> list:
        """Indices (in the block) of the states a new beacon map puts back to their prior."""
        return []

    def corrected_increment(self, increment: Pose2D, mean: np.ndarray) -> tuple[Pose2D, np.ndarray | None]:
        """The odometry increment it corrects and the 3 x size Jacobian (None: untouched)."""
        return increment, None

    def process_noise(self, increment: Pose2D, mean: np.ndarray) -> np.ndarray | None:
        """The size x size noise one odometry increment adds (None: a constant)."""
        return None

    def shift(self, mean: np.ndarray, sighting: Sighting) -> None:
        """Move the sighting's turret or beacon before h(x) is evaluated."""

    def bearing(self, mean: np.ndarray, sighting: Sighting, memory: Any) -> BearingPart:
        """The block's part of the bearing once h(x) is evaluated (`sighting.d_pose` set)."""
        return BearingPart(np.zeros(self.size))


StatesOf = Callable[[Mapping[str, Any]], StateBlock | None]


def block_field(specs: ParameterTable, states_of: StatesOf) -> dict[str, Any]:
    """The keywords of a settings `field` holding a block (None: off), registered with its ParameterSpecs
    and the block of their validated values; its default is the block of the specs' defaults."""
    return {"default_factory": lambda: states_of(specs.defaults()), "metadata": {"block": (specs, states_of)}}


def registered_blocks(settings_class: type) -> list[tuple[str, ParameterTable, StatesOf]]:
    """(field name, specs, states_of) of each `block_field` of a settings dataclass, in state order."""
    return [(f.name, *f.metadata["block"]) for f in fields(settings_class) if "block" in f.metadata]
