"""One BeAMS bearing (eq. 2.5, its variance ch. 4), as ToTal and the EKF take it from beams/bearings."""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, slots=True)
class Bearing:
    """One bearing: stamp (s, the instant the turret pointed at the beacon), beacon id (its code), bearing
    (rad, sensor frame, CCW from the turret's zero reference) and its variance (rad^2); the angular window
    (rad, 0 when unknown) and whether a calibration corrected the bearing (False: it carries the power
    bias of the window, eq. 7.17)."""

    stamp_s: float
    beacon_id: int
    bearing_rad: float
    variance_rad2: float
    angular_window_rad: float = 0.0
    calibrated: bool = True


def bearings_of_message(message: Any, seconds: Callable[[Any], float]) -> list[Bearing]:
    """The bearings of a beams_msgs/BeaconBearingArray (an rclpy or a rosbags message), seconds(stamp)
    converting its stamps; a bearing stamped zero takes the revolution's stamp. A message without the
    `calibrated` field (a bag recorded before it) counts as calibrated, as its driver took it to be."""
    revolution_s = seconds(message.header.stamp)
    calibrated = bool(getattr(message, "calibrated", True))
    return [
        Bearing(
            seconds(b.header.stamp) or revolution_s,
            int(b.beacon_id),
            float(b.bearing),
            float(b.variance),
            float(b.angular_window),
            calibrated,
        )
        for b in message.bearings
    ]
