"""The turret firmware in simavr, driven by the edge-level simulator: the pins' schedule and the harness.

The harness (test/hil/turret_hil.c, built by `make hil`) runs firmware/build/turret.elf on an emulated
ATmega328P at 16 MHz and raises the receiver's pin (PB0 = ICP1) and the zero reference's (PD2 = INT0) at
the CPU cycles of a schedule. `schedule_of(revolutions)` turns simulated revolutions into that schedule;
`TurretPins` simulates them revolution after revolution for a run in real time (the virtual turret,
virtual_turret_command.py), the HIL test and the firmware's bench build whole runs with it.
"""

import math
import os
import pathlib
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from beams_common.pose2d import Pose2D
from beams_driver.edges import RevolutionEdges
from beams_driver.serial_protocol import FIRMWARE_TICKS_PER_REVOLUTION, FIRMWARE_TIMER_HZ, EventKind
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator
from beams_sim.world import EurobotTrajectory

CPU_HZ = 16_000_000
TIMER_HZ = FIRMWARE_TIMER_HZ  # what its hello says
CYCLES_PER_TICK = CPU_HZ // TIMER_HZ
TICKS_PER_REVOLUTION = FIRMWARE_TICKS_PER_REVOLUTION  # 800 microsteps x 2 x 125 ticks: 10 turn/s
PERIOD_S = TICKS_PER_REVOLUTION / TIMER_HZ
# The firmware's boot (set-up, the boot hello) is over long before the first injected level.
START_CYCLE = CPU_HZ // 20
ZERO_PULSE_S = 50e-6  # how long the optical switch stays on
PIN_RECEIVER, PIN_ZERO_REFERENCE = 0, 1
RECORD = np.dtype([("cycle", "<u8"), ("pin", "u1"), ("level", "u1"), ("pad", "V6")])


def turret_config(**overrides: object) -> SensorSimConfig:
    """The thesis-hardware receiver on the firmware's clock: 0.1 s turns captured on 0.5 us ticks."""
    return SensorSimConfig.thesis_hardware(period_s=PERIOD_S, tick_s=1.0 / TIMER_HZ, **overrides)


@dataclass
class Schedule:
    """Pin levels at cycles, and the captures the firmware should report: kind and injected cycle."""

    records: np.ndarray
    kinds: list[EventKind]
    cycles: np.ndarray
    end_cycle: int

    def write(self, path: pathlib.Path) -> pathlib.Path:
        self.records.tofile(path)
        return path


def cycle_of(time_s: float | np.ndarray) -> np.ndarray:
    """The CPU cycle of an instant of turret time (0 s is START_CYCLE)."""
    return START_CYCLE + np.rint(np.asarray(time_s, dtype=float) * CPU_HZ).astype(np.int64)


