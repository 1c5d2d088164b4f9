"""Two sources in one stream, told from the values: counters or stamps that interleave.

One source's values increase by small steps (a restart starts a run the old one never rejoins); two
sources (two drivers in a namespace, a bag over a live robot) give alternating runs: SWITCHES_FOR_INTERLEAVE
switches back to an older run within the window. Merged values that still increase cannot be told from the
values: the ROS graph tells them (beams_common.ros.input_watch).
"""

from collections import deque
from dataclasses import dataclass

SWITCHES_FOR_INTERLEAVE = 4


@dataclass
class _Track:
    last_value: float
    last_used: int  # the message index that extended it last


class InterleaveDetector:
    """Counts the switches back between runs of increasing values (see the module docstring).

    A value continues a track when it exceeds the track's last value by at most `max_step` (modulo
    `modulus` for a counter that wraps); of several, the smallest step wins, then the most recent track.
    """

    def __init__(
        self,
        max_step: float,
        window_s: float = 2.0,
        modulus: float | None = None,
        max_tracks: int = 4,
        switches_for_interleave: int = SWITCHES_FOR_INTERLEAVE,
    ) -> None:
        if not (max_step > 0.0 and window_s > 0.0 and max_tracks >= 2 and switches_for_interleave >= 1):
            raise ValueError("max_step and window_s > 0, max_tracks >= 2 and switches_for_interleave >= 1")
        self.max_step = max_step
        self.window_s = window_s
        self.modulus = modulus
        self.max_tracks = max_tracks
        self.switches_for_interleave = switches_for_interleave
        self._tracks: list[_Track] = []
        self._count = 0
        self._previous: _Track | None = None
        self._switch_times_s: deque[float] = deque()

    def observe(self, value: float, now_s: float) -> None:
        """One message's value (a non-finite one is left out), received at `now_s` (monotonic s)."""
        if value != value or value in (float("inf"), float("-inf")):
            return
        self._count += 1
        track = self._continued(value)
        if track is None:
            if len(self._tracks) >= self.max_tracks:
                self._tracks.remove(min(self._tracks, key=lambda t: t.last_used))
            track = _Track(value, self._count)
            self._tracks.append(track)
        elif self._previous is not None and track is not self._previous:
            self._switch_times_s.append(now_s)
        track.last_value, track.last_used = value, self._count
        self._previous = track
        self._forget_before(now_s - self.window_s)

    def switches(self, now_s: float) -> int:
        """Switches back to an older track within the window ending at `now_s`."""
        self._forget_before(now_s - self.window_s)
        return len(self._switch_times_s)

    def interleaved(self, now_s: float) -> bool:
        return self.switches(now_s) >= self.switches_for_interleave

    def _continued(self, value: float) -> _Track | None:
        best: tuple[float, int, _Track] | None = None
        for track in self._tracks:
            step = value - track.last_value
            if self.modulus is not None:
                step %= self.modulus
            if 0.0 < step <= self.max_step and (best is None or (step, -track.last_used) < best[:2]):
                best = (step, -track.last_used, track)
        return None if best is None else best[2]

    def _forget_before(self, oldest_s: float) -> None:
        while self._switch_times_s and self._switch_times_s[0] < oldest_s:
            self._switch_times_s.popleft()
