"""The complete positioning scheme of thesis fig. 8.1 without ROS: odometry + BeAMS bearings in the EKF,
ToTal (or an operator) to initialise it.

`Localiser` owns the timing: the EKF state is kept at the newest odometry instant, with the states at
the odometry samples of the last `odometry_history_s`; a bearing (stamped when the turret pointed at its
beacon, so usually before the newest odometry) is applied at its own stamp by going back to the state
of the odometry sample before it, the turret placed where the interpolated odometry puts it, and
predicting again through the later samples (see `Localiser.on_bearings`); a pose (ToTal's accepted fix or an
operator's /initialpose) initialises the filter, brought to the filter's instant by the odometry motion
since its stamp (a ToTal fix is stamped at its revolution, ~0.1-0.2 s before it arrives, so a fix the
odometry history does not cover is refused: taken as current, it put the live filter 0.2 m and 7 deg
off, confidently), and re-initialises it when the robot was kidnapped (most of the recent bearings gated
out while ToTal is confident of a pose inconsistent with the estimate: identified beacons make this
possible, thesis ch. 8 "System deployment") or the filter is lost (`NisMonitor`: the bearings'
innovations, over a sliding window, too large for the covariance: the next ToTal fix restarts it).
Time going backwards (a rosbag played in a loop: consecutive odometry messages in the past, not one
stray; `beams_common.time_jumps`) resets everything; odometry gaps inflate the covariance instead of
freezing the filter.

ekf_node and the offline replay (`bag_replay`) share what lies between their inputs and the filter:
`filter_settings` (parameter values to the filter's settings), `build_localiser`,
and `Localiser.offer_pose` with its rules (`usable_covariance`, `operator_pose_stamp_s`).
"""

from collections import Counter, deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from math import hypot, isfinite
from typing import Any

import numpy as np
from scipy.stats import chi2

from beams_common.angles import wrap_to_pi
from beams_common.bearing import Bearing
from beams_common.pose2d import Pose2D, between, compose, inverse, is_finite_pose
from beams_common.pose_buffer import PoseBuffer
from beams_common.time_jumps import StampOrder, TimeJumpDetector
from beams_common.validation import bearing_problem, one_sighting_per_beacon, revolution_size_problem
from beams_ekf.bearing_ekf import BearingEkf, ProcessNoise, turret_pose
from beams_ekf.odometry_errors import OdometryErrorStates
from beams_ekf.pose_filter import BearingOutcome, PoseFilter
from beams_ekf.power_bias_states import PowerBiasStates, power_bias_states_of
from beams_ekf.turret_offset_states import TurretOffsetStates, turret_offset_states_of

# bearings waiting for odometry beyond this many are dropped, oldest first (a dead odometry source)
MAX_PENDING_BEARINGS = 64


