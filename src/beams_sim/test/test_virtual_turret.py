"""The virtual turret's pure side: its schedule, written in chunks, is the whole run's, and one
ground-truth pose places the trajectory on the match's clock."""

import numpy as np

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_sim.sensor_sim import SensorSimulator
from beams_sim.virtual_turret import (
    PERIOD_S,
    SYNC_SPEED_MPS,
    MatchClock,
    TurretPins,
    match_time_of,
    schedule_of,
    turret_config,
)
from beams_sim.world import EurobotTrajectory


def test_the_chunks_are_the_whole_runs_schedule() -> None:
    trajectory = EurobotTrajectory.random(seed=4, duration_s=20.0)
    pins = TurretPins(trajectory.pose_at, EUROBOT_BEACON_MAP, seed=8)
    chunks = [pins.until(s) for s in (0.05, 0.35, 0.35, 0.9, 1.0)]
    assert chunks[2] == b"" and pins.revolutions == 10
    simulator = SensorSimulator(turret_config(), EUROBOT_BEACON_MAP, np.random.default_rng(8))
    whole = schedule_of(
        [simulator.revolution(trajectory.pose_at, k * PERIOD_S) for k in range(10)], closed=False
    )
    assert b"".join(chunks) == whole.tobytes()
    # the chunks after the first carry no initial levels: every record is at or after its revolution
    later = np.frombuffer(b"".join(chunks[1:]), whole.dtype)
    assert later["cycle"].min() >= whole["cycle"][2]


def test_one_pose_gives_the_instant_of_the_match() -> None:
    trajectory = EurobotTrajectory.random(seed=2, duration_s=60.0)
    for match_s in np.random.default_rng(1).uniform(0.5, 59.5, 20):
        found = match_time_of(trajectory, trajectory.pose_at(float(match_s)))
        moving = trajectory.twist_at(float(match_s))[0] > SYNC_SPEED_MPS
        assert abs(found - match_s) < 1e-6 if moving else found is None
    # standing still for good (the path's end, the match's): an instant of that rest, the last pose
    found = match_time_of(trajectory, trajectory.pose_at(70.0))
    assert found is not None and np.allclose(trajectory.pose_at(found), trajectory.pose_at(70.0))


def test_the_match_clock_is_found_and_another_match_is_told() -> None:
    """sim_world_node's truth at 50 Hz from a match started at 1000 s: the clock is found within a
    microsecond; the truth of another seed, which starts at the same pose, is soon off the trajectory."""
    trajectory = EurobotTrajectory.random(seed=0, duration_s=30.0)
    clock = MatchClock(trajectory)
    for stamp_s in 1000.0 + np.arange(0.0, 10.0, 0.02):
        clock.on_truth(float(stamp_s), trajectory.pose_at(float(stamp_s) - 1000.0))
    assert abs(clock.origin_s - 1000.0) < 1e-6 and clock.off_m < 1e-9
    other = EurobotTrajectory.random(seed=5, duration_s=30.0)
    clock = MatchClock(trajectory)
    for stamp_s in 1000.0 + np.arange(0.0, 10.0, 0.02):
        clock.on_truth(float(stamp_s), other.pose_at(float(stamp_s) - 1000.0))
    assert clock.origin_s is not None and clock.off_m > 0.1