def schedule_of(revolutions: Sequence[RevolutionEdges], first: bool = True, closed: bool = True) -> Schedule:
    """Each revolution's zero reference (a pulse on INT0) and its receiver edges (levels on ICP1); with
    `closed` the closing zero reference of the last one, with `first` the pins' levels before the first
    event (the next revolutions of one simulator continue the line's level)."""
    zero_times = [r.start_time_s for r in revolutions]
    if closed:
        zero_times.append(revolutions[-1].start_time_s + revolutions[-1].period_s)
    edge_times = np.concatenate([r.edge_times_s for r in revolutions])
    edge_rising = np.concatenate([r.edge_rising for r in revolutions])
    zero_cycles = cycle_of(zero_times)
    edge_cycles = cycle_of(edge_times)
    pins = np.concatenate(
        [np.full(2 * zero_cycles.size, PIN_ZERO_REFERENCE), np.full(edge_cycles.size, PIN_RECEIVER)]
    )
    cycles = np.concatenate([zero_cycles, zero_cycles + round(ZERO_PULSE_S * CPU_HZ), edge_cycles])
    levels = np.concatenate([np.ones(zero_cycles.size), np.zeros(zero_cycles.size), edge_rising])
    capture_cycles = np.concatenate([zero_cycles, edge_cycles])
    kinds = [EventKind.ZERO_REFERENCE] * zero_cycles.size + [
        EventKind.RISING if rising else EventKind.FALLING for rising in edge_rising.tolist()
    ]
    if first:
        # the pins' levels before the first event (the receiver is high if its first edge falls), set once
        # the firmware runs, whatever simavr made of its port set-up
        receiver_level = int(edge_rising.size > 0 and not edge_rising[0])
        pins = np.concatenate([[PIN_RECEIVER, PIN_ZERO_REFERENCE], pins])
        cycles = np.concatenate([[START_CYCLE // 2] * 2, cycles])
        levels = np.concatenate([[receiver_level, 0], levels])
        if receiver_level:  # the firmware armed for a rising edge at boot, and sees this one
            capture_cycles = np.concatenate([[START_CYCLE // 2], capture_cycles])
            kinds = [EventKind.RISING, *kinds]
    order = np.argsort(cycles, kind="stable")
    records = np.zeros(cycles.size, RECORD)
    records["cycle"], records["pin"], records["level"] = cycles[order], pins[order], levels[order]
    capture_order = np.argsort(capture_cycles, kind="stable")
    return Schedule(
        records,
        [kinds[i] for i in capture_order],
        capture_cycles[capture_order],
        int(cycles.max()) + CPU_HZ // 20,
    )


class TurretPins:
    """The schedule of a turret turning from turret time 0 on, revolution after revolution: the sensor
    simulator's edges for the robot's pose at each instant (`pose_at`, turret time)."""

    def __init__(self, pose_at: Callable[[float], Pose2D], beacons: object, seed: int) -> None:
        self.pose_at = pose_at
        self.simulator = SensorSimulator(turret_config(), beacons, np.random.default_rng(seed))
        self.revolutions = 0

    def until(self, turret_s: float) -> bytes:
        """The records of the revolutions that start before turret_s and were not given yet."""
        count = max(0, int(np.ceil(turret_s / PERIOD_S)) - self.revolutions)
        if count == 0:
            return b""
        revolutions = [
            self.simulator.revolution(self.pose_at, (self.revolutions + k) * PERIOD_S) for k in range(count)
        ]
        schedule = schedule_of(revolutions, first=self.revolutions == 0, closed=False)
        self.revolutions += count
        return schedule.records.tobytes()


def match_time_of(trajectory: EurobotTrajectory, pose: Pose2D) -> float | None:
    """The instant of the match at which the trajectory passes through pose (the nearest point of its
    sampled path, position and heading): where sim_world_node's match is, from one ground-truth pose;
    None while the robot rests there before moving on (any instant of the rest fits)."""
    states = trajectory.states_at(np.arange(0.0, trajectory.duration_s, 1e-3))
    start, segment = states[:-1, :2], np.diff(states[:, :2], axis=0)
    length2 = np.sum(segment**2, axis=1)
    fraction = np.clip(
        np.sum((np.asarray(pose[:2]) - start) * segment, axis=1) / np.maximum(length2, 1e-30), 0, 1
    )
    off_m = np.hypot(*(start + fraction[:, None] * segment - pose[:2]).T)
    heading = states[:-1, 2] + fraction * np.diff(states[:, 2])
    off_rad = np.abs(np.angle(np.exp(1j * (heading - pose[2]))))
    best = int(np.argmin(off_m + 0.1 * off_rad))
    moving = length2 > 0.0
    if not moving[best] and moving[best:].any():
        return None
    return (best + float(fraction[best])) * 1e-3


class MatchClock:
    """sim_world_node's match clock, from its ground truth: the system time of the match's start (the
    median over SYNC_POSES moving poses), then how far each later truth pose is off the trajectory at its
    instant (another match: other parameters, or a match started over)."""

    SYNC_POSES = 3

    def __init__(self, trajectory: EurobotTrajectory) -> None:
        self.trajectory = trajectory
        self.origins_s: list[float] = []
        self.origin_s: float | None = None
        self.off_m = 0.0

    def on_truth(self, stamp_s: float, pose: Pose2D) -> None:
        if self.origin_s is not None:
            self.off_m = max(
                self.off_m, math.dist(self.trajectory.pose_at(stamp_s - self.origin_s)[:2], pose[:2])
            )
            return
        match_s = match_time_of(self.trajectory, pose)
        if match_s is not None:  # a resting robot's instant is the next moving pose's
            self.origins_s.append(stamp_s - match_s)
        if len(self.origins_s) == self.SYNC_POSES:
            self.origin_s = statistics.median(self.origins_s)


def repository_root() -> pathlib.Path:
    """The working copy this package was built from (colcon installs into it), else the current folder."""
    here = pathlib.Path(__file__).resolve()
    return next((p for p in here.parents if (p / "firmware" / "turret").is_dir()), pathlib.Path.cwd())


def default_harness() -> pathlib.Path:
    return pathlib.Path(
        os.environ.get("BEAMS_HIL_HARNESS", repository_root() / "build" / "hil" / "turret_hil")
    )


def default_firmware() -> pathlib.Path:
    return repository_root() / "firmware" / "build" / "turret.elf"


def missing(harness: pathlib.Path, firmware: pathlib.Path) -> str:
    """Why the firmware cannot run in simavr here ("" when it can)."""
    if not firmware.exists():
        return f"{firmware} is not built (make hil; avr-gcc from scripts/bootstrap.sh)"
    if not harness.exists():
        return f"{harness} is not built (make hil; libsimavr-dev from scripts/bootstrap.sh)"
    return ""


def harness_command(
    harness: pathlib.Path,
    firmware: pathlib.Path,
    schedule_path: pathlib.Path | str,
    end_cycle: int,
    *,
    out_fd: int | None = None,
    byte_log: pathlib.Path | None = None,
    realtime: bool = False,
    start_at_s: float | None = None,
    step_log: pathlib.Path | None = None,
) -> list[str]:
    """turret_hil's command line: `schedule_path` "-" and `end_cycle` 0 read the schedule from stdin until
    its end; `start_at_s` (system clock) is the instant of cycle 0 in real time."""
    command = [str(harness), str(firmware), str(schedule_path), str(end_cycle)]
    if step_log is not None:
        command += ["--step-log", str(step_log)]
    if out_fd is not None:
        command += ["--out-fd", str(out_fd)]
    if byte_log is not None:
        command += ["--byte-log", str(byte_log)]
    if realtime:
        command.append("--realtime")
    if start_at_s is not None:
        command += ["--start-at", f"{start_at_s:.6f}"]
    return command
