"""The one intake of a revolution's bearings (a beams/bearings message), shared by ToTal and the EKF: the
revolution refused whole past `validation.MAX_BEARINGS_PER_REVOLUTION` (`too_many`), then one sighting per
beacon (`validation.one_sighting_per_beacon`: REPEATED_BEACON set aside, CONFLICTING_BEACON refused), then
each bearing by `validation.bearing_problem`; kept and refused with reason and counts (docs/shape-core.md).
"""

import math
from collections import Counter
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from beams_common.geometry.bearing import Bearing, bearings_of_message
from beams_common.intake.validation import bearing_problem, one_sighting_per_beacon, revolution_size_problem


class BearingRefusal(StrEnum):
    """Why a bearing was not kept (the value is the counter's suffix: `bearings_<value>`)."""

    REPEATED_BEACON = "repeated_beacon"
    CONFLICTING_BEACON = "conflicting_beacon"
    UNKNOWN_BEACON = "unknown_beacon"
    INVALID_MEASUREMENT = "invalid_measurement"


@dataclass(frozen=True)
class RefusedBearing:
    """A bearing not kept, why (its kind) and the reason in words."""

    bearing: Bearing
    refusal: BearingRefusal
    reason: str


@dataclass(frozen=True)
class RevolutionIntake:
    """One revolution's bearings sorted out: those kept (in the given order) and those refused.

    `too_many` is the reason the revolution was refused whole (then nothing is kept or listed).
    """

    kept: list[Bearing] = field(default_factory=list)
    refused: list[RefusedBearing] = field(default_factory=list)
    too_many: str = ""

    def refused_as(self, *kinds: BearingRefusal) -> list[RefusedBearing]:
        """The refused bearings of the given kinds, in the given order."""
        return [r for r in self.refused if r.refusal in kinds]

    @property
    def conflicting_ids(self) -> list[int]:
        """The beacons seen twice at one instant, in order of appearance."""
        conflicting = self.refused_as(BearingRefusal.CONFLICTING_BEACON)
        return list(dict.fromkeys(r.bearing.beacon_id for r in conflicting))

    def revolution_refusals(self) -> list[tuple[str, str]]:
        """(diagnostic key, reason) for each kind of refusal that concerns the revolution: refused whole,
        a beacon seen twice at one instant, invalid bearings. A repeated sighting is not, nor a beacon
        not on the map (another team's beacon in view is ordinary on a Eurobot table: only counted)."""
        if self.too_many:
            return [("revolutions_too_many_bearings", self.too_many)]
        refusals = []
        if self.conflicting_ids:
            reason = (
                f"beacon(s) {self.conflicting_ids} seen twice at one instant (not physical): bearings refused"
            )
            refusals.append(("revolutions_conflicting_beacon", reason))
        invalid = self.refused_as(BearingRefusal.INVALID_MEASUREMENT)
        if invalid:
            reason = f"{len(invalid)} bearing(s) refused, the first: {invalid[0].reason}"
            refusals.append(("revolutions_with_invalid_bearings", reason))
        return refusals

    @property
    def newest_stamp_s(self) -> float:
        """The newest finite stamp of the bearings, kept or refused (nan without one): the revolution's."""
        stamps = (b.stamp_s for b in (*self.kept, *(r.bearing for r in self.refused)))
        return max((t for t in stamps if math.isfinite(t)), default=math.nan)

    def counts(self) -> Counter:
        """Refused bearings per kind, keyed `bearings_<kind>` (the diagnostic keys)."""
        return Counter(f"bearings_{r.refusal}" for r in self.refused)


def bearing_refusal(bearing: Bearing, known_ids: Collection[int]) -> RefusedBearing | None:
    """Rule 3 on one bearing (`validation.bearing_problem`): why it can never be used, or None."""
    problem = bearing_problem(
        bearing.beacon_id, bearing.bearing_rad, bearing.variance_rad2, bearing.stamp_s, known_ids
    )
    if not problem:
        return None
    unknown = bearing.beacon_id not in known_ids
    kind = BearingRefusal.UNKNOWN_BEACON if unknown else BearingRefusal.INVALID_MEASUREMENT
    return RefusedBearing(bearing, kind, problem)


def revolution_intake(bearings: Sequence[Bearing], known_ids: Collection[int]) -> RevolutionIntake:
    """The three rules on one revolution's bearings (see the module docstring)."""
    too_many = revolution_size_problem(len(bearings))
    if too_many:
        return RevolutionIntake(too_many=too_many)
    sightings = one_sighting_per_beacon(bearings)
    conflicting = set(sightings.conflicting_ids)
    refused: list[RefusedBearing] = []
    for bearing in bearings:  # a conflicting beacon's bearings, all of them, in their order
        if bearing.beacon_id in conflicting:
            reason = f"beacon {bearing.beacon_id} seen twice at one instant (not physical)"
            refused.append(RefusedBearing(bearing, BearingRefusal.CONFLICTING_BEACON, reason))
    for bearing in sightings.dropped:
        if bearing.beacon_id not in conflicting:
            reason = f"beacon {bearing.beacon_id} seen again: the sighting nearest the middle kept"
            refused.append(RefusedBearing(bearing, BearingRefusal.REPEATED_BEACON, reason))
    kept: list[Bearing] = []
    for bearing in sightings.kept:
        if bearing.beacon_id in conflicting:
            continue
        refusal = bearing_refusal(bearing, known_ids)
        if refusal is None:
            kept.append(bearing)
        else:
            refused.append(refusal)
    return RevolutionIntake(kept, refused)


def bearings_message_intake(
    message: Any, seconds: Callable[[Any], float], known_ids: Collection[int]
) -> RevolutionIntake:
    """`revolution_intake` of a beams_msgs/BeaconBearingArray (an rclpy or a rosbags message; seconds(stamp)
    converts its stamps): an oversized message is refused before its bearings are read."""
    too_many = revolution_size_problem(len(message.bearings))
    if too_many:
        return RevolutionIntake(too_many=too_many)
    return revolution_intake(bearings_of_message(message, seconds), known_ids)
