"""The turret firmware's pins (receiver: PB0 = ICP1, zero reference: PD2 = INT0) driven by the edge-level
simulator: test/hil/turret_hil.c's schedule, for the HIL tests, bench_firmware and virtual_turret_command."""

import math
import os
import pathlib
from collections.abc import Callable, Sequence

import numpy as np

from beams_common.geometry.pose2d import Pose2D
from beams_driver.edges import RevolutionEdges
from beams_driver.serial_protocol import FIRMWARE_TICKS_PER_REVOLUTION, FIRMWARE_TIMER_HZ
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator

CPU_HZ = 16_000_000
PERIOD_S = FIRMWARE_TICKS_PER_REVOLUTION / FIRMWARE_TIMER_HZ
START_CYCLE = CPU_HZ // 20  # turret time 0: the firmware's boot (set-up, hello) is long over
ZERO_PULSE_S = 50e-6  # how long the optical switch stays on
PIN_RECEIVER, PIN_ZERO_REFERENCE = 0, 1
RECORD = np.dtype([("cycle", "<u8"), ("pin", "u1"), ("level", "u1"), ("pad", "V6")])
# the working copy colcon installed this package into
ROOT = next((p for p in pathlib.Path(__file__).parents if (p / "firmware/turret").is_dir()), pathlib.Path())
HARNESS = pathlib.Path(os.environ.get("BEAMS_HIL_HARNESS", ROOT / "build/hil/turret_hil"))
FIRMWARE = ROOT / "firmware/build/turret.elf"


def turret_config(**overrides: object) -> SensorSimConfig:
    """The thesis-hardware receiver on the firmware's clock: 0.1 s turns captured on 0.5 us ticks."""
    return SensorSimConfig.thesis_hardware(period_s=PERIOD_S, tick_s=1.0 / FIRMWARE_TIMER_HZ, **overrides)


def cycle_of(time_s: float | Sequence[float] | np.ndarray) -> np.ndarray:
    """The CPU cycle of an instant of turret time."""
    return START_CYCLE + np.rint(np.asarray(time_s, dtype=float) * CPU_HZ).astype(np.int64)


def schedule_of(revolutions: list[RevolutionEdges], first: bool = True) -> np.ndarray:
    """The RECORDs of each revolution's zero reference (a pulse) and receiver edges (levels), in cycle
    order; `first`: the pins' levels before them, once the firmware runs (high when the first edge falls)."""
    zero = cycle_of([r.start_time_s for r in revolutions])
    edges = cycle_of(np.concatenate([r.edge_times_s for r in revolutions]))
    rising = np.concatenate([r.edge_rising for r in revolutions])
    cycles = [zero, zero + round(ZERO_PULSE_S * CPU_HZ), edges]
    pins = [np.full(2 * zero.size, PIN_ZERO_REFERENCE), np.full(edges.size, PIN_RECEIVER)]
    levels = [np.ones(zero.size), np.zeros(zero.size), rising]
    if first:
        cycles.insert(0, [START_CYCLE // 2] * 2)
        pins.insert(0, [PIN_RECEIVER, PIN_ZERO_REFERENCE])
        levels.insert(0, [rising.size > 0 and not rising[0], 0])
    records = np.zeros(sum(map(np.size, cycles)), RECORD)
    records["cycle"], records["pin"], records["level"] = (np.concatenate(v) for v in (cycles, pins, levels))
    return records[np.argsort(records["cycle"], kind="stable")]


class TurretPins:
    """The sensor simulator's revolutions from turret time 0, the robot at `pose_at(turret time)`, and
    their schedule in chunks."""

    def __init__(
        self, pose_at: Callable[[float], Pose2D], beacons: object, seed: int, **config: object
    ) -> None:
        self.pose_at = pose_at  # config: turret_config's overrides
        self.simulator = SensorSimulator(turret_config(**config), beacons, np.random.default_rng(seed))
        self.revolutions = 0

    def simulate(self, turret_s: float) -> list[RevolutionEdges]:
        """The revolutions that start before turret_s and were not simulated yet."""
        start = self.revolutions
        self.revolutions = max(start, math.ceil(turret_s / PERIOD_S - 1e-9))
        return [self.simulator.revolution(self.pose_at, k * PERIOD_S) for k in range(start, self.revolutions)]

    def until(self, turret_s: float) -> bytes:
        first = self.revolutions == 0
        revolutions = self.simulate(turret_s)
        return schedule_of(revolutions, first).tobytes() if revolutions else b""


def missing(firmware: pathlib.Path = FIRMWARE) -> str:
    """Why the firmware cannot run in simavr here ("" when it can)."""
    absent = " and ".join(str(path) for path in (firmware, HARNESS) if not path.exists())
    return absent and f"{absent} not built (make hil; avr-gcc, libsimavr-dev: scripts/bootstrap.sh)"


def harness_command(
    schedule: object, end_cycle: int, *options: object, firmware: object = FIRMWARE
) -> list[str]:
    """turret_hil's command line (its options: test/hil/turret_hil.c); schedule "-" and end_cycle 0 read
    the schedule from stdin until its end."""
    return [str(value) for value in (HARNESS, firmware, schedule, end_cycle, *options)]
