"""One stamped planar pose buffer for every consumer of a pose stream: ToTal's motion compensation, the EKF's
odometry branch (thesis fig. 8.1) and the simulated sensor. A pose at any recent instant is interpolated
(linear in position, shortest arc in heading) or, shortly past the newest sample (a bearing racing the
odometry), extrapolated along the newest twist's arc or step. `append` takes strictly increasing stamps;
`add` / `add_valid` refuse non-finite samples and handle stamps in the past. Poses are (x, y, theta), REP-103.
"""

import math
from bisect import bisect_right
from collections import deque
from collections.abc import Sequence

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.pose2d import Pose2D, between, compose, interpolate
from beams_common.intake.time_jumps import StampOrder, TimeJumpDetector
from beams_common.intake.validation import odometry_problem

Twist = tuple[float, float]


def arc_increment(speed_mps: float, yaw_rate_rad_s: float, dt_s: float) -> Pose2D:
    """Pose increment (in the starting robot frame) after dt_s at constant speed and yaw rate (an arc)."""
    turn = yaw_rate_rad_s * dt_s
    # Chord of the arc: length 2 sin(turn/2)/turn of the arc, along the mid heading (exact, no 0/0).
    chord = speed_mps * dt_s * (math.sin(turn / 2.0) / (turn / 2.0) if turn else 1.0)
    return chord * math.cos(turn / 2.0), chord * math.sin(turn / 2.0), turn


def twist_between(
    earlier: Sequence[float], earlier_stamp_s: float, later: Sequence[float], later_stamp_s: float
) -> Twist | None:
    """(speed m/s, yaw rate rad/s) from two poses (x, y, theta), or None when their stamps do not
    increase. The speed is signed along the earlier pose's heading (a robot backing up has v < 0)."""
    dt = later_stamp_s - earlier_stamp_s
    if not dt > 0.0:
        return None
    dx, dy = later[0] - earlier[0], later[1] - earlier[1]
    forward = dx * math.cos(earlier[2]) + dy * math.sin(earlier[2])
    speed = math.copysign(math.hypot(dx, dy), forward) / dt
    return speed, wrap_to_pi(later[2] - earlier[2]) / dt


