"""Edge-level simulation of the BeAMS sensor (thesis section 2.4, with the departures of section 5.6).

`SensorSimulator.revolution` gives the edges the microcontroller captures in one turret revolution: the turret
driven by the 625 kHz capture timer, angles from the zero reference on the robot's x axis; each beacon's code
looped from a random phase (section 2.4.4); the window where the received power, 1/d^2 (eq. 2.7) over a
Gaussian beam, exceeds the threshold (eq. 2.4); code AND window OR-ed over beacons (compound windows, section
2.4.5) and stray-IR pulses. Two noise models: `SensorSimConfig()` (driver_node's `ideal`) and
`SensorSimConfig.thesis_hardware()` (sections 5.5-5.7). Chapter 7's imperfections (power and rotation biases,
turret offset, true beacon positions) are injected; the pose is taken at each window's edges."""

import math
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike

from beams_driver.codes import BeaconCode, bursts_in_window, code_family, first_last_edges
from beams_driver.edges import TIMER_HZ, TURRET_PERIOD_S, RevolutionEdges
from beams_driver.receiver import (
    THESIS_MIN_BURST_FRACTION,
    THESIS_MIN_BURST_GAP_EXPONENT,
    HardwareNoise,
    ReceiverModel,
)

PoseAt = Callable[[float], tuple[float, float, float]]
BiasFunction = Callable[[np.ndarray], np.ndarray]
Occlusion = Collection[int] | Callable[[int, float], bool]
# A pass centred this close to the zero reference may reach into the neighbouring revolution
# (half window plus the robot's turn in one revolution, with room to spare).
_PASS_MARGIN_RAD = 1.0
_FIXED_POINT_STEPS = 3
_TWO_PI = 2.0 * math.pi
# Generator(Philox(key)) anew costs 60 us (a SeedSequence drawn first): one generator is re-keyed per pass
_ZERO_COUNTER = np.zeros(4, dtype=np.uint64)
_FRESH_PHILOX = dict(bit_generator="Philox", buffer=_ZERO_COUNTER, buffer_pos=4, has_uint32=0, uinteger=0)