@dataclass(frozen=True)
class LocaliserConfig:
    """Timing and re-initialisation parameters (defaults suit 50 Hz odometry and a 10 Hz turret)."""

    odometry_history_s: float = 1.0
    max_odometry_extrapolation_s: float = 0.05
    # an odometry step longer than this is a gap: the covariance grows with its duration
    odometry_gap_s: float = 0.25
    gap_position_variance_m2_per_s: float = 1.0e-3
    gap_heading_variance_rad2_per_s: float = 1.0e-3
    # a gap never inflates more than this long (the table bounds how lost the robot can be)
    max_gap_inflation_s: float = 10.0
    # the filter is "lost" when at least kidnap_gated_bearings of the last kidnap_window_bearings new
    # bearings were gated out (a consistent filter gates 1 - gate_probability of them); a lost filter
    # takes ToTal's fix when the fix is elsewhere: inconsistent with the estimate (chi-square, 3 dof,
    # at kidnap_probability, the two covariances summed) or farther than the distance/heading below
    kidnap_gated_bearings: int = 6
    kidnap_window_bearings: int = 12
    kidnap_probability: float = 0.999
    kidnap_distance_m: float = 0.25
    kidnap_heading_rad: float = 0.35
    # odometry stamps going back by more than this, in time_jump_confirmations consecutive messages,
    # reset the filter (a bag loop); smaller steps, and a single stray old message, are dropped
    time_jump_tolerance_s: float = 0.0
    time_jump_confirmations: int = 2
    # lost detection (NisMonitor): the NIS of the last lost_nis_window_bearings new bearings, summed,
    # beyond the chi-square quantile at lost_nis_probability (0: the monitor is off)
    lost_nis_window_bearings: int = 30
    lost_nis_probability: float = 1.0 - 1.0e-6

    def __post_init__(self) -> None:
        if self.lost_nis_window_bearings < 0 or not 0.0 < self.lost_nis_probability < 1.0:
            raise ValueError(
                f"need lost_nis_window_bearings >= 0 and lost_nis_probability in (0, 1), got "
                f"{self.lost_nis_window_bearings} and {self.lost_nis_probability}"
            )
        if not (
            self.odometry_history_s > 0.0
            and self.max_odometry_extrapolation_s >= 0.0
            and self.odometry_gap_s > 0.0
        ):
            raise ValueError(
                "odometry_history_s and odometry_gap_s must be > 0, max_odometry_extrapolation_s >= 0"
            )
        if not 1 <= self.kidnap_gated_bearings <= self.kidnap_window_bearings:
            raise ValueError(
                f"need 1 <= kidnap_gated_bearings <= kidnap_window_bearings, got "
                f"{self.kidnap_gated_bearings} and {self.kidnap_window_bearings}"
            )
        if self.time_jump_confirmations < 1:
            raise ValueError(f"time_jump_confirmations must be >= 1, got {self.time_jump_confirmations}")
        if not 0.0 < self.kidnap_probability < 1.0:
            raise ValueError(f"kidnap_probability must be in (0, 1), got {self.kidnap_probability}")


# ekf_node's parameter name of each ProcessNoise field (those of LocaliserConfig are its field names)
PROCESS_NOISE_PARAMETERS = {
    "translation_m2_per_m": "translation_variance_m2_per_m",
    "rotation_rad2_per_rad": "rotation_variance_rad2_per_rad",
    "rotation_rad2_per_m": "rotation_variance_rad2_per_m",
    "cross_track_m2_per_m": "cross_track_variance_m2_per_m",
}
# ekf_node's parameter name of each OdometryErrorStates prior (odometry_error_states switches them on)
ODOMETRY_ERROR_PARAMETERS = {
    "scale_sigma": "odometry_scale_sigma",
    "rotation_scale_sigma": "odometry_rotation_scale_sigma",
    "heading_drift_sigma_rad_per_m": "odometry_heading_drift_sigma_rad_per_m",
}

# The wheels' random error, variance per metre rolled, of the simulated robot (sim_world's OdometryDrift:
# noise 1 mm/sqrt(m) is 1.0e-6; the random part of the half-normal slip, 0.005^2 (1 - 2/pi) of a step's
# squared length, adds at most 0.09e-6 at the 1 cm steps of 0.5 m/s and 50 Hz), and its wheel base (m).
WHEEL_VARIANCE_M2_PER_M = 1.1e-6
WHEEL_BASE_M = 0.3


@dataclass(frozen=True)
class FilterSettings:
    """What ekf_node takes from its parameters (besides the beacon geometry).

    By default the filter estimates the odometry's systematic errors (`odometry_errors`), so its process
    noise is the wheels' random noise alone (`ProcessNoise.wheel_noise`); without those states the
    process noise must also cover the systematic errors as white noise (ProcessNoise's own defaults).
    """

    process_noise: ProcessNoise = field(
        default_factory=lambda: ProcessNoise.wheel_noise(WHEEL_VARIANCE_M2_PER_M, WHEEL_BASE_M)
    )
    odometry_errors: OdometryErrorStates | None = field(default_factory=OdometryErrorStates)
    # the power bias of uncalibrated bearings as states (estimated or considered); None: white noise
    power_bias: PowerBiasStates | None = field(default_factory=PowerBiasStates)
    # the turret offset's correction as states (self-calibration); None: the configured offset is exact
    turret_offset: TurretOffsetStates | None = None
    # chi-square (1 dof) probability of the per-bearing gate
    gate_probability: float = 0.999
    localiser: LocaliserConfig = field(default_factory=LocaliserConfig)
    # initialise (and re-initialise after a kidnapping) from ToTal's accepted poses
    use_total_pose: bool = True
    # standard deviations (m, m, rad) of a pose without a usable covariance
    default_pose_sigma: tuple[float, float, float] = (0.05, 0.05, 0.1)

    @property
    def default_pose_covariance(self) -> np.ndarray:
        """The 3x3 covariance of default_pose_sigma."""
        return np.diag(np.square(self.default_pose_sigma))


