"""A short history of odometry poses (thesis fig. 8.1, the odometry branch).

The EKF state lives at the instant of the newest odometry sample, while each BeAMS bearing is stamped
with the instant the turret pointed at its beacon (earlier, since a revolution is published when it
ends). The history below gives the odometry pose at any recent instant by interpolation, so the motion
between a bearing's stamp and the filter's instant is known (odometry is precise over such short spans).

Poses are (x, y, theta) tuples: x, y in metres, theta in radians, REP-103.
"""

from bisect import bisect_right
from collections import deque

from beams_driver.pose2d import Pose2D, between, interpolate


class OdometryHistory:
    """The odometry poses (odom frame) of the last `span_s` seconds, strictly increasing in time.

    `pose_at(t)` interpolates between the two samples around t, and extrapolates with the newest
    sample's velocity for at most `max_extrapolation_s` past the newest sample (a bearing may be
    stamped a little after the last odometry message when the two streams race).
    """

    def __init__(self, span_s: float = 1.0, max_extrapolation_s: float = 0.05) -> None:
        if not span_s > 0.0 or not max_extrapolation_s >= 0.0:
            raise ValueError(f"span_s must be > 0 and max_extrapolation_s >= 0, got {span_s}, "
                             f"{max_extrapolation_s}")
        self.span_s = span_s
        self.max_extrapolation_s = max_extrapolation_s
        self._times: deque[float] = deque()
        self._poses: deque[Pose2D] = deque()
        # whatever the owner attaches to a sample (the filter's state after it, to replay late bearings)
        self._payloads: deque[object] = deque()

    def __len__(self) -> int:
        return len(self._times)

    def clear(self) -> None:
        """Forget every sample (after a time jump)."""
        self._times.clear()
        self._poses.clear()
        self._payloads.clear()

    @property
    def latest(self) -> tuple[float, Pose2D] | None:
        """(stamp, pose) of the newest sample, or None when empty."""
        return (self._times[-1], self._poses[-1]) if self._times else None

    @property
    def oldest_time_s(self) -> float | None:
        """Stamp of the oldest sample kept, or None when empty."""
        return self._times[0] if self._times else None

    def last_step(self) -> tuple[float, Pose2D] | None:
        """(duration, robot-frame motion) between the two newest samples, or None with fewer than two."""
        if len(self._times) < 2:
            return None
        return self._times[-1] - self._times[-2], between(self._poses[-2], self._poses[-1])

    def append(self, stamp_s: float, pose: Pose2D, payload: object = None) -> None:
        """Add a sample newer than every other; raises ValueError otherwise (the caller decides to reset)."""
        if self._times and not stamp_s > self._times[-1]:
            raise ValueError(f"odometry stamp {stamp_s} is not after the newest {self._times[-1]}")
        self._times.append(stamp_s)
        self._poses.append(pose)
        self._payloads.append(payload)
        # keep one sample older than the span so the span's first instant can still be interpolated
        while len(self._times) > 2 and self._times[1] < stamp_s - self.span_s:
            self._times.popleft()
            self._poses.popleft()
            self._payloads.popleft()

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

    def pose_at(self, stamp_s: float) -> Pose2D | None:
        """Odometry pose at stamp_s, or None when stamp_s is outside what the history covers."""
        times = self._times
        if not times or stamp_s < times[0]:
            return None
        if stamp_s >= times[-1]:
            return self._extrapolate(stamp_s)
        index = bisect_right(times, stamp_s)  # times[index - 1] <= stamp_s < times[index]
        t0, t1 = times[index - 1], times[index]
        return interpolate(self._poses[index - 1], self._poses[index], (stamp_s - t0) / (t1 - t0))

    def _extrapolate(self, stamp_s: float) -> Pose2D | None:
        """Constant-velocity extrapolation past the newest sample, within max_extrapolation_s."""
        ahead_s = stamp_s - self._times[-1]
        if ahead_s > self.max_extrapolation_s:
            return None
        if ahead_s == 0.0 or len(self._times) < 2:
            return self._poses[-1]
        previous, newest = self._poses[-2], self._poses[-1]
        step_s = self._times[-1] - self._times[-2]
        return interpolate(previous, newest, 1.0 + ahead_s / step_s)
