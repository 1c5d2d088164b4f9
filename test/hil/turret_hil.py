"""The turret firmware in simavr over a schedule of pin levels (beams_sim.virtual_turret's, which the
virtual turret runs in real time): `run_harness` runs firmware/build/turret.elf under test/hil/turret_hil.c
(built by `make hil`) and returns what the UART sent; a `Schedule` says which captures the firmware should
report. Used by test/dds/test_firmware_hil.py and bench/bench_firmware.py.
"""

import pathlib
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from beams_driver.edges import RevolutionEdges
from beams_driver.serial_protocol import FIRMWARE_TICKS_PER_REVOLUTION, FIRMWARE_TIMER_HZ, EventKind
from beams_sim import virtual_turret
from beams_sim.virtual_turret import (  # noqa: F401 (the tests' and the bench's names)
    CPU_HZ,
    PERIOD_S,
    PIN_RECEIVER,
    PIN_ZERO_REFERENCE,
    RECORD,
    ROOT,
    START_CYCLE,
    ZERO_PULSE_S,
    TurretPins,
    cycle_of,
    harness_command,
    missing,
    turret_config,
)

FIRMWARE_ELF = virtual_turret.FIRMWARE
TIMER_HZ = FIRMWARE_TIMER_HZ  # what its hello says
CYCLES_PER_TICK = CPU_HZ // TIMER_HZ
TICKS_PER_REVOLUTION = FIRMWARE_TICKS_PER_REVOLUTION  # 800 microsteps x 2 x 125 ticks: 10 turn/s


@dataclass
class Schedule:
    """Pin levels at cycles, and the captures the firmware should report: kind and injected cycle."""

    records: np.ndarray
    kinds: list[EventKind]
    cycles: np.ndarray
    end_cycle: int

    @classmethod
    def of(cls, records: np.ndarray) -> "Schedule":
        """The captures of the records: every zero-reference pulse, every change of the receiver's level
        (low before the schedule: the firmware armed for a rising edge at boot)."""
        kinds, cycles, level = [], [], 0
        for cycle, pin, value in zip(*(records[f].tolist() for f in ("cycle", "pin", "level")), strict=True):
            if pin == PIN_ZERO_REFERENCE and value:
                kinds.append(EventKind.ZERO_REFERENCE)
            elif pin == PIN_RECEIVER and value != level:
                kinds.append(EventKind.RISING if value else EventKind.FALLING)
                level = value
            else:
                continue
            cycles.append(cycle)
        return cls(
            records, kinds, np.array(cycles, dtype=np.int64), int(records["cycle"].max()) + CPU_HZ // 20
        )

    def write(self, path: pathlib.Path) -> pathlib.Path:
        self.records.tofile(path)
        return path


def simulate(duration_s: float, pose_at, seed: int, beacons, **overrides: object) -> list[RevolutionEdges]:
    """The revolutions of duration_s of turret time, the first opened at 0 s (turret_config's overrides)."""
    return TurretPins(pose_at, beacons, seed, **overrides).simulate(int(duration_s / PERIOD_S) * PERIOD_S)


def schedule_of(revolutions: Sequence[RevolutionEdges]) -> Schedule:
    """Each revolution's zero reference and receiver edges, and the closing zero reference of the last."""
    end_s = revolutions[-1].start_time_s + revolutions[-1].period_s  # a revolution of no edge: its zero
    return Schedule.of(
        virtual_turret.schedule_of([*revolutions, RevolutionEdges(0, end_s, PERIOD_S, [], [], [])])
    )


def receiver_schedule(cycles: np.ndarray, rising: np.ndarray, zero_cycles: Sequence[int] = ()) -> Schedule:
    """Levels on the receiver's pin at these cycles (it starts low), and zero references (pulses on the
    switch's pin) opening at zero_cycles."""
    zero_cycles = np.asarray(zero_cycles, dtype=np.int64)
    parts = [
        ([START_CYCLE // 2] * 2, [PIN_RECEIVER, PIN_ZERO_REFERENCE], [0, 0]),
        (cycles, [PIN_RECEIVER] * len(cycles), rising),
        (zero_cycles, [PIN_ZERO_REFERENCE] * zero_cycles.size, [1] * zero_cycles.size),
        (
            zero_cycles + round(ZERO_PULSE_S * CPU_HZ),
            [PIN_ZERO_REFERENCE] * zero_cycles.size,
            [0] * zero_cycles.size,
        ),
    ]
    records = np.zeros(sum(len(p[0]) for p in parts), RECORD)
    for i, field in enumerate(("cycle", "pin", "level")):
        records[field] = np.concatenate([np.asarray(p[i], dtype=np.int64) for p in parts])
    return Schedule.of(records[np.argsort(records["cycle"], kind="stable")])


def run_harness(
    schedule: Schedule, workdir: pathlib.Path, byte_log: bool = False, firmware: pathlib.Path = FIRMWARE_ELF
) -> tuple[bytes, str, np.ndarray]:
    """Run the firmware over the schedule as fast as simavr goes: (UART bytes, summary line, byte log
    records (cycle, byte) or an empty array)."""
    path = schedule.write(workdir / "schedule.bin")
    log_path = workdir / "bytes.bin" if byte_log else None
    options = ("--byte-log", log_path) if log_path else ()
    result = subprocess.run(
        harness_command(path, schedule.end_cycle, *options, firmware=firmware),
        capture_output=True,
        timeout=600,
        check=False,
    )
    if result.returncode != 0:
        raise RuntimeError(f"turret_hil exited {result.returncode}: {result.stderr.decode(errors='replace')}")
    summary = next(
        line
        for line in result.stderr.decode(errors="replace").splitlines()
        if line.startswith("turret_hil: cycles")
    )
    log = np.fromfile(log_path, np.dtype([("cycle", "<u8"), ("byte", "u1")])) if log_path else np.empty(0)
    return result.stdout, summary, log


def step_toggles(
    duration_s: float, workdir: pathlib.Path, firmware: pathlib.Path = FIRMWARE_ELF
) -> np.ndarray:
    """The CPU cycles at which the STEP pin (PB3) changed level during duration_s from reset."""
    schedule = workdir / "no_edges.bin"
    schedule.write_bytes(b"")
    log = workdir / "steps.bin"
    command = harness_command(schedule, round(duration_s * CPU_HZ), "--step-log", log, firmware=firmware)
    result = subprocess.run(command, capture_output=True, timeout=600, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"turret_hil exited {result.returncode}: {result.stderr.decode(errors='replace')}")
    # simavr notifies the pin twice per toggle (the timer's output, then the port): one change per cycle
    return np.unique(np.fromfile(log, "<u8"))