def filter_parameter_defaults() -> dict[str, Any]:
    """ekf_node's filter parameters by name with their defaults (FilterSettings'), for declaring them."""
    defaults = FilterSettings()
    values: dict[str, Any] = {
        parameter: getattr(defaults.process_noise, name)
        for name, parameter in PROCESS_NOISE_PARAMETERS.items()
    }
    errors = defaults.odometry_errors or OdometryErrorStates()
    values.update({parameter: getattr(errors, name) for name, parameter in ODOMETRY_ERROR_PARAMETERS.items()})
    values["odometry_error_states"] = defaults.odometry_errors is not None
    values.update({f.name: getattr(defaults.localiser, f.name) for f in fields(LocaliserConfig)})
    values.update(
        gate_probability=defaults.gate_probability,
        use_total_pose=defaults.use_total_pose,
        default_pose_sigma=list(defaults.default_pose_sigma),
    )
    return values


def filter_settings(parameters: Mapping[str, Any]) -> FilterSettings:
    """Settings from ekf_node's parameter values by name (a missing one takes its default).

    Raises ValueError for values the settings refuse, alone or together (kidnap counts, sigma length).
    """
    defaults = FilterSettings()
    noise = ProcessNoise(
        **{
            name: float(parameters.get(parameter, getattr(defaults.process_noise, name)))
            for name, parameter in PROCESS_NOISE_PARAMETERS.items()
        }
    )
    config = LocaliserConfig(
        **{f.name: parameters[f.name] for f in fields(LocaliserConfig) if f.name in parameters}
    )
    sigma = tuple(float(v) for v in parameters.get("default_pose_sigma", defaults.default_pose_sigma))
    if len(sigma) != 3:
        raise ValueError(f"default_pose_sigma needs 3 values (x, y, yaw), got {list(sigma)}")
    errors = None
    if parameters.get("odometry_error_states", defaults.odometry_errors is not None):
        prior = defaults.odometry_errors or OdometryErrorStates()
        errors = OdometryErrorStates(
            **{
                name: float(parameters.get(parameter, getattr(prior, name)))
                for name, parameter in ODOMETRY_ERROR_PARAMETERS.items()
            }
        )
    return FilterSettings(
        noise,
        errors,
        power_bias_states_of(dict(parameters)),
        float(parameters.get("gate_probability", defaults.gate_probability)),
        config,
        bool(parameters.get("use_total_pose", defaults.use_total_pose)),
        sigma,
        turret_offset_states_of(dict(parameters)),
    )


def usable_covariance(covariance: np.ndarray, default: np.ndarray) -> np.ndarray:
    """A pose's 3x3 covariance when finite and positive definite, else the default (RViz's /initialpose
    and the set_pose service may send zeros)."""
    covariance = np.asarray(covariance, dtype=float)
    if np.all(np.isfinite(covariance)) and np.all(np.linalg.eigvalsh(covariance) > 0.0):
        return covariance
    return default


def operator_pose_stamp_s(stamp_s: float, newest_odometry_s: float | None) -> float:
    """The instant an operator's pose is taken at: "now" (the newest odometry) when it is stamped zero or
    after the odometry, since an operator's stamp has no meaning in the odometry's past."""
    if newest_odometry_s is not None and (stamp_s == 0.0 or stamp_s > newest_odometry_s):
        return newest_odometry_s
    return stamp_s


@dataclass
class _Slot:
    """What the localiser keeps with an odometry sample: the filter state there (before the bearings of
    the interval that starts at the sample) and those bearings, to filter again from there."""

    state: tuple[np.ndarray, np.ndarray]
    bearings: list[Bearing] = field(default_factory=list)


