"""The turret firmware in simavr, driven by the project's edge-level simulator (issue 20).

`schedule_of(revolutions)` turns simulated revolutions into pin levels at exact CPU cycles (the receiver
on PB0 = ICP1, the zero reference on PD2 = INT0); `run_harness` runs firmware/build/turret.elf under
test/hil/turret_hil.c (built by `make hil`) with that schedule and returns what the UART sent. Used by
test/dds/test_firmware_hil.py and bench/bench_firmware.py.
"""

import os
import pathlib
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from beams_driver.edges import RevolutionEdges
from beams_driver.serial_protocol import FIRMWARE_TICKS_PER_REVOLUTION, FIRMWARE_TIMER_HZ, EventKind
from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator

ROOT = pathlib.Path(__file__).resolve().parents[2]
FIRMWARE_ELF = ROOT / "firmware" / "build" / "turret.elf"
HARNESS = pathlib.Path(os.environ.get("BEAMS_HIL_HARNESS", ROOT / "build" / "hil" / "turret_hil"))
CPU_HZ = 16_000_000
TIMER_HZ = FIRMWARE_TIMER_HZ  # what its hello says
CYCLES_PER_TICK = CPU_HZ // TIMER_HZ
TICKS_PER_REVOLUTION = FIRMWARE_TICKS_PER_REVOLUTION  # 800 microsteps x 2 x 125 ticks: 10 turn/s
PERIOD_S = TICKS_PER_REVOLUTION / TIMER_HZ
# The firmware's boot (set-up, the boot hello) is over long before the first injected level.
START_CYCLE = CPU_HZ // 20
ZERO_PULSE_S = 50e-6  # how long the optical switch stays on
PIN_RECEIVER, PIN_ZERO_REFERENCE = 0, 1
_RECORD = np.dtype([("cycle", "<u8"), ("pin", "u1"), ("level", "u1"), ("pad", "V6")])


def missing() -> str:
    """Why the HIL tests cannot run here ("" when they can)."""
    if not FIRMWARE_ELF.exists():
        return f"{FIRMWARE_ELF} is not built (make firmware; avr-gcc from scripts/bootstrap.sh)"
    if not HARNESS.exists():
        return f"{HARNESS} is not built (make hil; libsimavr-dev from scripts/bootstrap.sh)"
    return ""


def turret_config(**overrides: object) -> SensorSimConfig:
    """The thesis-hardware receiver on the firmware's clock: 0.1 s turns captured on 0.5 us ticks."""
    return SensorSimConfig.thesis_hardware(period_s=PERIOD_S, tick_s=1.0 / TIMER_HZ, **overrides)


def simulate(
    duration_s: float, pose_at, seed: int, config: SensorSimConfig, beacons
) -> list[RevolutionEdges]:
    """The revolutions of duration_s of turret time, the first opened at 0 s."""
    simulator = SensorSimulator(config, beacons, np.random.default_rng(seed))
    count = int(duration_s / config.period_s)
    return [simulator.revolution(pose_at, k * config.period_s) for k in range(count)]


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


def schedule_of(revolutions: Sequence[RevolutionEdges]) -> Schedule:
    """Each revolution's zero reference (a pulse on INT0) and its receiver edges (levels on ICP1), and the
    closing zero reference of the last one."""
    last = revolutions[-1]
    zero_times = [r.start_time_s for r in revolutions] + [last.start_time_s + last.period_s]
    edge_times = np.concatenate([r.edge_times_s for r in revolutions])
    edge_rising = np.concatenate([r.edge_rising for r in revolutions])
    zero_cycles = cycle_of(zero_times)
    edge_cycles = cycle_of(edge_times)
    pins = np.concatenate(
        [np.full(2 * zero_cycles.size, PIN_ZERO_REFERENCE), np.full(edge_cycles.size, PIN_RECEIVER)]
    )
    cycles = np.concatenate([zero_cycles, zero_cycles + round(ZERO_PULSE_S * CPU_HZ), edge_cycles])
    levels = np.concatenate([np.ones(zero_cycles.size), np.zeros(zero_cycles.size), edge_rising])
    # the pins' levels before the first event (the receiver is high if its first edge falls), set once the
    # firmware runs, whatever simavr made of its port set-up
    receiver_level = int(edge_rising.size > 0 and not edge_rising[0])
    pins = np.concatenate([[PIN_RECEIVER, PIN_ZERO_REFERENCE], pins])
    cycles = np.concatenate([[START_CYCLE // 2] * 2, cycles])
    levels = np.concatenate([[receiver_level, 0], levels])
    order = np.argsort(cycles, kind="stable")
    records = np.zeros(cycles.size, _RECORD)
    records["cycle"], records["pin"], records["level"] = cycles[order], pins[order], levels[order]
    capture_cycles = np.concatenate([zero_cycles, edge_cycles])
    kinds = [EventKind.ZERO_REFERENCE] * zero_cycles.size + [
        EventKind.RISING if rising else EventKind.FALLING for rising in edge_rising.tolist()
    ]
    if receiver_level:  # the firmware armed for a rising edge at boot, and sees this one
        capture_cycles = np.concatenate([[START_CYCLE // 2], capture_cycles])
        kinds = [EventKind.RISING, *kinds]
    capture_order = np.argsort(capture_cycles, kind="stable")
    return Schedule(
        records,
        [kinds[i] for i in capture_order],
        capture_cycles[capture_order],
        int(cycles.max()) + CPU_HZ // 20,
    )


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
    records = np.zeros(at.size, _RECORD)
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
    schedule_path: pathlib.Path,
    end_cycle: int,
    *,
    out_fd: int | None = None,
    byte_log: pathlib.Path | None = None,
    realtime: bool = False,
    firmware: pathlib.Path = FIRMWARE_ELF,
    step_log: pathlib.Path | None = None,
) -> list[str]:
    command = [str(HARNESS), str(firmware), str(schedule_path), str(end_cycle)]
    if step_log is not None:
        command += ["--step-log", str(step_log)]
    if out_fd is not None:
        command += ["--out-fd", str(out_fd)]
    if byte_log is not None:
        command += ["--byte-log", str(byte_log)]
    if realtime:
        command.append("--realtime")
    return command


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
