"""The beacon firmware (firmware/beacon) run in simavr and decoded by the project's own decoder.

The shipped image, firmware/build/beacon.elf (no simulator-only build flag), runs on simavr's
ATmega328P at 16 MHz with its code-selection jumpers (PC0..PC3) set by the harness; the harness prints
every transition of the envelope output OC1A at the cycle of its compare match. Checked, for every code
of the family (eq. 2.6): each burst and gap lasts its bits times the bit time T_b = 30.8 us within one
Timer1 tick (1/16 MHz), the edges never drift from the bit grid, and the edges a turret sees through a
window spanning the beacon (the ideal receiver: code AND window, section 3.2) decode as that code and
as no other (beams_driver.decoder.BearingDecoder, the decoder every edge source feeds). Figures (code
period, timing error): `make test PYTEST_ARGS="test/test_beacon_firmware.py -s -q"`.
"""

import ctypes.util
import math
import pathlib
import re
import shutil
import subprocess
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import pytest

from beams_driver.codes import BIT_TIME_S, BeaconCode, code_family, codes_from_strings
from beams_driver.decoder import BearingDecoder, DecodedRevolution
from beams_driver.edges import TURRET_PERIOD_S, TURRET_SPEED_RAD_S, RevolutionEdges

ROOT = pathlib.Path(__file__).resolve().parents[1]
BEACON_SOURCE_DIR = ROOT / "firmware" / "beacon"
SHIPPED_BUILD_DIR = ROOT / "firmware" / "build"
CPU_HZ = 16_000_000
TIMER_TICK_S = 1.0 / CPU_HZ
BIT_CYCLES = BIT_TIME_S * CPU_HZ
# 300 ms of beacon time: 811 periods of a 12-bit code, longer than the 250 ms watchdog (a reset would
# break the bit grid) and three blinks of the LED.
SIMULATED_CYCLES = 300 * CPU_HZ // 1000
SELECT_PINS = ("C0", "C1", "C2", "C3")
ENVELOPE_PIN = "B1"
ENVELOPE_COMPARE = "1A"
LED_PIN = "B5"
# The turret's window over the beacon: 3.75 code periods (5 deg at 10 turns/s for a 12-bit code, so
# that two complete codes always lie inside, section 2.5.2), swept over one code period in 41 steps.
WINDOW_CODE_PERIODS = 3.75
WINDOW_PHASES = 41
FAMILY = code_family()
# Thesis section 5.3's C5b, a test code with 2-bit gaps: the custom-code build.
CUSTOM_BITS = "11111001111100"


def _missing_tools() -> str | None:
    """Why the firmware cannot be built and emulated here, or None."""
    for tool in ("make", "cc", "avr-gcc", "avr-objcopy", "avr-size"):
        if shutil.which(tool) is None:
            return f"{tool} not found (apt-get install gcc-avr avr-libc simavr libsimavr-dev)"
    if not pathlib.Path("/usr/include/simavr/sim_avr.h").exists():
        return "simavr headers missing (/usr/include/simavr/sim_avr.h; apt-get install libsimavr-dev)"
    if ctypes.util.find_library("simavr") is None:
        return "libsimavr not found (apt-get install libsimavr-dev)"
    return None


