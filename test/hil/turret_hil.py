"""The turret firmware in simavr, driven by the project's edge-level simulator (issue 20).

The schedule of pin levels and the harness's command line are beams_sim.virtual_turret's (the virtual
turret runs the same in real time); `run_harness` runs firmware/build/turret.elf under
test/hil/turret_hil.c (built by `make hil`) with a schedule and returns what the UART sent. Used by
test/dds/test_firmware_hil.py and bench/bench_firmware.py.
"""

import os
import pathlib
import subprocess
from collections.abc import Sequence

import numpy as np

from beams_driver.edges import RevolutionEdges
from beams_driver.serial_protocol import EventKind
from beams_sim import virtual_turret
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator
from beams_sim.virtual_turret import (  # noqa: F401 (the tests' and the bench's names)
    CPU_HZ,
    CYCLES_PER_TICK,
    PERIOD_S,
    PIN_RECEIVER,
    PIN_ZERO_REFERENCE,
    RECORD,
    START_CYCLE,
    TICKS_PER_REVOLUTION,
    TIMER_HZ,
    ZERO_PULSE_S,
    Schedule,
    cycle_of,
    schedule_of,
    turret_config,
)

ROOT = pathlib.Path(__file__).resolve().parents[2]
FIRMWARE_ELF = ROOT / "firmware" / "build" / "turret.elf"
HARNESS = pathlib.Path(os.environ.get("BEAMS_HIL_HARNESS", ROOT / "build" / "hil" / "turret_hil"))


def missing() -> str:
    """Why the HIL tests cannot run here ("" when they can)."""
    return virtual_turret.missing(HARNESS, FIRMWARE_ELF)


def simulate(
    duration_s: float, pose_at, seed: int, config: SensorSimConfig, beacons
) -> list[RevolutionEdges]:
    """The revolutions of duration_s of turret time, the first opened at 0 s."""
    simulator = SensorSimulator(config, beacons, np.random.default_rng(seed))
    count = int(duration_s / config.period_s)
    return [simulator.revolution(pose_at, k * config.period_s) for k in range(count)]


def receiver_schedule(cycles: np.ndarray, rising: np.ndarray, zero_cycles: Sequence[int] = ()) -> Schedule:
    """Levels on the receiver's pin at these cycles (it starts low), and zero references (pulses on the
    switch's pin) opening at zero_cycles."""
    order = np.argsort(cycles, kind="stable")
    cycles, rising = np.asarray(cycles, dtype=np.int64)[order], np.asarray(rising, dtype=bool)[order]
    zero_cycles = np.asarray(zero_cycles, dtype=np.int64)
    pins = np.concatenate([[PIN_RECEIVER, PIN_ZERO_REFERENCE], np.full(cycles.size, PIN_RECEIVER)])
    pins = np.concatenate([pins, np.full(2 * zero_cycles.size, PIN_ZERO_REFERENCE)])
    pulse = round(ZERO_PULSE_S * CPU_HZ)
    at = np.concatenate([[START_CYCLE // 2] * 2, cycles, zero_cycles, zero_cycles + pulse])
    levels = np.concatenate([[0, 0], rising, np.ones(zero_cycles.size), np.zeros(zero_cycles.size)])
    records = np.zeros(at.size, RECORD)
    records_order = np.argsort(at, kind="stable")
    records["cycle"], records["pin"], records["level"] = (
        at[records_order],
        pins[records_order],
        levels[records_order],
    )
    captures = np.concatenate([cycles, zero_cycles])
    kinds = [EventKind.RISING if r else EventKind.FALLING for r in rising.tolist()]
    kinds += [EventKind.ZERO_REFERENCE] * zero_cycles.size
    capture_order = np.argsort(captures, kind="stable")
    return Schedule(
        records, [kinds[i] for i in capture_order], captures[capture_order], int(at.max()) + CPU_HZ // 20
    )


def harness_command(
    schedule_path: pathlib.Path, end_cycle: int, *, firmware: pathlib.Path = FIRMWARE_ELF, **options: object
) -> list[str]:
    return virtual_turret.harness_command(HARNESS, firmware, schedule_path, end_cycle, **options)


def run_harness(
    schedule: Schedule, workdir: pathlib.Path, byte_log: bool = False, firmware: pathlib.Path = FIRMWARE_ELF
) -> tuple[bytes, str, np.ndarray]:
    """Run the firmware over the schedule as fast as simavr goes: (UART bytes, summary line, byte log
    records (cycle, byte) or an empty array)."""
    path = schedule.write(workdir / "schedule.bin")
    log_path = workdir / "bytes.bin" if byte_log else None
    result = subprocess.run(
        harness_command(path, schedule.end_cycle, byte_log=log_path, firmware=firmware),
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
    command = harness_command(schedule, round(duration_s * CPU_HZ), firmware=firmware, step_log=log)
    result = subprocess.run(command, capture_output=True, timeout=600, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"turret_hil exited {result.returncode}: {result.stderr.decode(errors='replace')}")
    # simavr notifies the pin twice per toggle (the timer's output, then the port): one change per cycle
    return np.unique(np.fromfile(log, "<u8"))
