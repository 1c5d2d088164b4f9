"""A second EdgeSource written outside beams_driver, as a newcomer would: it replays edges recorded to an
.npz file (one revolution after another, each re-stamped on the node's clock), and plugs into driver_node
with `source:=beams_test_plugins.replay_source:EDGE_SOURCE` without an edit to the driver."""

import itertools
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from beams_common.config.parameters import ParameterSpec
from beams_driver.edge_source import EdgeSourceKind, SourceHealth, SourceHost, SourcePoll
from beams_driver.edges import TURRET_PERIOD_S, RevolutionEdges


def save_recording(path: str, revolutions: Sequence[RevolutionEdges]) -> None:
    """Edges of each revolution relative to its start: times, angles, polarities, revolution by revolution."""
    np.savez(
        path,
        counts=np.array([r.n_edges for r in revolutions]),
        times=np.concatenate([r.edge_times_s - r.start_time_s for r in revolutions]),
        angles=np.concatenate([r.edge_angles_rad for r in revolutions]),
        rising=np.concatenate([r.edge_rising for r in revolutions]),
    )


class ReplaySource:
    def __init__(self, values: Mapping[str, Any], _codes: Sequence[Any], _host: SourceHost) -> None:
        recording = np.load(values["replay_file"])
        bounds = np.concatenate([[0], np.cumsum(recording["counts"])])
        self.revolutions = [
            (recording["times"][a:b], recording["angles"][a:b], recording["rising"][a:b])
            for a, b in itertools.pairwise(bounds)
        ]
        self.next_index = 0
        self.next_start_s: float | None = None

    def poll(self, now_s: float) -> SourcePoll:
        if self.next_start_s is None:
            self.next_start_s = now_s
            return SourcePoll(continuity_broken=True)
        poll = SourcePoll()
        while self.next_start_s + TURRET_PERIOD_S <= now_s:
            times, angles, rising = self.revolutions[self.next_index % len(self.revolutions)]
            poll.revolutions.append(
                RevolutionEdges(
                    self.next_index,
                    self.next_start_s,
                    TURRET_PERIOD_S,
                    times + self.next_start_s,
                    angles,
                    rising,
                )
            )
            self.next_index += 1
            self.next_start_s += TURRET_PERIOD_S
            if self.next_index % len(self.revolutions) == 0:
                poll.continuity_broken = bool(poll.revolutions[:-1])  # the recording starts over
                break
        return poll

    def health(self) -> SourceHealth:
        return SourceHealth(values={"replayed_revolutions": self.next_index})

    def close(self) -> None:
        pass


EDGE_SOURCE = EdgeSourceKind(
    "replay",
    (ParameterSpec("replay_file", "", "Recorded edges (.npz) to replay in a loop."),),
    ReplaySource,
)
