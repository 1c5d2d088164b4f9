"""The turret firmware in simavr: emulation speed, edge-to-host latency, the most edges a
revolution carries before the firmware drops some at 500000 baud, and the image's flash and RAM.

Needs `make hil` (firmware/build/turret.elf and the simavr harness).
"""

import math
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

import numpy as np

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_driver.serial_protocol import FRAME_SIZE, HELLO_SIZE, EventKind, FrameParser
from beams_sim.world import EurobotTrajectory

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "test" / "hil"))
import turret_hil
from rows_table import Row, bench_main

SPEED_TURRET_S = 21.0
LATENCY_TURRET_S = 5.0
# simavr 1.6 times a byte as 11 bits (it counts a parity bit even with none); the chip sends 10 (8N1).
EMULATED_BITS_PER_BYTE = 11
BAUD = 500_000
BEAM_SIGMAS_DEG = np.arange(5.0, 14.01, 0.25)


def _revolutions(duration_s: float, seed: int, **config: object):
    trajectory = EurobotTrajectory.random(seed=seed)
    return turret_hil.simulate(duration_s, trajectory.pose_at, seed, EUROBOT_BEACON_MAP, **config)


def emulation_speed(workdir: pathlib.Path) -> tuple[float, float]:
    """(x real time, mean edges per revolution) of 21 s of turret time, nominal load."""
    revolutions = _revolutions(SPEED_TURRET_S, seed=3)
    schedule = turret_hil.schedule_of(revolutions)
    _, summary, _ = turret_hil.run_harness(schedule, workdir)
    wall_s = float(re.search(r"wall_s ([0-9.]+)", summary).group(1))
    emulated_s = schedule.end_cycle / turret_hil.CPU_HZ
    return emulated_s / wall_s, float(np.mean([r.n_edges for r in revolutions]))


def _frames(stream: bytes) -> tuple[list[int], list[int]]:
    """(kind, index of the last byte) of every frame of a clean stream (the emulator's)."""
    kinds, ends, offset = [], [], 0
    while offset + 2 < len(stream):
        kind = stream[offset + 2]
        offset += HELLO_SIZE if kind == EventKind.HELLO else FRAME_SIZE
        kinds.append(kind)
        ends.append(offset - 1)
    return kinds, ends


def latencies(workdir: pathlib.Path) -> tuple[np.ndarray, np.ndarray]:
    """Edge to last byte on the wire (emulated cycles), and edge to the host's read (real-time mode:
    the pipe's arrival times, aligned on the least-delayed frame), in seconds, per receiver edge."""
    schedule = turret_hil.schedule_of(_revolutions(LATENCY_TURRET_S, seed=4))
    path = schedule.write(workdir / "latency.bin")
    log_path = workdir / "latency_bytes.bin"
    read_end, write_end = os.pipe()
    options = ("--out-fd", write_end, "--byte-log", log_path, "--realtime")
    command = turret_hil.harness_command(path, schedule.end_cycle, *options)
    harness = subprocess.Popen(command, pass_fds=(write_end,), stderr=subprocess.DEVNULL)
    os.close(write_end)
    arrivals: list[tuple[int, float]] = []  # (bytes received so far, wall time)
    received = bytearray()
    while chunk := os.read(read_end, 65536):
        received += chunk
        arrivals.append((len(received), time.monotonic()))
    os.close(read_end)
    harness.wait(timeout=60)
    log = np.fromfile(log_path, np.dtype([("cycle", "<u8"), ("byte", "u1")]))
    bytes_on_wire_s = EMULATED_BITS_PER_BYTE / BAUD
    kinds, ends = _frames(bytes(received))
    sent_s = log["cycle"][ends] / turret_hil.CPU_HZ + bytes_on_wire_s  # each frame's last stop bit
    arrival_counts = np.array([n for n, _ in arrivals])
    arrival_s = np.array([t for _, t in arrivals])[np.searchsorted(arrival_counts, np.array(ends) + 1)]
    host_s = arrival_s - sent_s
    host_s -= host_s.min()  # the least-delayed frame sets the clocks' offset
    events = [i for i, k in enumerate(kinds) if k in (EventKind.RISING, EventKind.FALLING)]
    edge_cycles = np.array(
        [c for c, k in zip(schedule.cycles, schedule.kinds, strict=True) if k != EventKind.ZERO_REFERENCE]
    )
    wire_s = sent_s[events] - edge_cycles / turret_hil.CPU_HZ
    return wire_s, wire_s + host_s[events]


def edges_before_loss(workdir: pathlib.Path) -> tuple[float, float]:
    """(mean, largest) edges per revolution of the widest beam with no event dropped, 3 s each."""
    best = (0.0, 0.0)
    for sigma_deg in BEAM_SIGMAS_DEG:
        revolutions = _revolutions(3.0, seed=9, beam_sigma_rad=math.radians(sigma_deg))
        data, _, _ = turret_hil.run_harness(turret_hil.schedule_of(revolutions), workdir)
        parser = FrameParser()
        parser.feed(data)
        if parser.drops["lost_frames"] or parser.device.dropped_events:
            break
        counts = [r.n_edges for r in revolutions]
        best = (float(np.mean(counts)), float(max(counts)))
    return best


def image_size() -> tuple[int, int]:
    """(flash bytes: text + data, RAM bytes: data + bss) of firmware/build/turret.elf."""
    output = subprocess.run(
        ["avr-size", str(turret_hil.FIRMWARE_ELF)], capture_output=True, text=True, check=True
    )
    text, data, bss = (int(v) for v in output.stdout.splitlines()[1].split()[:3])
    return text + data, data + bss


def rows() -> list[Row]:
    why = turret_hil.missing()
    if why:
        raise RuntimeError(why)
    with tempfile.TemporaryDirectory() as directory:
        workdir = pathlib.Path(directory)
        speed, edges_per_revolution = emulation_speed(workdir)
        wire_s, host_s = latencies(workdir)
        mean_edges, max_edges = edges_before_loss(workdir)
    flash, ram = image_size()
    link_frames = BAUD / 10 / FRAME_SIZE / 10.0
    emulated_frames = BAUD / EMULATED_BITS_PER_BYTE / FRAME_SIZE / 10.0
    return [
        (
            "simavr emulation speed, turret firmware (16 MHz ATmega328P)",
            speed,
            "x real time",
            f"{SPEED_TURRET_S:.0f} s of turret time, {edges_per_revolution:.0f} edges per revolution",
        ),
        *(
            (f"edge to {where}, p{percent}", float(np.percentile(delays_s, percent)) * 1e3, "ms", compared)
            for where, delays_s, percent, compared in (
                ("last byte on the wire", wire_s, 50, "frame: 10 bytes = 0.2 ms"),
                ("last byte on the wire", wire_s, 99, "queue of 128 events"),
                ("host read (real-time mode, pipe)", host_s, 50, "turret period 100 ms"),
                ("host read (real-time mode, pipe)", host_s, 99, "turret period 100 ms"),
            )
        ),
        (
            "edges per revolution without loss at 500000 baud (mean, widest beam)",
            mean_edges,
            "edges",
            f"largest revolution {max_edges:.0f}; link {link_frames:.0f} frames/rev "
            f"({emulated_frames:.0f} in simavr)",
        ),
        ("turret firmware flash", flash, "bytes", "ATmega328P: 32768 (30720 with the Arduino bootloader)"),
        ("turret firmware RAM (data + bss)", ram, "bytes", "ATmega328P: 2048; stack gets the rest"),
    ]


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
