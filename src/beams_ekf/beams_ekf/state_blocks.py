"""The EKF's state as a list of blocks: the pose of thesis fig. 8.1, then what self-calibration learns.

A block is one module: a frozen dataclass deriving from `StateBlock` that gives its size, its prior, its
process noise and its correction of an odometry increment (if any), what it does to a bearing's geometry
(`shift`: the turret, the beacon), its part of the bearing's Jacobian and of the predicted bearing
(`bearing`), whether a reset keeps it (`learnt`), and its ParameterSpecs with the block of their values;
its one line in `settings.FilterSettings`, `field(**block_field(...))`, registers it. `bearing_ekf.BearingEkf`
lays the blocks out one after the other and slices the state by their sizes (docs/state_blocks.md).
"""

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, NamedTuple

import numpy as np

from beams_common.parameters import ParameterSpec, ParameterTable
from beams_common.pose2d import Pose2D


@dataclass
class Sighting:
    """One bearing as the blocks see it, h(x) = atan2(yb - ys, xb - xs) - theta - ptheta.

    The blocks' `shift` may move the turret (`lever`, its pose in the robot frame, see
    `bearing_ekf.turret_pose`) and the beacon (`beacon_xy`, map frame); then `d_pose` holds
    dh/d(x, y, theta) of the robot, dh/d(x, y) being dh/d(turret) = -dh/d(beacon) in the map frame.
    `window_rad`: the angular window of a bearing no calibration corrected (0: corrected); a block that
    sees an error it cannot model yet sets `pose_only` (the bearing then teaches no learnt block).
    """

    beacon_id: int
    pose: Pose2D
    lever: Pose2D
    beacon_xy: tuple[float, float]
    window_rad: float = 0.0
    d_pose: np.ndarray = field(default_factory=lambda: np.zeros(3))
    pose_only: bool = False


class BearingPart(NamedTuple):
    """A block's part of a bearing: dh/d(its states) (size,), what it adds to h (None: nothing), and
    whether the bearing updates its states (False: Schmidt-Kalman, their gain rows zero)."""

    jacobian: np.ndarray
    shift: float | None = None
    learns: bool = True


class StateBlock:
    """A part of the EKF state; each hook's default does nothing (a constant that no bearing sees)."""

    size = 0
    # a re-initialisation keeps it, with its covariance (what the bearings taught of the odometry and
    # the sensor); the pose's is not
    learnt = True

    @property
    def prior_mean(self) -> np.ndarray:
        return np.zeros(self.size)

    @property
    def prior_covariance(self) -> np.ndarray:
        raise NotImplementedError

    def new_memory(self) -> Any:
        """What the block remembers of the bearings besides its states (per filter, forgotten with what
        the states learnt)."""
        return None

    def problem(self, beacon_ids: Iterable[int]) -> str | None:
        """Why the block cannot run with a beacon map of these ids, or None."""
        return None

    def stale(
        self, old_xy: Mapping[int, tuple[float, float]], new_xy: Mapping[int, tuple[float, float]]
    ) -> list:
        """Indices (in the block) of the states a new beacon map puts back to their prior."""
        return []

    def corrected_increment(self, increment: Pose2D, mean: np.ndarray) -> tuple[Pose2D, np.ndarray | None]:
        """The odometry increment (robot frame) corrected by the block, and the correction's 3 x size
        Jacobian (None: the block does not touch it)."""
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


def typed_value(spec: ParameterSpec, value: Any) -> Any:
    """A validated parameter value as its spec's type (a list as a tuple: a frozen dataclass's field)."""
    return (
        tuple(spec.item_type(v) for v in value) if isinstance(spec.default, list) else spec.item_type(value)
    )
