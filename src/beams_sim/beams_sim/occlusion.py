"""What the simulated sensor follows and meets: the robot's own true pose (beams/sim/ground_truth), needed at
every instant of a revolution, and the other robots' bodies (`OtherRobots`)."""

import math
from collections.abc import Callable, Mapping

from beams_common.geometry.pose_buffer import PoseBuffer
from beams_driver.edges import TURRET_PERIOD_S

# seconds of true poses kept
TRUTH_SPAN_S = 2.0
# a pose older than this cannot stand for the robot during a revolution (extrapolated with its twist)
TRUTH_MAX_EXTRAPOLATION_S = 0.25
# the history must start this long before a revolution: a beacon near the zero reference is seen around
# the revolution's start, and before the first sample the pose would be frozen at it (a pose taken as
# constant before the first sample put the first fix of a driver started on a moving robot 3 cm off)
TRUTH_LEAD_S = 0.5 * TURRET_PERIOD_S


def truth_buffer() -> PoseBuffer:
    """A robot's recent true poses as they arrive, a stamp in the past starting it over (a bag loop)."""
    return PoseBuffer(TRUTH_SPAN_S, TRUTH_MAX_EXTRAPOLATION_S)


def truth_covers(history: PoseBuffer, start_s: float, end_s: float) -> bool:
    """True when every instant of the revolution [start_s, end_s] has a true pose (from TRUTH_LEAD_S
    before it to at most TRUTH_MAX_EXTRAPOLATION_S past the newest sample)."""
    return history.covers(start_s, end_s, lead_s=TRUTH_LEAD_S)


def sight_line_blocked(
    sensor_xy: tuple[float, float],
    beacon_xy: tuple[float, float],
    centre_xy: tuple[float, float],
    radius_m: float,
) -> bool:
    """True when the segment from the sensor to the beacon passes closer than radius_m to centre_xy."""
    (ax, ay), (bx, by), (cx, cy) = sensor_xy, beacon_xy, centre_xy
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    s = 0.0 if length2 == 0.0 else min(1.0, max(0.0, ((cx - ax) * dx + (cy - ay) * dy) / length2))
    return math.hypot(ax + s * dx - cx, ay + s * dy - cy) < radius_m


class OtherRobots:
    """The other robots on the table as the simulated sensor meets them: each one's body in the beacons'
    plane is a disc of radius_m around its true position (from its own ground truth), and hides a beacon
    while it stands across the line of sight. Called as the sensor simulator's occlusion, (beacon_id,
    time_s) -> hidden; a robot whose truth has stopped arriving is no longer on the table."""

    def __init__(
        self,
        beacons: Mapping[int, tuple[float, float]],
        radius_m: float,
        sensor_position: Callable[[float], tuple[float, float]],
    ) -> None:
        self.beacons = dict(beacons)
        self.radius_m = radius_m
        self.sensor_position = sensor_position
        self.histories: dict[str, PoseBuffer] = {}
        self.hidden_windows = 0

    def add(
        self,
        name: str,
        stamp_s: float,
        x: float,
        y: float,
        theta: float,
        speed_mps: float,
        yaw_rate_radps: float,
    ) -> bool:
        """Store a true pose of robot `name`; False (nothing stored) for a non-finite one."""
        history = self.histories.setdefault(name, truth_buffer())
        return history.add(stamp_s, (x, y, theta), (speed_mps, yaw_rate_radps))

    def positions_at(self, t: float) -> list[tuple[float, float]]:
        """Where the other robots known at t stand."""
        lookback_s = TRUTH_MAX_EXTRAPOLATION_S
        poses = (history.pose_at(t, lookback_s=lookback_s) for history in self.histories.values())
        return [pose[:2] for pose in poses if pose is not None]

    def __call__(self, beacon_id: int, time_s: float) -> bool:
        beacon = self.beacons.get(beacon_id)
        if beacon is None or not self.histories:
            return False
        sensor = self.sensor_position(time_s)
        hidden = any(
            sight_line_blocked(sensor, beacon, centre, self.radius_m) for centre in self.positions_at(time_s)
        )
        self.hidden_windows += hidden
        return hidden