class NisMonitor:
    """Lost detection on the bearings' innovations: a consistent filter's normalised innovations squared
    (NIS, r^2 / S) are independent chi-square (1 dof) draws, so the sum over the last n bearings is
    chi-square with n dof; a sum beyond its quantile at `probability` says the estimate (or its
    covariance) is wrong. Each NIS counts at most the gate's threshold (a gated-out bearing says "beyond
    the gate", and one wild reflection must not make the filter lost on its own); the test runs on the
    bearings so far until the window fills (a lost start is caught within a few bearings)."""

    def __init__(self, window_bearings: int, probability: float, gate: float) -> None:
        self._nis: deque[float] = deque(maxlen=max(window_bearings, 1))
        self.enabled = window_bearings > 0
        self._gate = gate
        self._thresholds = [float("inf")] + [
            float(chi2.ppf(probability, df=n)) for n in range(1, max(window_bearings, 1) + 1)
        ]

    def add(self, nis: float) -> bool:
        """Record one new bearing's NIS (gated ones too); True when that makes the filter lost."""
        was_lost = self.lost
        self._nis.append(min(nis, self._gate) if isfinite(nis) else self._gate)
        return self.lost and not was_lost

    @property
    def window_sum(self) -> float:
        """The capped NIS summed over the window (a diagnostic)."""
        return float(sum(self._nis))

    @property
    def lost(self) -> bool:
        """True when the window's NIS sum exceeds the chi-square quantile for its length."""
        return self.enabled and self.window_sum > self._thresholds[len(self._nis)]

    def clear(self) -> None:
        self._nis.clear()


def _rejected(reason: str) -> BearingOutcome:
    return BearingOutcome(False, float("nan"), float("nan"), reason)


@dataclass
class Estimate:
    """The filter's output at its instant."""

    stamp_s: float
    pose: Pose2D
    covariance: np.ndarray
    # robot-frame velocity (v_x, v_y, omega) from the last two odometry samples
    twist: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # the odometry pose (odom frame) at stamp_s; None before any odometry
    odom_pose: Pose2D | None = None

    @property
    def map_to_odom(self) -> Pose2D | None:
        """The map -> odom transform (REP-105: the localisation's correction of the odometry's drift) that
        puts the odometry pose on the estimate; None without odometry."""
        return None if self.odom_pose is None else compose(self.pose, inverse(self.odom_pose))


@dataclass
class LocaliserCounters:
    """Counts for diagnostics (names are the diagnostic keys)."""

    counts: Counter = field(default_factory=Counter)
    last_bearing_stamp_s: float | None = None


