"""Beacon coordinates as EKF states (with a fourth beacon the map is overdetermined).

The thesis measures the beacons' coordinates by hand (chapter 7 calibrates them with the turret offset
from 48 reference poses). With three beacons fixed, the map frame is defined and a further beacon's
coordinates are observable from a moving robot's bearings and odometry (to 0.2 mm of a 1 cm prior in
60 s: docs/self_calibration.md, test/scenario/test_self_calibration_observability.py). The states are
the correction (dx, dy) (m) of each listed beacon's configured coordinates, zero-mean with
`prior_sigma_m`; the bearing model (`bearing_ekf.bearing_measurement`, the EKF of thesis fig. 8.1) then
sees the beacon at the configured position plus its correction. Freeing a beacon when fewer than three
others stay fixed would leave the frame itself (two translations, one rotation) unobservable: refused.
"""

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from beams_common.config.parameters import ParameterSpec, ParameterTable
from beams_ekf.state_blocks import BeaconsXy, BearingPart, Sighting, StateBlock

# the map frame needs three fixed beacons (its two translations and its rotation)
MIN_FIXED_BEACONS = 3
COORDINATES = 2

BEACON_STATE_SPECS = ParameterTable(
    "ekf_node",
    (
        ParameterSpec(
            "estimated_beacons",
            "",
            "Ids of the beacons whose coordinates the EKF learns while driving, comma-separated (e.g. '4'); "
            "at least 3 beacons must stay fixed (they define the map frame); written by ~/save_calibration. "
            "Empty (default): every beacon's coordinates are taken as exact.",
        ),
        ParameterSpec(
            "estimated_beacon_sigma_m",
            0.05,
            "Prior standard deviation (m) of each coordinate of an estimated beacon (estimated_beacons).",
            minimum=1e-4,
            maximum=1.0,
        ),
    ),
)


@dataclass(frozen=True)
class BeaconStates(StateBlock):
    """The corrections (dx, dy) (m) of the coordinates of `beacon_ids`, in the map frame."""

    beacon_ids: tuple[int, ...]
    prior_sigma_m: float = BEACON_STATE_SPECS.default("estimated_beacon_sigma_m")

    def __post_init__(self) -> None:
        ids = tuple(int(i) for i in self.beacon_ids)
        if not ids or len(set(ids)) != len(ids):
            raise ValueError(f"estimated beacons: need distinct ids, got {list(self.beacon_ids)}")
        object.__setattr__(self, "beacon_ids", ids)

    @property
    def size(self) -> int:
        return COORDINATES * len(self.beacon_ids)

    @property
    def prior_covariance(self) -> np.ndarray:
        return self.prior_sigma_m**2 * np.eye(self.size)

    def _block(self, beacon_id: int) -> slice | None:
        """The beacon's (dx, dy) in the block, None for a fixed beacon."""
        k = self.beacon_ids.index(beacon_id) if beacon_id in self.beacon_ids else None
        return None if k is None else slice(COORDINATES * k, COORDINATES * (k + 1))

    def problem(self, beacon_ids: Iterable[int]) -> str | None:
        map_ids = [int(i) for i in beacon_ids]
        unknown = [i for i in self.beacon_ids if i not in map_ids]
        if unknown:
            return f"estimated_beacons {unknown} not in the beacon map {map_ids}"
        fixed = len(map_ids) - len(self.beacon_ids)
        if fixed < MIN_FIXED_BEACONS:
            return (
                f"estimated_beacons {list(self.beacon_ids)} leave {fixed} of the {len(map_ids)} beacons "
                f"fixed: the map frame needs {MIN_FIXED_BEACONS} (else its translation and rotation are "
                "unobservable)"
            )
        return None

    def stale(self, old_xy: BeaconsXy, new_xy: BeaconsXy) -> list:
        """A moved beacon's: the corrections learnt were relative to its old coordinates."""
        moved = [self._block(i) for i in self.beacon_ids if old_xy.get(i) != new_xy[i]]
        return [k for block in moved for k in range(block.start, block.stop)]

    def shift(self, mean: np.ndarray, sighting: Sighting) -> None:
        block = self._block(sighting.beacon_id)
        if block is not None:
            xy, (dx, dy) = sighting.beacon_xy, mean[block]
            sighting.beacon_xy = (xy[0] + float(dx), xy[1] + float(dy))

    def bearing(self, mean: np.ndarray, sighting: Sighting, memory: Any) -> BearingPart:
        """The bearing depends on the beacon minus the turret: dh/d(beacon) = -dh/d(robot position)."""
        jacobian, block = np.zeros(self.size), self._block(sighting.beacon_id)
        if block is not None:
            jacobian[block] = -sighting.d_pose[:2]
        return BearingPart(jacobian)

    def learnt(self, mean: np.ndarray, covariance: np.ndarray, beacons_xy: BeaconsXy) -> dict[int, tuple]:
        """{id: ((x, y) learnt (m), its 2x2 covariance)} of the states (mean, covariance) and the
        configured map."""
        blocks = [(i, self._block(i)) for i in self.beacon_ids]
        return {
            i: (tuple(float(v) for v in np.add(beacons_xy[i], mean[b])), covariance[b, b].copy())
            for i, b in blocks
        }


def parse_beacon_ids(text: str) -> tuple[int, ...]:
    """The ids of a comma- or space-separated list ('' -> ()); ValueError naming the parameter."""
    try:
        return tuple(int(token) for token in text.replace(",", " ").split())
    except ValueError:
        raise ValueError(f"estimated_beacons: need comma-separated beacon ids, got {text!r}") from None


def beacon_states_of(values: Mapping[str, Any]) -> BeaconStates | None:
    """The states of ekf_node's validated parameter values; None when estimated_beacons is empty."""
    ids = parse_beacon_ids(str(values["estimated_beacons"]))
    return BeaconStates(ids, float(values["estimated_beacon_sigma_m"])) if ids else None
