"""The beacon map: where each identified beacon stands in the map frame (REP-105), in metres."""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

# Beacons closer to a common line than this (m) give no usable triangle.
COLLINEARITY_TOLERANCE_M = 1e-3


@dataclass(frozen=True, eq=False)
class BeaconMap:
    """Beacon identifiers (the code index, 1..Nc) and their positions (n, 2) in the map frame."""

    ids: tuple[int, ...]
    xy: np.ndarray

    @classmethod
    def from_lists(cls, ids: Sequence[int], xs: Sequence[float], ys: Sequence[float]) -> "BeaconMap":
        """Build and validate a map from parallel lists (the form ROS parameters take)."""
        if not len(ids) == len(xs) == len(ys):
            raise ValueError(
                f"beacon map: {len(ids)} ids, {len(xs)} x and {len(ys)} y values; the three lists must match"
            )
        if len(ids) < 3:
            raise ValueError(f"beacon map: {len(ids)} beacons given, triangulation needs at least 3")
        if len(set(ids)) != len(ids):
            raise ValueError(f"beacon map: duplicated beacon ids in {list(ids)}")
        if any(int(i) < 0 for i in ids):
            raise ValueError(f"beacon map: beacon ids must be non-negative, got {list(ids)}")
        xy = np.column_stack([np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)])
        if not np.all(np.isfinite(xy)):
            raise ValueError("beacon map: beacon coordinates must be finite numbers")
        if _distance_to_best_line(xy) < COLLINEARITY_TOLERANCE_M:
            raise ValueError("beacon map: all beacons lie on one line; triangulation is impossible")
        xy.setflags(write=False)
        return cls(ids=tuple(int(i) for i in ids), xy=xy)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BeaconMap):
            return NotImplemented
        return self.ids == other.ids and np.array_equal(self.xy, other.xy)

    def __hash__(self) -> int:
        return hash((self.ids, self.xy.tobytes()))

    def __contains__(self, beacon_id: object) -> bool:
        return beacon_id in self.ids

    def position(self, beacon_id: int) -> np.ndarray:
        """Position (2,) of one beacon; KeyError for an id that is not on the map."""
        try:
            return self.xy[self.ids.index(beacon_id)]
        except ValueError:
            raise KeyError(f"beacon {beacon_id} is not on the beacon map {list(self.ids)}") from None

    def as_dict(self) -> dict[int, tuple[float, float]]:
        """{beacon id: (x, y)} with Python floats."""
        return {beacon_id: (float(x), float(y)) for beacon_id, (x, y) in zip(self.ids, self.xy, strict=True)}

    def subset(self, beacon_ids: Sequence[int]) -> np.ndarray:
        """Positions (k, 2) of the given beacons, in the given order."""
        return np.array([self.position(i) for i in beacon_ids], dtype=float).reshape(-1, 2)


def _distance_to_best_line(xy: np.ndarray) -> float:
    """Root-sum-square distance of the beacons to their least-squares line (m)."""
    centred = xy - xy.mean(axis=0)
    singular_values = np.linalg.svd(centred, compute_uv=False)
    return float(singular_values[-1]) if singular_values.size > 1 else 0.0


# The Eurobot table: 3 m x 2 m, x in [0, 3], y in [0, 2]; beacons on supports outside its border.
EUROBOT_BEACON_MAP = BeaconMap.from_lists(ids=(1, 2, 3), xs=(-0.062, -0.062, 3.062), ys=(-0.062, 2.062, 1.0))
