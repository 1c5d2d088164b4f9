"""Bag replay benchmark: how fast `replay_bag` runs the triangulation and the EKF over a simulated 90 s match
(110 input messages per second: truth and odometry at 50 Hz, bearings at 10 Hz) in MCAP and sqlite3.
"""

import pathlib
import sys
import tempfile

from rows_table import Row, bench_main, budget_row

from beams_sim.simulated_match import simulate_match
from beams_tools.bag_io import beams_typestore
from beams_tools.bag_messages import simulated_messages, write_bag
from beams_tools.bag_replay import replay_bag
from beams_tools.replay_pipelines import ReplayResult

DEFAULT_DURATION_S = 90.0
DEFAULT_SEED = 3
BEAMS_MSGS = pathlib.Path(__file__).resolve().parents[1] / "src" / "beams_msgs"
# the suite's live input rate: truth 50 Hz + odometry 50 Hz + bearings 10 Hz
LIVE_MESSAGES_PER_S = 110.0
REAL_TIME_BUDGET = 200.0  # x real time, MCAP (replay_bag's default)


def replay_once(duration_s: float, seed: int, storage: str) -> ReplayResult:
    """Write the match to a bag of the given storage and replay it into another (same storage)."""
    typestore = beams_typestore(BEAMS_MSGS)
    messages = simulated_messages(simulate_match(duration_s, seed=seed), typestore, 1_795_000_000 * 10**9)
    with tempfile.TemporaryDirectory() as directory:
        bag = write_bag(pathlib.Path(directory) / "input", messages, typestore, storage=storage)
        return replay_bag(bag, pathlib.Path(directory) / "output", typestore=typestore, storage=storage)


def rows(duration_s: float = DEFAULT_DURATION_S, seed: int = DEFAULT_SEED) -> list[Row]:
    table = []
    for storage in ("mcap", "sqlite3"):
        result = replay_once(duration_s, seed, storage)
        table += [
            (
                f"replay_bag speed, {duration_s:.0f} s match, {storage}",
                result.messages_per_s,
                "messages/s",
                f"{LIVE_MESSAGES_PER_S:.0f} messages/s live",
            ),
            budget_row(
                f"replay_bag speed, {duration_s:.0f} s match, {storage}",
                result.real_time_factor,
                "x real time",
                REAL_TIME_BUDGET,
                at_least=True,
            )
            if storage == "mcap"
            else (
                f"replay_bag speed, {duration_s:.0f} s match, {storage}",
                result.real_time_factor,
                "x real time",
                "-",
            ),
        ]
    table.append(
        (
            f"replay_bag outputs written per input message ({duration_s:.0f} s match)",
            result.messages_out / result.messages_in,
            "messages",
            "1 (inputs copied) + outputs",
        )
    )
    return table


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