class PoseBuffer:
    """The poses of one stream over the last `span_s` seconds (and one older, to interpolate the first
    instant), strictly increasing; each with an optional twist and an owner's payload (the EKF's state)."""

    def __init__(
        self, span_s: float, max_extrapolation_s: float, time_jumps: TimeJumpDetector | None = None
    ) -> None:
        if not span_s > 0.0 or not max_extrapolation_s >= 0.0:
            raise ValueError(
                f"span_s must be > 0 and max_extrapolation_s >= 0, got {span_s}, {max_extrapolation_s}"
            )
        self.span_s = float(span_s)
        self.max_extrapolation_s = float(max_extrapolation_s)
        # a stamp in the past starts the buffer over at once unless the owner asks for confirmations
        self.time_jumps = time_jumps or TimeJumpDetector(tolerance_s=0.0, confirmations=1)
        self._times: deque[float] = deque()
        self._poses: deque[Pose2D] = deque()
        self._twists: deque[Twist | None] = deque()
        self._payloads: deque[object] = deque()

    def __len__(self) -> int:
        return len(self._times)

    def clear(self) -> None:
        """Forget every sample (after a time jump)."""
        for column in (self._times, self._poses, self._twists, self._payloads):
            column.clear()
        self.time_jumps.clear()

    @property
    def latest(self) -> tuple[float, Pose2D] | None:
        """(stamp, pose) of the newest sample, or None when empty."""
        return (self._times[-1], self._poses[-1]) if self._times else None

    @property
    def newest_stamp_s(self) -> float | None:
        """Stamp of the newest sample, or None when empty."""
        return self._times[-1] if self._times else None

    @property
    def oldest_time_s(self) -> float | None:
        """Stamp of the oldest sample kept, or None when empty."""
        return self._times[0] if self._times else None

    def add(self, stamp_s: float, pose: Pose2D, twist: Twist | None = None) -> bool:
        """Feed one raw sample through the odometry rule (`validation.odometry_problem`, its one home):
        False (nothing stored) for a non-finite one; else `add_valid`, True."""
        if odometry_problem(stamp_s, pose, twist):
            return False
        self.add_valid(stamp_s, pose, twist)
        return True

    def add_valid(self, stamp_s: float, pose: Pose2D, twist: Twist | None = None) -> None:
        """Feed one sample the caller's intake already found finite (`validation.odometry_problem`): a
        stamp in the past is dropped, or starts the buffer over once `time_jumps` confirms the jump."""
        order = self.time_jumps.classify(stamp_s, self.newest_stamp_s)
        if order in (StampOrder.STALE, StampOrder.HELD):
            return
        if order is StampOrder.JUMP:
            self.clear()
        self.append(stamp_s, pose, twist=twist)

    def append(
        self, stamp_s: float, pose: Pose2D, payload: object = None, *, twist: Twist | None = None
    ) -> None:
        """Add a sample newer than every other; raises ValueError otherwise (the caller decides to reset)."""
        if self._times and not stamp_s > self._times[-1]:
            raise ValueError(f"stamp {stamp_s} is not after the newest {self._times[-1]}")
        self._times.append(stamp_s)
        self._poses.append((float(pose[0]), float(pose[1]), float(pose[2])))
        self._twists.append(None if twist is None else (float(twist[0]), float(twist[1])))
        self._payloads.append(payload)
        while len(self._times) > 2 and self._times[1] < stamp_s - self.span_s:
            for column in (self._times, self._poses, self._twists, self._payloads):
                column.popleft()

    def last_step(self) -> tuple[float, Pose2D] | None:
        """(duration, robot-frame motion) between the two newest samples, or None with fewer than two."""
        if len(self._times) < 2:
            return None
        return self._times[-1] - self._times[-2], between(self._poses[-2], self._poses[-1])

    def sample(self, index: int) -> tuple[float, Pose2D, object]:
        """(stamp, pose, payload) of the sample at index (0 = oldest, -1 = newest)."""
        return self._times[index], self._poses[index], self._payloads[index]

    def set_payload(self, index: int, payload: object) -> None:
        """Replace the payload of the sample at index."""
        self._payloads[index] = payload

    def index_at_or_before(self, stamp_s: float) -> int | None:
        """Index of the newest sample not after stamp_s, or None when every sample is after it."""
        index = bisect_right(self._times, stamp_s) - 1
        return index if index >= 0 else None

    def has_pose_at(self, t: float, lookback_s: float = 0.0) -> bool:
        """True when pose_at(t) has an answer, taking a pose before the first sample as that sample's
        for at most lookback_s."""
        return (
            bool(self._times)
            and self._times[0] - lookback_s <= t <= self._times[-1] + self.max_extrapolation_s
        )

    def covers(self, start_s: float, end_s: float, lead_s: float = 0.0) -> bool:
        """True when the buffer starts lead_s before start_s and reaches end_s (extrapolation included)."""
        return (
            bool(self._times)
            and self._times[0] <= start_s - lead_s
            and end_s <= self._times[-1] + self.max_extrapolation_s
        )

    def pose_at(self, t: float, lookback_s: float = 0.0) -> Pose2D | None:
        """Pose at t: interpolated inside the buffer, extrapolated along the newest twist's arc for at
        most max_extrapolation_s past it, the first sample's for at most lookback_s before it; None
        outside."""
        if not self.has_pose_at(t, lookback_s):
            return None
        times = self._times
        if t <= times[0]:
            return self._poses[0]
        if t >= times[-1]:
            return self._extrapolate(t - times[-1])
        index = bisect_right(times, t)  # times[index - 1] <= t < times[index]
        t0, t1 = times[index - 1], times[index]
        return interpolate(self._poses[index - 1], self._poses[index], (t - t0) / (t1 - t0))

    def _extrapolate(self, ahead_s: float) -> Pose2D:
        """Past the newest sample: along its twist's arc, or the newest step continued (linear in position
        and heading) for a stream without twists."""
        newest = self._poses[-1]
        if ahead_s == 0.0:
            return newest
        twist = self._twists[-1]
        if twist is not None:
            return compose(newest, arc_increment(twist[0], twist[1], ahead_s))
        if len(self._times) < 2:
            return newest
        step_s = self._times[-1] - self._times[-2]
        return interpolate(self._poses[-2], newest, 1.0 + ahead_s / step_s)
