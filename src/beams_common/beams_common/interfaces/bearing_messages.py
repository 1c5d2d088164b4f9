"""The one builder of beams_msgs/BeaconBearingArray: driver_node's publication, the bags the offline
simulator writes, and every test's revolutions.

It builds from the message types it is given by their ROS names (`types["beams_msgs/msg/BeaconBearing"]`),
so one builder serves rclpy's classes (`beams_common.ros.messages.bearing_array`) and a rosbags
typestore's (`typestore.types`, for bags) alike; every field is set, as rosbags' classes require.
Stamps are integer nanoseconds (a bag's clock), exact at any epoch.
"""

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

NS_PER_S = 1_000_000_000
SENSOR_FRAME = "beams_sensor"
# the message's field widths: revolution is uint32, rejected_windows uint16
_REVOLUTION_MODULUS = 2**32
_MAX_REJECTED_WINDOWS = 2**16 - 1


def nanoseconds(seconds: float) -> int:
    """A stamp in seconds as integer nanoseconds (rounded, as seconds_to_stamp does)."""
    return round(seconds * 1e9)


@dataclass(frozen=True)
class BearingFields:
    """One beams_msgs/BeaconBearing: the instant the turret pointed at the beacon, the beacon, the
    bearing (rad, CCW) and its variance (rad^2), and what the decoder measured of the window."""

    stamp_ns: int
    beacon_id: int
    bearing_rad: float
    variance_rad2: float
    angular_window_rad: float = 0.0
    rising_angle_rad: float = 0.0
    falling_angle_rad: float = 0.0
    codes_seen: int = 0


def bearing_array_message(
    types: Mapping[str, Callable[..., Any]],
    start_ns: int,
    bearings: Iterable[BearingFields],
    *,
    period_s: float,
    revolution: int = 0,
    rejected_windows: int = 0,
    frame_id: str = SENSOR_FRAME,
    calibrated: bool = True,
) -> Any:
    """beams_msgs/BeaconBearingArray of one revolution begun at start_ns (its header stamp), each
    bearing stamped with its own instant; revolution wraps to uint32, rejected_windows saturates.
    `calibrated`: the driver's flag (false: the bearings carry the uncorrected power bias, which the EKF
    then models; true for bearings that need no correction, such as synthetic ones)."""

    def header(stamp_ns: int) -> Any:
        time = types["builtin_interfaces/msg/Time"](sec=stamp_ns // NS_PER_S, nanosec=stamp_ns % NS_PER_S)
        return types["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    bearing_type = types["beams_msgs/msg/BeaconBearing"]
    items = [
        bearing_type(
            header=header(b.stamp_ns),
            beacon_id=int(b.beacon_id),
            bearing=float(b.bearing_rad),
            variance=float(b.variance_rad2),
            angular_window=float(b.angular_window_rad),
            rising_angle=float(b.rising_angle_rad),
            falling_angle=float(b.falling_angle_rad),
            codes_seen=int(b.codes_seen),
        )
        for b in bearings
    ]
    return types["beams_msgs/msg/BeaconBearingArray"](
        header=header(start_ns),
        revolution=int(revolution) % _REVOLUTION_MODULUS,
        period=float(period_s),
        bearings=items,
        rejected_windows=min(int(rejected_windows), _MAX_REJECTED_WINDOWS),
        calibrated=bool(calibrated),
    )