class Localiser:
    """Odometry history + a PoseFilter (BearingEkf by default) + initialisation, kidnap and time-jump
    logic."""

    def __init__(self, ekf: PoseFilter, config: LocaliserConfig | None = None) -> None:
        self.ekf = ekf
        self.config = config or LocaliserConfig()
        self.history = PoseBuffer(self.config.odometry_history_s, self.config.max_odometry_extrapolation_s)
        self.stats = LocaliserCounters()
        # gated (True) or accepted (False), for the last new bearings: the kidnap evidence
        self._recent_gated: deque[bool] = deque(maxlen=self.config.kidnap_window_bearings)
        self._time_jumps = TimeJumpDetector(
            self.config.time_jump_tolerance_s, self.config.time_jump_confirmations
        )
        self._kidnap_threshold = float(chi2.ppf(self.config.kidnap_probability, df=3))
        self.nis_monitor = NisMonitor(
            self.config.lost_nis_window_bearings, self.config.lost_nis_probability, ekf.gate
        )
        self._stamp_s: float | None = None
        # bearings stamped after the newest odometry, waiting for the odometry that covers them
        self._pending: list[Bearing] = []

    @property
    def initialised(self) -> bool:
        """True once a pose initialised the filter (and no reset since)."""
        return self.ekf.initialised

    def configure(
        self,
        beacons_xy: Mapping[int, Sequence[float]],
        sensor_offset_m: tuple[float, float],
        settings: "FilterSettings",
    ) -> None:
        """New beacon geometry, process noise and bearing gate (a runtime parameter change, a calibration
        reload); the estimate and the odometry history stay."""
        self.ekf.configure(beacons_xy, sensor_offset_m, settings.process_noise, settings.gate_probability)

    def reset(self, reason: str = "reset") -> None:
        """Forget the estimate and the odometry; the filter waits for a pose."""
        self.ekf.reset()
        self.history.clear()
        self._recent_gated.clear()
        self.nis_monitor.clear()
        self._stamp_s = None
        self._pending.clear()
        self._time_jumps.clear()
        self.stats.counts[reason] += 1

    # -- odometry -------------------------------------------------------------------------------------
    def on_odometry(self, stamp_s: float, odom_pose: Pose2D) -> str:
        """Predict with the motion since the previous odometry pose. Returns what happened."""
        if not (isfinite(stamp_s) and is_finite_pose(odom_pose)):
            self.stats.counts["odometry_invalid"] += 1
            return "invalid"
        latest = self.history.latest
        order = self._time_jumps.classify(stamp_s, None if latest is None else latest[0])
        if order in (StampOrder.STALE, StampOrder.HELD):
            # held: stamped far in the past, a stray message unless the next ones confirm a jump
            self.stats.counts["odometry_stale" if order is StampOrder.STALE else "odometry_back_in_time"] += 1
            return order.value
        if order is StampOrder.JUMP:
            self.reset("time_jump_resets")
            latest = None
        self.stats.counts["odometry"] += 1
        if latest is None or not self.ekf.initialised:
            self.history.append(stamp_s, odom_pose, _Slot(self.ekf.state()) if self.ekf.initialised else None)
            self._stamp_s = stamp_s if self.ekf.initialised else None
            return "reference"
        if stamp_s - latest[0] > self.config.odometry_gap_s:
            self.stats.counts["odometry_gaps"] += 1
        self._advance(latest[0], latest[1], stamp_s, odom_pose)
        self.history.append(stamp_s, odom_pose, _Slot(self.ekf.state()))
        self._stamp_s = stamp_s
        self._apply_pending(stamp_s)
        return "predicted"

    def _apply_pending(self, newest_s: float) -> None:
        """Apply the waiting bearings the odometry now covers."""
        ready = [b for b in self._pending if b.stamp_s <= newest_s]
        if ready:
            self._pending = [b for b in self._pending if b.stamp_s > newest_s]
            self.on_bearings(ready)

    def _advance(self, from_s: float, from_pose: Pose2D, to_s: float, to_pose: Pose2D) -> None:
        """Predict over one odometry step; a long silence of odometry (the robot may have slipped)
        also grows the covariance with its duration."""
        self.ekf.predict(between(from_pose, to_pose))
        step_s = to_s - from_s
        if step_s > self.config.odometry_gap_s:
            duration_s = min(step_s, self.config.max_gap_inflation_s)
            self.ekf.add_time_noise(
                self.config.gap_position_variance_m2_per_s * duration_s,
                self.config.gap_heading_variance_rad2_per_s * duration_s,
            )

    def _motion_since(self, stamp_s: float) -> Pose2D | None:
        """Odometry motion from stamp_s to the filter's instant (robot frame at stamp_s); None if unknown
        (stamp_s outside the history, or no odometry yet)."""
        latest = self.history.latest
        if latest is None:
            return None
        then = self.history.pose_at(stamp_s)
        return None if then is None else between(then, latest[1])

    # -- bearings -------------------------------------------------------------------------------------
    def on_revolution(self, bearings: Sequence[Bearing]) -> str:
        """One revolution's bearings (a beams/bearings message): refused whole beyond
        MAX_BEARINGS_PER_REVOLUTION, then one sighting per beacon (`validation.one_sighting_per_beacon`,
        the triangulation's rule), then `on_bearings`. A beacon seen again at another instant (a robot
        turning against the turret) keeps the sighting nearest the revolution's middle, counted in
        `bearings_repeated_beacon`; a beacon seen twice at one instant is not physical: its bearings are
        refused. Returns the reason of a refusal ('' when none); every case is counted."""
        problem = revolution_size_problem(len(bearings))
        if problem:
            self.stats.counts["revolutions_too_many_bearings"] += 1
            return problem
        sightings = one_sighting_per_beacon(bearings)
        conflicting = set(sightings.conflicting_ids)
        repeated = sum(b.beacon_id not in conflicting for b in sightings.dropped)
        if repeated:
            self.stats.counts["bearings_repeated_beacon"] += repeated
        self.on_bearings([b for b in sightings.kept if b.beacon_id not in conflicting])
        if not conflicting:
            return ""
        self.stats.counts["bearings_conflicting_beacon"] += sum(b.beacon_id in conflicting for b in bearings)
        return f"beacon(s) {sorted(conflicting)} seen twice at one instant (not physical): bearings refused"

    def on_bearing(
        self, stamp_s: float, beacon_id: int, bearing_rad: float, variance_rad2: float
    ) -> BearingOutcome:
        """Apply one bearing (sensor frame) at its own stamp."""
        return self.on_bearings([Bearing(stamp_s, beacon_id, bearing_rad, variance_rad2)])[0]

    def on_bearings(self, bearings: Sequence[Bearing]) -> list[BearingOutcome]:
        """Apply bearings (typically one revolution's), each at its own stamp; outcomes in the given order.

        The filter goes back to its state at the odometry sample before the earliest stamp, applies the
        bearings of each odometry interval in stamp order (those already applied there again, so any
        arrival order gives the same estimate), the turret where the interpolated odometry puts it at
        the stamp, and predicts again through the later odometry samples. Applying a bearing at the
        newest instant instead would let it shrink the covariance of the odometry noise accrued after
        it was measured: the filter would become overconfident.
        """
        if not self.ekf.initialised:
            return [self._count(_rejected("uninitialised")) for _ in bearings]
        outcomes: dict[int, BearingOutcome] = {}
        valid: list[tuple[int, Bearing]] = []
        for n, bearing in enumerate(bearings):
            # refused before scheduling: a bad bearing must not make the filter go back and re-filter
            problem = self._invalid_reason(bearing)
            if problem:
                outcomes[n] = self._count(_rejected(problem))
            else:
                valid.append((n, bearing))
        if len(self.history) == 0:  # no odometry: the robot is taken as still
            outcomes.update((n, self._count(self._apply(b, (0.0, 0.0, 0.0)))) for n, b in valid)
            return [outcomes[n] for n in range(len(bearings))]
        scheduled: dict[int, list[tuple[Bearing, int]]] = {}  # history index -> (bearing, input index)
        first_state = self._first_state_index()
        for n, bearing in valid:
            index = self._replay_index(bearing.stamp_s, first_state)
            if index is None and self._ahead_of_odometry(bearing.stamp_s):
                outcomes[n] = self._defer(bearing)
            elif index is None:
                outcomes[n] = self._count(_rejected("outside_history"))
            else:
                scheduled.setdefault(index, []).append((bearing, n))
        if scheduled:
            self._replay(scheduled, outcomes)
        return [outcomes[n] for n in range(len(bearings))]

    def _invalid_reason(self, bearing: Bearing) -> str:
        """Why the filter can never use a bearing (`validation.bearing_problem`, the triangulation's rule
        too), as a counter name, or an empty string."""
        problem = bearing_problem(
            bearing.beacon_id,
            bearing.bearing_rad,
            bearing.variance_rad2,
            bearing.stamp_s,
            self.ekf.beacons_xy,
        )
        if not problem:
            return ""
        return "unknown beacon" if bearing.beacon_id not in self.ekf.beacons_xy else "invalid measurement"

    def _ahead_of_odometry(self, stamp_s: float) -> bool:
        """True for a stamp after the newest odometry (past extrapolation) but within the history span."""
        newest_s = self.history.latest[0]
        return newest_s < stamp_s <= newest_s + self.config.odometry_history_s

    def _defer(self, bearing: Bearing) -> BearingOutcome:
        """Keep a bearing until odometry reaches its stamp (the oldest goes when too many wait)."""
        self._pending.append(bearing)
        if len(self._pending) > MAX_PENDING_BEARINGS:
            self._pending.pop(0)
            self.stats.counts["bearings_dropped_pending"] += 1
        return self._count(_rejected("deferred"))

    def _replay_index(self, stamp_s: float, first_valid: int) -> int | None:
        """History index (negative, from the newest) to apply a bearing at stamp_s, or None."""
        if self.history.pose_at(stamp_s) is None:
            return None
        index = self.history.index_at_or_before(stamp_s)
        # before the initialisation there is no state: use the first one (the turret lever spans the gap)
        index = first_valid if index is None or index < first_valid else index
        return index - len(self.history)

    def _first_state_index(self) -> int:
        """Index of the oldest history sample carrying a filter state."""
        for index in range(len(self.history) - 1, -1, -1):
            if self.history.sample(index)[2] is None:
                return index + 1
        return 0

    def _replay(
        self, scheduled: dict[int, list[tuple[Bearing, int]]], outcomes: dict[int, BearingOutcome]
    ) -> None:
        """Go back to the earliest scheduled sample and filter forward through the history."""
        first = min(scheduled)
        for index in range(first, 0):
            t0, pose0, slot = self.history.sample(index)
            if index == first:
                self.ekf.restore(slot.state)
            else:
                t_prev, pose_prev, _ = self.history.sample(index - 1)
                self._advance(t_prev, pose_prev, t0, pose0)
                slot.state = self.ekf.state()
            new = scheduled.get(index, [])
            if not (new or slot.bearings):
                continue
            # the bearings already applied in this interval are applied again, without being counted
            merged = [(b, None) for b in slot.bearings] + new
            merged.sort(key=lambda item: item[0].stamp_s)
            for bearing, n in merged:
                outcome = self._apply(bearing, between(pose0, self.history.pose_at(bearing.stamp_s)))
                if n is not None:
                    outcomes[n] = self._count(outcome)
                    self._track_gating(bearing, outcome)
            slot.bearings = [bearing for bearing, _ in merged]

    def _apply(self, bearing: Bearing, robot_then: Pose2D) -> BearingOutcome:
        """Update with a bearing taken with the robot at `robot_then` in the current state's robot frame."""
        lever = turret_pose(robot_then, self.ekf.sensor_offset_m)
        window = 0.0 if bearing.calibrated else bearing.angular_window_rad  # an uncorrected power bias
        return self.ekf.update_bearing(
            bearing.beacon_id, bearing.bearing_rad, bearing.variance_rad2, lever, window
        )

    def _track_gating(self, bearing: Bearing, outcome: BearingOutcome) -> None:
        """Record whether a new bearing was gated (kidnap evidence) and the last accepted one."""
        if outcome.accepted:
            self.stats.last_bearing_stamp_s = bearing.stamp_s
        if outcome.accepted or outcome.reason == "gated":
            self._recent_gated.append(not outcome.accepted)
            if self.nis_monitor.add(outcome.nis):
                self.stats.counts["lost_detections"] += 1

    def _count(self, outcome: BearingOutcome) -> BearingOutcome:
        self.stats.counts["bearings_accepted" if outcome.accepted else f"bearings_{outcome.reason}"] += 1
        return outcome

    @property
    def recent_gated_bearings(self) -> int:
        """Gated bearings among the last kidnap_window_bearings new ones (a diagnostic)."""
        return sum(self._recent_gated)

    @property
    def kidnap_suspected(self) -> bool:
        """True when at least kidnap_gated_bearings of the last kidnap_window_bearings were gated out
        (a filter initialised a little wrong, and overconfident, still accepts some bearings in between)."""
        return self.recent_gated_bearings >= self.config.kidnap_gated_bearings

    # -- poses ----------------------------------------------------------------------------------------
    def on_pose(self, stamp_s: float, pose: Pose2D, covariance: np.ndarray, *, operator: bool) -> str:
        """A pose from ToTal (operator=False) or an operator (True). Returns what it did.

        An operator's pose always (re)initialises (one older than the odometry history is taken as
        current: it has no meaningful stamp); ToTal's initialises a filter that has no estimate, and
        re-initialises one that is kidnapped (kidnap suspected and the fix elsewhere) or lost (the
        NisMonitor's test), provided the odometry
        history covers its stamp ("outside_history" otherwise: the next fix will be covered).
        """
        if not (isfinite(stamp_s) and is_finite_pose(pose)):
            self.stats.counts["poses_invalid"] += 1
            return "invalid"
        motion = self._motion_since(stamp_s)
        if motion is None and not operator:
            # the robot moved since the fix by an unknown amount (0.1 m in 0.2 s at 0.5 m/s)
            self.stats.counts["poses_outside_history"] += 1
            return "outside_history"
        pose_now = pose if motion is None else compose(pose, motion)
        if operator or not self.ekf.initialised:
            return self._initialise(stamp_s, pose_now, covariance, "initialisations")
        if self.kidnap_suspected and self._far_from_estimate(pose_now, covariance):
            return self._initialise(stamp_s, pose_now, covariance, "kidnap_reinitialisations")
        if self.nis_monitor.lost:
            return self._initialise(stamp_s, pose_now, covariance, "lost_reinitialisations")
        return "ignored"

    def offer_pose(
        self,
        stamp_s: float,
        pose: Pose2D,
        covariance: np.ndarray,
        default_covariance: np.ndarray,
        *,
        operator: bool,
    ) -> str:
        """`on_pose` for a pose from a message: an unusable covariance replaced by the default
        (`usable_covariance`), an operator's stamp by "now" (`operator_pose_stamp_s`)."""
        if operator:
            latest = self.history.latest
            stamp_s = operator_pose_stamp_s(stamp_s, None if latest is None else latest[0])
        usable = usable_covariance(covariance, default_covariance)
        return self.on_pose(stamp_s, pose, usable, operator=operator)

    def _far_from_estimate(self, pose: Pose2D, covariance: np.ndarray) -> bool:
        """True when `pose` (of `covariance`) is inconsistent with the estimate or beyond the absolute
        thresholds: the squared Mahalanobis distance of the difference, under the sum of the two
        covariances, above the chi-square (3 dof) quantile at kidnap_probability."""
        x, y, theta = self.ekf.pose
        difference = np.array([pose[0] - x, pose[1] - y, wrap_to_pi(pose[2] - theta)])
        combined = self.ekf.covariance + np.asarray(covariance, dtype=float).reshape(3, 3)
        try:
            distance2 = float(difference @ np.linalg.solve(combined, difference))
        except np.linalg.LinAlgError:
            distance2 = float("inf")
        return (
            not distance2 <= self._kidnap_threshold
            or hypot(difference[0], difference[1]) > self.config.kidnap_distance_m
            or abs(difference[2]) > self.config.kidnap_heading_rad
        )

    def _initialise(self, stamp_s: float, pose: Pose2D, covariance: np.ndarray, counter: str) -> str:
        try:
            self.ekf.initialise(pose, covariance)
        except ValueError:
            self.stats.counts["poses_invalid"] += 1
            return "invalid"
        self._recent_gated.clear()
        self.nis_monitor.clear()
        # the states kept for late bearings belong to the old estimate
        for index in range(len(self.history)):
            self.history.set_payload(index, None)
        latest = self.history.latest
        if latest is not None:
            self.history.set_payload(-1, _Slot(self.ekf.state()))
        self._stamp_s = latest[0] if latest is not None else stamp_s
        self.stats.counts[counter] += 1
        return counter

    # -- output ---------------------------------------------------------------------------------------
    def estimate(self) -> Estimate | None:
        """The current estimate, or None before initialisation."""
        if not self.ekf.initialised:
            return None
        stamp_s = self._stamp_s if self._stamp_s is not None else float("nan")
        latest = self.history.latest
        odom_pose = latest[1] if latest is not None and latest[0] == stamp_s else None
        return Estimate(stamp_s, self.ekf.pose, self.ekf.covariance, self._odometry_twist(), odom_pose)

    def _odometry_twist(self) -> tuple[float, float, float]:
        """Robot-frame velocity over the last odometry step (zero with fewer than two samples)."""
        step = self.history.last_step()
        if step is None:
            return (0.0, 0.0, 0.0)
        step_s, (dx, dy, dtheta) = step
        return (dx / step_s, dy / step_s, dtheta / step_s)


def build_localiser(
    beacons_xy: Mapping[int, Sequence[float]], sensor_offset_m: tuple[float, float], settings: FilterSettings
) -> Localiser:
    """The Localiser of a beacon map ({id: (x, y)}), a turret offset (m) and the filter settings."""
    ekf = BearingEkf(
        beacons_xy,
        sensor_offset_m,
        settings.process_noise,
        settings.gate_probability,
        settings.odometry_errors,
        settings.power_bias,
        settings.turret_offset,
    )
    return Localiser(ekf, settings.localiser)