def _make(*arguments: str) -> str:
    """Run the beacon's Makefile; its output (avr-size's report, say)."""
    completed = subprocess.run(
        ["make", "--no-print-directory", "-C", str(BEACON_SOURCE_DIR), *arguments],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert completed.returncode == 0, completed.stdout + completed.stderr
    return completed.stdout


@pytest.fixture(scope="module")
def shipped_build() -> pathlib.Path:
    """firmware/build with the shipped beacon image and the simavr harness, built by the Makefile."""
    reason = _missing_tools()
    if reason is not None:
        pytest.skip(reason)
    _make("all", "sim")
    return SHIPPED_BUILD_DIR


@dataclass(frozen=True)
class BeaconTrace:
    """What the harness saw: the envelope's compare-match transitions, its pin, the LED, the registers."""

    edge_cycles: np.ndarray
    edge_levels: np.ndarray
    pin_cycles: np.ndarray
    pin_levels: np.ndarray
    led_cycles: np.ndarray
    registers: dict[str, int]

    @property
    def edge_times_s(self) -> np.ndarray:
        return self.edge_cycles / CPU_HZ


def _jumpers(code_index: int) -> list[str]:
    """The pins jumpered to GND for a family index: bit k of the index on PCk."""
    return [pin for bit, pin in enumerate(SELECT_PINS) if code_index >> bit & 1]


def run_beacon(build_dir: pathlib.Path, elf: pathlib.Path, jumpered: Iterable[str]) -> BeaconTrace:
    """Run an image in simavr for SIMULATED_CYCLES with the given pins held at 0 (jumpers to GND)."""
    command = [str(build_dir / "beacon_sim"), "-f", str(elf), "-n", str(SIMULATED_CYCLES)]
    command += ["-o", ENVELOPE_COMPARE, "-w", ENVELOPE_PIN, "-w", LED_PIN]
    for pin in jumpered:
        command += ["-d", f"{pin}=0"]
    completed = subprocess.run(command, capture_output=True, text=True, timeout=60, check=True)
    rows = [line.split() for line in completed.stdout.splitlines()]
    end = next(row for row in rows if row[0] == "end")
    assert int(end[1]) >= SIMULATED_CYCLES, completed.stdout[-500:]

    def transitions(kind: str, name: str) -> tuple[np.ndarray, np.ndarray]:
        chosen = [(int(r[2]), int(r[3])) for r in rows if r[0] == kind and r[1] == name]
        # The harness reports changes only, but a pin's reset level once at start-up: not an edge.
        kept = chosen[1:] if chosen and chosen[0][1] == 0 else chosen
        array = np.array(kept, dtype=np.int64).reshape(-1, 2)
        return array[:, 0], array[:, 1]

    edge_cycles, edge_levels = transitions("compare", ENVELOPE_COMPARE)
    pin_cycles, pin_levels = transitions("pin", ENVELOPE_PIN)
    led_cycles, _ = transitions("pin", LED_PIN)
    registers = {r[1]: int(r[2]) for r in rows if r[0] == "register"}
    return BeaconTrace(edge_cycles, edge_levels, pin_cycles, pin_levels, led_cycles, registers)


@dataclass(frozen=True)
class TimingError:
    """How far the emitted edges are from the ideal code (cycles of 1/16 MHz)."""

    max_run_error_cycles: float
    max_edge_drift_cycles: float
    code_period_s: float


def timing_error(trace: BeaconTrace, code: BeaconCode) -> TimingError:
    """Burst and gap durations against their bit counts times T_b, and every edge against the bit grid
    started at the first one; the mean code period over the whole trace."""
    assert trace.edge_levels[0] == 1, "the first edge must start a burst"
    assert np.all(np.diff(trace.edge_levels) != 0), "edges must alternate"
    run_bits = np.array([n for _, n in code.runs_bits])
    runs = trace.edge_cycles.size - 1
    ideal_bits = np.concatenate([[0], np.cumsum(np.resize(run_bits, runs))])
    drift = (trace.edge_cycles - trace.edge_cycles[0]) - ideal_bits * BIT_CYCLES
    run_error = np.diff(trace.edge_cycles) - np.diff(ideal_bits) * BIT_CYCLES
    periods = runs // run_bits.size
    period_cycles = (trace.edge_cycles[periods * run_bits.size] - trace.edge_cycles[0]) / periods
    return TimingError(float(np.max(np.abs(run_error))), float(np.max(np.abs(drift))), period_cycles / CPU_HZ)


class _NoVariance:
    """The decoder's variance source: this test checks identities and angles, not variances."""

    def variance(self, code: int | BeaconCode, angular_window_rad: float) -> float:
        return 0.0


def _window_edges(trace: BeaconTrace, start_s: float, end_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The ideal receiver's output through the window [start_s, end_s]: code AND window (section 3.2)."""
    times, rising = trace.edge_times_s, trace.edge_levels == 1
    before_start = np.searchsorted(times, start_s, side="right") - 1
    before_end = np.searchsorted(times, end_s, side="right") - 1
    inside = slice(before_start + 1, before_end + 1)
    on_at_start = int(before_start >= 0 and rising[before_start])
    on_at_end = int(before_end >= 0 and rising[before_end])
    edge_times = np.concatenate([[start_s] * on_at_start, times[inside], [end_s] * on_at_end])
    edge_rising = np.concatenate([[True] * on_at_start, rising[inside], [False] * on_at_end])
    return edge_times, edge_rising


def decode_windows(trace: BeaconTrace, codes: Sequence[BeaconCode]) -> list[DecodedRevolution]:
    """One turret revolution per window phase, the window centred at 90 deg, decoded in order."""
    decoder = BearingDecoder(codes, _NoVariance())
    period_s = max(c.duration_s for c in codes)
    window_s = WINDOW_CODE_PERIODS * period_s
    first_start_s = trace.edge_times_s[0] + period_s
    assert first_start_s + period_s + window_s < trace.edge_times_s[-1], "trace too short"
    decoded = []
    for revolution, phase in enumerate(np.linspace(0.0, period_s, WINDOW_PHASES)):
        start_s = first_start_s + phase
        times, rising = _window_edges(trace, start_s, start_s + window_s)
        zero_reference_s = start_s + 0.5 * window_s - 0.25 * TURRET_PERIOD_S
        angles = (times - zero_reference_s) * TURRET_SPEED_RAD_S
        edges = RevolutionEdges(revolution, zero_reference_s, TURRET_PERIOD_S, times, angles, rising)
        decoded.append(decoder.decode(edges))
    return decoded


def assert_decodes_only_as(trace: BeaconTrace, code: BeaconCode, codes: Sequence[BeaconCode]) -> None:
    """Every window gives one bearing, of this code, within phi0 / 2 of the beacon (section 2.5.2); a
    decoder that knows every code but this one finds nothing."""
    decoded = decode_windows(trace, codes)
    identities = [[b.beacon_id for b in r.bearings] for r in decoded]
    assert identities == [[code.code_id]] * WINDOW_PHASES, [r.rejections for r in decoded]
    assert min(b.codes_seen for r in decoded for b in r.bearings) >= 2
    # The largest bearing error: half the longest gap's angle, plus the edges' rounding to a cycle.
    max_error_rad = 0.5 * (max(code.gap_bits) * code.bit_time_s + TIMER_TICK_S) * TURRET_SPEED_RAD_S
    errors = [abs(r.bearings[0].bearing - 0.5 * math.pi) for r in decoded]
    assert max(errors) <= max_error_rad, (max(errors), max_error_rad)
    others = [c for c in codes if c.code_id != code.code_id]
    if others:
        wrong = [b for r in decode_windows(trace, others) for b in r.bearings]
        assert wrong == [], f"code {code.code_id} decoded as {[b.beacon_id for b in wrong]}"


def assert_timing(trace: BeaconTrace, code: BeaconCode) -> TimingError:
    """Durations within one Timer1 tick, no drift, the period N_b T_b; the pin follows the compares."""
    error = timing_error(trace, code)
    assert error.max_run_error_cycles < 1.0, f"a burst or gap off by {error.max_run_error_cycles} cycles"
    assert error.max_edge_drift_cycles < 1.0, (
        f"an edge off the bit grid by {error.max_edge_drift_cycles} cycles"
    )
    assert error.code_period_s == pytest.approx(code.duration_s, abs=TIMER_TICK_S / 10)
    # simavr notices the pin's change at the end of the sleep step passing the match: 0 or 1 cycle late.
    np.testing.assert_array_equal(trace.pin_levels, trace.edge_levels)
    lateness = trace.pin_cycles - trace.edge_cycles
    assert lateness.min() >= 0 and lateness.max() <= 1
    return error


@pytest.mark.parametrize("code", FAMILY, ids=lambda c: f"C{c.code_id}")
def test_shipped_image_emits_the_jumpered_family_code(shipped_build: pathlib.Path, code: BeaconCode) -> None:
    trace = run_beacon(shipped_build, shipped_build / "beacon.elf", _jumpers(code.code_id))
    error = assert_timing(trace, code)
    assert_decodes_only_as(trace, code, FAMILY)
    assert trace.led_cycles.size == 1  # on, steadily, while emitting
    print(
        f"code {code.code_id} ({code}) | period {error.code_period_s * 1e6:.4f} us "
        f"(N_b T_b {code.duration_s * 1e6:.4f} us) | burst/gap error max "
        f"{error.max_run_error_cycles / CPU_HZ * 1e9:.1f} ns | edge drift max "
        f"{error.max_edge_drift_cycles / CPU_HZ * 1e9:.1f} ns | {trace.edge_cycles.size} edges"
    )


@pytest.mark.parametrize("jumpered", [(), SELECT_PINS], ids=["no jumper (0)", "all jumpers (15)"])
def test_a_code_outside_the_family_keeps_the_beacon_dark(
    shipped_build: pathlib.Path, jumpered: tuple[str, ...]
) -> None:
    trace = run_beacon(shipped_build, shipped_build / "beacon.elf", jumpered)
    assert trace.edge_cycles.size == 0 and trace.pin_cycles.size == 0
    # The LED blinks: toggled every 100 ms.
    assert trace.led_cycles.size == 3
    np.testing.assert_allclose(np.diff(trace.led_cycles) / CPU_HZ, 0.1, rtol=1e-3)


def test_carrier_is_457_khz_on_oc0b(shipped_build: pathlib.Path) -> None:
    """The carrier's registers (simavr 1.6 ignores OCR0A as TOP in fast PWM: its frequency is read from
    the registers, against the datasheet's fast-PWM formula F_CPU / (TOP + 1))."""
    registers = run_beacon(shipped_build, shipped_build / "beacon.elf", _jumpers(1)).registers
    assert registers["TCCR0A"] & 0b11 == 0b11 and registers["TCCR0B"] & 0b1000  # WGM 7: TOP = OCR0A
    assert registers["TCCR0B"] & 0b111 == 0b001  # no prescaler
    assert registers["TCCR0A"] >> 4 & 0b11 == 0b10  # OC0B non-inverting
    assert registers["DDRD"] >> 5 & 1 == 1  # PD5 (OC0B) is an output
    carrier_hz = CPU_HZ / (registers["OCR0A"] + 1)
    # The TSOP7000's 455 kHz (section 2.4.4); its band-pass takes a few percent off the centre.
    assert carrier_hz == pytest.approx(455e3, rel=0.005)
    assert (registers["OCR0B"] + 1) / (registers["OCR0A"] + 1) == pytest.approx(0.5, abs=0.03)


def _build_variant(directory: pathlib.Path, *settings: str) -> pathlib.Path:
    """An image built with extra Makefile settings (BEACON_CODE=3, say) into its own directory."""
    _make("all", f"BUILD_DIR={directory}", *settings)
    return directory / "beacon.elf"


def test_larger_family_by_jumpers(shipped_build: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """BEACON_CODE_COUNT=7: C_6 of the 7-code family (16 bits), chosen by jumpers on PC1 and PC2."""
    elf = _build_variant(tmp_path, "BEACON_CODE_COUNT=7")
    family = code_family(7)
    trace = run_beacon(shipped_build, elf, _jumpers(6))
    assert_timing(trace, family[5])
    assert_decodes_only_as(trace, family[5], family)


def test_compile_time_code_ignores_the_jumpers(shipped_build: pathlib.Path, tmp_path: pathlib.Path) -> None:
    elf = _build_variant(tmp_path, "BEACON_CODE=3")
    trace = run_beacon(shipped_build, elf, _jumpers(1))
    code = FAMILY[2]
    assert_timing(trace, code)
    assert_decodes_only_as(trace, code, FAMILY)


def test_custom_code_is_sent_as_written(shipped_build: pathlib.Path, tmp_path: pathlib.Path) -> None:
    elf = _build_variant(tmp_path, f"BEACON_BITS={CUSTOM_BITS}")
    trace = run_beacon(shipped_build, elf, ())
    (custom,) = codes_from_strings([CUSTOM_BITS])
    assert_timing(trace, custom)
    assert_decodes_only_as(trace, custom, [custom])
    # Its 2-bit gaps are no family code's: a decoder of the family finds no beacon in it.
    assert [b for r in decode_windows(trace, FAMILY) for b in r.bearings] == []


def test_image_fits_the_board(shipped_build: pathlib.Path) -> None:
    """Flash and RAM from avr-size: under the 32 KiB less the 0.5 KiB bootloader, and the 2 KiB RAM."""
    report = _make("size")
    flash_bytes = int(re.search(r"Program:\s+(\d+) bytes", report).group(1))
    ram_bytes = int(re.search(r"Data:\s+(\d+) bytes", report).group(1))
    assert 0 < flash_bytes <= 32 * 1024 - 512
    assert 0 < ram_bytes <= 2048 - 256  # room for the stack
    print(f"beacon.elf | flash {flash_bytes} bytes | RAM {ram_bytes} bytes (static, before the stack)")


def test_missing_tools_are_named(monkeypatch: pytest.MonkeyPatch) -> None:
    """The skip reason names what is missing (the tools' absence simulated with an empty PATH)."""
    monkeypatch.setenv("PATH", "")
    assert (_missing_tools() or "").startswith("make not found")
