"""Beacon coordinates as EKF states (with a fourth beacon the map is overdetermined).

The thesis measures the beacons' coordinates by hand (chapter 7 calibrates them with the turret offset
from 48 reference poses). With three beacons fixed, the map frame is defined and a further beacon's
coordinates are observable from a moving robot's bearings and odometry (beams_thesis.observability: to
0.2 mm of a 1 cm prior in 60 s; docs/self_calibration.md). The states are the correction (dx, dy) (m)
of each listed beacon's configured coordinates, zero-mean with `prior_sigma_m`; the bearing model
(`bearing_ekf.bearing_measurement`, the EKF of thesis fig. 8.1) then sees the beacon at the configured
position plus its correction. Freeing a beacon when fewer than three others stay fixed would leave the
frame itself (two translations, one rotation) unobservable: refused.
"""

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from beams_common.parameters import ParameterSpec

# the map frame needs three fixed beacons (its two translations and its rotation)
MIN_FIXED_BEACONS = 3
COORDINATES = 2


@dataclass(frozen=True)
class BeaconStates:
    """The corrections (dx, dy) (m) of the coordinates of `beacon_ids`, in the map frame."""

    beacon_ids: tuple[int, ...]
    prior_sigma_m: float = 0.05

    def __post_init__(self) -> None:
        ids = tuple(int(i) for i in self.beacon_ids)
        if not ids or len(set(ids)) != len(ids):
            raise ValueError(f"estimated beacons: need distinct ids, got {list(self.beacon_ids)}")
        if not (np.isfinite(self.prior_sigma_m) and self.prior_sigma_m > 0.0):
            raise ValueError(f"beacon coordinate prior sigma must be > 0, got {self.prior_sigma_m}")
        object.__setattr__(self, "beacon_ids", ids)

    @property
    def size(self) -> int:
        return COORDINATES * len(self.beacon_ids)

    @property
    def prior_mean(self) -> np.ndarray:
        return np.zeros(self.size)

    @property
    def prior_covariance(self) -> np.ndarray:
        return self.prior_sigma_m**2 * np.eye(self.size)

    def offset_of(self, beacon_id: int) -> int | None:
        """Index of the beacon's dx within the block (dy follows), None for a fixed beacon."""
        return COORDINATES * self.beacon_ids.index(beacon_id) if beacon_id in self.beacon_ids else None

    def problem(self, map_ids: Iterable[int]) -> str | None:
        """Why these states cannot run with a map of `map_ids`, or None."""
        map_ids = tuple(map_ids)
        unknown = [i for i in self.beacon_ids if i not in map_ids]
        if unknown:
            return f"estimated_beacons {unknown} not in the beacon map {list(map_ids)}"
        fixed = len(map_ids) - len(self.beacon_ids)
        if fixed < MIN_FIXED_BEACONS:
            return (
                f"estimated_beacons {list(self.beacon_ids)} leave {fixed} of the {len(map_ids)} beacons "
                f"fixed: the map frame needs {MIN_FIXED_BEACONS} (else its translation and rotation are "
                "unobservable)"
            )
        return None


BEACON_STATE_PARAMETERS = (
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
)


def parse_beacon_ids(text: str) -> tuple[int, ...]:
    """The ids of a comma- or space-separated list ('' -> ()); ValueError naming the parameter."""
    try:
        return tuple(int(token) for token in text.replace(",", " ").split())
    except ValueError:
        raise ValueError(f"estimated_beacons: need comma-separated beacon ids, got {text!r}") from None


def beacon_states_of(values: dict) -> BeaconStates | None:
    """The states of ekf_node's parameter values; None when estimated_beacons is empty (the default)."""
    ids = parse_beacon_ids(str(values.get("estimated_beacons", BEACON_STATE_PARAMETERS[0].default)))
    if not ids:
        return None
    sigma_m = float(values.get("estimated_beacon_sigma_m", BEACON_STATE_PARAMETERS[1].default))
    return BeaconStates(ids, sigma_m)