@dataclass(frozen=True)
class SensorSimConfig:
    """Parameters of the simulated sensor; defaults model the thesis's device on a Eurobot table.

    Beam: P_IR(phi) = P_r exp(-phi^2 / (2 beam_sigma^2)), P_r(d) / P_th = power_ratio_at_1m / d^2
    (eq. 2.7), so the window is 2 beam_sigma sqrt(2 ln(P_r / P_th)): about 8 deg at 1 m, 2.2 deg (about
    20 bits, section 2.5.1) at 6 m, nothing beyond 6.9 m.
    """

    codes: tuple[BeaconCode, ...] = field(default_factory=code_family)
    period_s: float = TURRET_PERIOD_S
    tick_s: float = 1.0 / TIMER_HZ
    beam_sigma_rad: float = float(np.radians(1.437))
    power_ratio_at_1m: float = 48.0
    min_burst_fraction: float = THESIS_MIN_BURST_FRACTION
    min_burst_gap_exponent: float = 1.0
    rising_noise_rad: float = float(np.radians(0.06))
    falling_noise_rad: float = float(np.radians(0.02))
    edge_jitter_s: float = 0.3e-6
    spurious_rate_hz: float = 0.0
    spurious_burst_s: tuple[float, float] = (15e-6, 150e-6)
    hardware: HardwareNoise | None = None

    def __post_init__(self) -> None:
        if not self.period_s > 0.0 or not self.tick_s > 0.0:
            raise ValueError("sensor sim: period_s and tick_s must be positive")
        if self.beam_sigma_rad <= 0.0 or self.power_ratio_at_1m <= 0.0:
            raise ValueError("sensor sim: beam_sigma_rad and power_ratio_at_1m must be positive")
        if min(self.rising_noise_rad, self.falling_noise_rad, self.edge_jitter_s, self.spurious_rate_hz) < 0:
            raise ValueError("sensor sim: noise levels and spurious rate must be >= 0")

    @classmethod
    def ideal(cls, **overrides: object) -> "SensorSimConfig":
        """The receiver of the theory (chapters 3-4): exact AND, no natural noise, no stray IR."""
        base = cls(min_burst_fraction=0.0, rising_noise_rad=0.0, falling_noise_rad=0.0, edge_jitter_s=0.0)
        return replace(base, **overrides)

    @classmethod
    def thesis_hardware(cls, **overrides: object) -> "SensorSimConfig":
        """The receiver the thesis measured (sections 5.5-5.7; driver_node's default `thesis_hardware`):
        `HardwareNoise.thesis_hardware()`'s edge noise and power bias instead of the constant outer-edge
        noise, and the minimum burst falling as sqrt(T_b / G), which reproduce table 5.1's experiment column.
        """
        base = cls(rising_noise_rad=0.0, falling_noise_rad=0.0, hardware=HardwareNoise.thesis_hardware())
        return replace(base, **{"min_burst_gap_exponent": THESIS_MIN_BURST_GAP_EXPONENT, **overrides})

    @property
    def receiver(self) -> ReceiverModel:
        """The simulated receiver's systematic behaviour, as the decoder and the variance model must know
        it (`ReceiverModel.thesis_hardware()` for `thesis_hardware()`)."""
        shortening = (
            self.hardware.modulation_shortening_rad / self.turret_speed_rad_s if self.hardware else 0.0
        )
        return ReceiverModel(self.min_burst_fraction, self.min_burst_gap_exponent, shortening)

    @property
    def turret_speed_rad_s(self) -> float:
        """omega (rad/s), eq. 2.1."""
        return 2.0 * np.pi / self.period_s

    @property
    def natural_variance_rad2(self) -> float:
        """Bearing variance the edge noise adds, (sigma_r^2 + sigma_f^2) / 4 (eq. 3.13, independent edges);
        with the hardware noise, its mean over the 1-6 m windows (C_k)."""
        if self.hardware is not None:
            windows = np.linspace(*self.hardware.window_range_rad, 101)
            return float(np.mean(self.hardware.natural_variance_rad2(windows, None)))
        return (self.rising_noise_rad**2 + self.falling_noise_rad**2) / 4.0

    def code(self, beacon_id: int) -> BeaconCode:
        """The code a beacon emits (its identifier is the code identifier)."""
        for code in self.codes:
            if code.code_id == beacon_id:
                return code
        raise KeyError(f"beacon {beacon_id} has no code in {[c.code_id for c in self.codes]}")

    def half_window_rad(self, distance_m: float, power_scale: float = 1.0) -> float:
        """Half angular window (rad) at distance d: where P_IR crosses the threshold; 0 when out of range."""
        ratio = power_scale * self.power_ratio_at_1m / max(distance_m, 1e-3) ** 2
        return self.beam_sigma_rad * math.sqrt(2.0 * math.log(max(ratio, 1.0)))

    def window_rad(self, distance_m: ArrayLike, power_scale: float = 1.0) -> np.ndarray | float:
        """True angular window phi_W = phi_F - phi_R (rad) at distance(s) d (figure 2.8)."""
        if np.ndim(distance_m) == 0:
            return 2.0 * self.half_window_rad(float(distance_m), power_scale)  # type: ignore[arg-type]
        window = np.vectorize(lambda d: 2.0 * self.half_window_rad(d, power_scale), otypes=[float])
        return window(np.asarray(distance_m, dtype=float))


@dataclass(frozen=True)
class SimulatedBeacon:
    """A beacon as it really stands: id (= its code), map position (m), emitted power / nominal."""

    beacon_id: int
    x_m: float
    y_m: float
    power_scale: float = 1.0


def beacons_from_map(beacon_map: object) -> tuple[SimulatedBeacon, ...]:
    """SimulatedBeacons from any object with `ids` and `xy` (n, 2), e.g. a BeaconMap."""
    xy = np.asarray(beacon_map.xy, dtype=float).reshape(-1, 2)  # type: ignore[attr-defined]
    ids = beacon_map.ids  # type: ignore[attr-defined]
    return tuple(SimulatedBeacon(int(i), float(x), float(y)) for i, (x, y) in zip(ids, xy, strict=True))


