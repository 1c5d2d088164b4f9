"""The virtual turret's pure side: its schedule, written in chunks, is the whole run's."""

import numpy as np

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_sim.sensor_sim import SensorSimulator
from beams_sim.virtual_turret import PERIOD_S, TurretPins, schedule_of, turret_config
from beams_sim.world import EurobotTrajectory


def test_the_chunks_are_the_whole_runs_schedule() -> None:
    trajectory = EurobotTrajectory.random(seed=4, duration_s=20.0)
    pins = TurretPins(trajectory.pose_at, EUROBOT_BEACON_MAP, seed=8)
    chunks = [pins.until(s) for s in (0.05, 0.35, 0.35, 0.9, 1.0)]
    assert chunks[2] == b"" and pins.revolutions == 10
    simulator = SensorSimulator(turret_config(), EUROBOT_BEACON_MAP, np.random.default_rng(8))
    whole = schedule_of([simulator.revolution(trajectory.pose_at, k * PERIOD_S) for k in range(10)])
    assert b"".join(chunks) == whole.tobytes()
    # the chunks after the first carry no initial levels: every record is at or after its revolution
    later = np.frombuffer(b"".join(chunks[1:]), whole.dtype)
    assert later["cycle"].min() >= whole["cycle"][2]