class SensorSimulator:
    """Simulated BeAMS sensor: `revolution(pose_at, start_time_s)` gives one revolution's edges."""

    def __init__(
        self,
        config: SensorSimConfig,
        beacons: Sequence[SimulatedBeacon] | object,
        rng: np.random.Generator,
        power_bias_rad: BiasFunction | None = None,
        rotation_bias_rad: BiasFunction | None = None,
        turret_offset_m: tuple[float, float] = (0.0, 0.0),
        *,
        occlusion: Occlusion | None = None,
    ) -> None:
        """beacons: true positions (SimulatedBeacons, or a BeaconMap-like object); power_bias_rad(window) and
        rotation_bias_rad(angle) are added to the bearing (eq. 7.17, 7.24); turret_offset_m is the turret
        centre in base_link; occlusion: a set of hidden ids or (beacon_id, time_s) -> hidden."""
        self.config = config
        self.beacons = tuple(beacons) if _is_beacon_sequence(beacons) else beacons_from_map(beacons)
        self._codes = [config.code(b.beacon_id) for b in self.beacons]
        self._rng = rng
        # Free-running beacons: each code starts from an independent random phase (section 2.4.4).
        self._phase_s = np.array([rng.uniform(0.0, code.duration_s) for code in self._codes])
        # Receiver noise of one pass is drawn from a key of (beacon, pass instant): a pass over the zero
        # reference, simulated in two revolutions, is the same pass in both.
        self._noise_key = int(rng.integers(0, 2**62))
        self._noise = np.random.Generator(np.random.Philox(key=[0, 0]))
        self._hardware_bias = config.hardware.power_bias_correction() if config.hardware else None
        self._power_bias = power_bias_rad
        self._rotation_bias = rotation_bias_rad
        self._turret_offset_m = (float(turret_offset_m[0]), float(turret_offset_m[1]))
        self.occlusion = occlusion
        self._revolution = 0
        # per pass: the config's derived values once, not a ReceiverModel built at each pass
        self._omega = config.turret_speed_rad_s
        self._min_burst_s = [config.receiver.min_burst_s(code) for code in self._codes]

    def revolution(self, pose_at: PoseAt, start_time_s: float) -> RevolutionEdges:
        """Edges captured during the revolution opened by the zero-reference pulse at start_time_s."""
        period = self.config.period_s
        intervals = [self._beacon_bursts(k, pose_at, start_time_s) for k in range(len(self.beacons))]
        intervals.append(self._spurious_bursts())
        # Relative times keep the capture arithmetic exact however long the run has lasted.
        starts = np.concatenate([s for s, _ in intervals])
        ends = np.concatenate([e for _, e in intervals])
        times_rel, rising = self._capture(starts, ends)
        edges = RevolutionEdges(
            revolution=self._revolution,
            start_time_s=float(start_time_s),
            period_s=period,
            edge_times_s=start_time_s + times_rel,
            edge_angles_rad=times_rel * self.config.turret_speed_rad_s,
            edge_rising=rising,
        )
        self._revolution += 1
        return edges

    def true_bearing(self, beacon_id: int, pose: tuple[float, float, float]) -> tuple[float, float]:
        """(bearing in [0, 2 pi), distance m) of a beacon from the turret centre, robot frame."""
        beacon = next(b for b in self.beacons if b.beacon_id == beacon_id)
        return self._view(beacon, pose)

    # ---- one beacon's window ----

    def _beacon_bursts(self, k: int, pose_at: PoseAt, t0: float) -> tuple[np.ndarray, np.ndarray]:
        """Bursts (s from t0, unclipped) of every pass of beacon k that can reach this revolution: near the
        zero reference, the tail of the pass around t0 and the head of the one around t0 + period, each at its
        own pose."""
        beacon = self.beacons[k]
        omega, period = self._omega, self.config.period_s
        bearing, _ = self._view(beacon, pose_at(t0 + 0.5 * period))
        cycles = [0.0]
        if bearing < _PASS_MARGIN_RAD:
            cycles.append(1.0)
        if bearing > 2.0 * np.pi - _PASS_MARGIN_RAD:
            cycles.append(-1.0)
        pieces = [self._pass_bursts(k, pose_at, t0, t0 + (bearing + 2.0 * np.pi * n) / omega) for n in cycles]
        return np.concatenate([s for s, _ in pieces]), np.concatenate([e for _, e in pieces])

    def _pass_bursts(
        self, k: int, pose_at: PoseAt, t0: float, t_guess: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Bursts (s from t0) of one pass of the turret over beacon k, the pass nearest t_guess."""
        beacon = self.beacons[k]
        window = self._window_times(beacon, pose_at, t0, t_guess)
        if window is None or self._occluded(beacon.beacon_id, 0.5 * (window[0] + window[1])):
            return np.empty(0), np.empty(0)
        code = self._codes[k]
        # Code time of instant t0 + r: the beacon's clock runs from its own phase.
        phase = (t0 + self._phase_s[k]) % code.duration_s
        pass_index = math.floor(0.5 * (window[0] + window[1]) / self.config.period_s)
        key = np.array([self._noise_key + k, pass_index % 2**63], dtype=np.uint64)
        self._noise.bit_generator.state = {**_FRESH_PHILOX, "state": {"counter": _ZERO_COUNTER, "key": key}}
        opens, closes = window
        if self.config.hardware is not None:  # the AGC's jitter of the threshold crossings (fig. 5.3)
            omega = self._omega
            rising_std, falling_std = self.config.hardware.edge_std_rad((closes - opens) * omega, code)
            opens += self._noise.normal(0.0, float(rising_std)) / omega
            closes += self._noise.normal(0.0, float(falling_std)) / omega
        starts, ends = bursts_in_window(code, opens - t0 + phase, closes - t0 + phase, self._min_burst_s[k])
        return self._add_edge_noise(starts - phase, ends - phase, self._noise)

    def _window_times(
        self, beacon: SimulatedBeacon, pose_at: PoseAt, t0: float, t_guess: float
    ) -> tuple[float, float] | None:
        """Instants (s) the received power crosses the threshold, upwards then downwards (eq. 2.4).

        Fixed-point iterations on turret angle = beacon bearing (+- half window + bias), the pose taken
        at each iterate; they contract by the ratio of the robot's turn rate to the turret's (~3%).
        """
        omega = self._omega
        half_window_rad, view = self.config.half_window_rad, self._view

        def mismatch(t: float, side: float, bias: float) -> tuple[float, float]:
            bearing, distance = view(beacon, pose_at(t))
            half = half_window_rad(distance, beacon.power_scale)
            return _wrap(bearing + side * half + bias - omega * (t - t0)) / omega, half

        centre = t_guess
        for _ in range(_FIXED_POINT_STEPS):
            step, half = mismatch(centre, 0.0, 0.0)
            centre += step
        if half <= 0.0:
            return None
        bias = self._bias(2.0 * half, (omega * (centre - t0)) % _TWO_PI)
        edges = []
        for side in (-1.0, 1.0):
            edge = centre + (side * half + bias) / omega
            for _ in range(_FIXED_POINT_STEPS - 1):
                edge += mismatch(edge, side, bias)[0]
            edges.append(edge)
        return (edges[0], edges[1]) if edges[1] > edges[0] else None

    def turret_position(self, pose: tuple[float, float, float]) -> tuple[float, float]:
        """Map position (m) of the turret centre of a robot at pose (x, y, theta): the true offset applied."""
        # Scalar math: called seven times per pass of each beacon, where numpy's overhead dominates.
        x, y, theta = pose
        theta = float(theta)
        c, s = math.cos(theta), math.sin(theta)
        ox, oy = self._turret_offset_m
        return x + c * ox - s * oy, y + s * ox + c * oy

    def _view(self, beacon: SimulatedBeacon, pose: tuple[float, float, float]) -> tuple[float, float]:
        """(bearing in [0, 2 pi) in the robot frame, distance m) of the beacon from the turret centre."""
        turret_x, turret_y = self.turret_position(pose)
        dx, dy = beacon.x_m - turret_x, beacon.y_m - turret_y
        return (math.atan2(dy, dx) - float(pose[2])) % _TWO_PI, math.hypot(dx, dy)

    def _bias(self, window_rad: float, bearing_rad: float) -> float:
        """Injected chapter-7 biases (rad) added to the bearing this window gives (and the hardware's)."""
        total = 0.0
        if self._hardware_bias is not None:
            total += float(self._hardware_bias.power_bias(window_rad))
        if self._power_bias is not None:
            total += float(np.asarray(self._power_bias(np.array([window_rad]))).reshape(-1)[0])
        if self._rotation_bias is not None:
            total += float(np.asarray(self._rotation_bias(np.array([bearing_rad]))).reshape(-1)[0])
        return total

    def _occluded(self, beacon_id: int, time_s: float) -> bool:
        if callable(self.occlusion):
            return bool(self.occlusion(beacon_id, time_s))
        return self.occlusion is not None and beacon_id in self.occlusion

    def _add_edge_noise(
        self, starts: np.ndarray, ends: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Receiver jitter on every edge, plus the AGC's larger noise on the window's outer edges (5.6)."""
        if starts.size == 0:
            return starts, ends
        cfg = self.config
        if cfg.edge_jitter_s > 0.0:
            starts = starts + rng.normal(0.0, cfg.edge_jitter_s, starts.size)
            ends = ends + rng.normal(0.0, cfg.edge_jitter_s, ends.size)
        omega = cfg.turret_speed_rad_s
        # Keep each outer burst at least one tick long so the edge order never changes.
        starts[0] = min(starts[0] + rng.normal(0.0, cfg.rising_noise_rad / omega), ends[0] - cfg.tick_s)
        ends[-1] = max(ends[-1] + rng.normal(0.0, cfg.falling_noise_rad / omega), starts[-1] + cfg.tick_s)
        if cfg.hardware is not None:
            half_shift_s = 0.5 * cfg.hardware.modulation_shortening_rad / omega
            starts[0] = min(starts[0] + half_shift_s, ends[0] - cfg.tick_s)
            ends[-1] = max(ends[-1] - half_shift_s, starts[-1] + cfg.tick_s)
        return starts, ends

    def _spurious_bursts(self) -> tuple[np.ndarray, np.ndarray]:
        """Stray-IR pulses (s from the revolution start): a Poisson process over the revolution."""
        cfg = self.config
        count = self._rng.poisson(cfg.spurious_rate_hz * cfg.period_s) if cfg.spurious_rate_hz > 0 else 0
        durations = self._rng.uniform(*cfg.spurious_burst_s, count)
        # Kept inside the revolution: a pulse is drawn once, so it must not straddle two of them.
        starts = self._rng.uniform(0.0, 1.0, count) * (cfg.period_s - durations)
        return starts, starts + durations

    def _capture(self, starts_rel: np.ndarray, ends_rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Timer captures (s from the zero reference) and polarities of the OR of all bursts, only those
        inside [0, period): a window over the zero reference shows its tail at the start and the next pass's
        head at the end."""
        period, tick = self.config.period_s, self.config.tick_s
        starts, ends = _union(starts_rel, ends_rel)
        captured_starts, captured_ends = np.round(starts / tick) * tick, np.round(ends / tick) * tick
        # A burst shorter than the timer resolution leaves no capture.
        keep = captured_ends > captured_starts
        raw = np.column_stack([starts[keep], ends[keep]]).ravel()
        times = np.column_stack([captured_starts[keep], captured_ends[keep]]).ravel()
        rising = np.tile([True, False], int(np.count_nonzero(keep)))
        inside = (raw >= 0.0) & (raw < period)
        return np.clip(times[inside], 0.0, period - tick), rising[inside]


def _is_beacon_sequence(beacons: object) -> bool:
    return isinstance(beacons, Sequence) and all(isinstance(b, SimulatedBeacon) for b in beacons)


def _wrap(angle: float) -> float:
    return (angle + math.pi) % _TWO_PI - math.pi


def _union(starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Union of intervals (the receiver ORs overlapping signals), sorted."""
    if starts.size == 0:
        return starts, ends
    order = np.argsort(starts, kind="stable")
    starts, ends = starts[order], ends[order]
    reach = np.maximum.accumulate(ends)
    new = np.ones(starts.size, dtype=bool)
    new[1:] = starts[1:] > reach[:-1]
    first = np.flatnonzero(new)
    return starts[first], np.maximum.reduceat(ends, first)


def fixed_window_bearing_errors(
    code: BeaconCode,
    window_s: np.ndarray,
    period_s: float,
    n_turns: int,
    tick_s: float = 100e-9,
    min_burst_s: float = 0.0,
    phase_s: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The simulator of sections 4.3-4.4: one beacon, fixed windows, n_turns turns, turn k seeing the code
    shifted by k * period (mod T_c; a coprime period visits every shift, time stationarity), edges on the
    tick. Bearing errors (windows, turns) in s and the detected mask."""
    windows = np.asarray(window_s, dtype=float).reshape(-1, 1)
    starts = phase_s + np.arange(n_turns, dtype=float)[None, :] * period_s
    starts = np.round(np.mod(starts, code.duration_s) / tick_s) * tick_s
    starts = np.broadcast_to(starts, (windows.size, n_turns))
    ends = starts + np.round(windows / tick_s) * tick_s
    rising, falling, detected = first_last_edges(code, starts, ends, min_burst_s)
    error = 0.5 * ((rising - starts) + (falling - ends))
    return np.where(detected, error, 0.0), detected
