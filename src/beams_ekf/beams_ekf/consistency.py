"""The Localiser's consistency monitors: is the estimate still the robot's pose?

- `KidnapEvidence`: the robot was carried elsewhere (kidnapped) when most of the recent bearings were
  gated out and ToTal is confident of a pose inconsistent with the estimate (identified beacons make
  this possible, thesis ch. 8 "System deployment").
- `NisMonitor`: the filter is lost when the bearings' innovations, over a sliding window, are too large
  for its covariance.
Either lets the next ToTal fix re-initialise the filter (`Localiser.on_pose`).
- `BeaconExclusion`: one beacon whose bearings the gate refuses while the others' pass (moved, biased, a
  reflection taken for it) is excluded until its bearings agree again, instead of making the filter lost
  and re-initialising it from a ToTal fix that uses that beacon.
- `PoseConfirmation`: after an event that breaks the estimate's continuity (an operator's pose, an
  implausible odometry step, an odometry silence, a time jump, a re-initialisation from ToTal after a
  kidnap or a lost test), the estimate is not the filter's own until its bearings confirm it: the status
  says degraded meanwhile (a pose no sensor has verified must not be called "tracking").
"""

from collections import deque
from functools import lru_cache
from math import copysign, exp, hypot, isfinite, lgamma, log, sqrt
from statistics import NormalDist

import numpy as np

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.pose2d import Pose2D
from beams_ekf.pose_filter import BearingOutcome, BearingReason, PoseFilter


@lru_cache(maxsize=256)  # a Localiser asks for every window length's quantile at its creation
def chi2_quantile(probability: float, dof: int) -> float:
    """The chi-square distribution's quantile (scipy.stats' chi2.ppf, to 1e-12): its CDF is the regularised
    incomplete gamma function P(dof/2, x/2), the lower one summed by its series below x/2 = dof/2 + 1 and
    the upper one by its continued fraction above (each where it keeps its precision), inverted by Newton's
    method from the Wilson-Hilferty approximation. scipy.stats' import would be a second of a node's start."""
    if not 0.0 < probability < 1.0 or dof < 1:
        raise ValueError(
            f"chi-square quantile at {probability} with {dof} dof: 0 < probability < 1, dof >= 1"
        )
    a = dof / 2.0

    def excess_and_density(x: float) -> tuple[float, float]:
        """CDF(x) - probability, computed as the smaller tail, and the density at x."""
        half = x / 2.0
        scale = exp(a * log(half) - half - lgamma(a))
        if half < a + 1.0:
            term = total = 1.0 / a
            n = 0
            while term > total * 1e-17:
                n += 1
                term *= half / (a + n)
                total += term
            excess = scale * total - probability
        else:  # modified Lentz evaluation of the upper tail's continued fraction
            b = half + 1.0 - a
            c, d = 1e300, 1.0 / b
            fraction = d
            for n in range(1, 1000):
                an = -n * (n - a)
                b += 2.0
                d = 1.0 / (an * d + b or 1e-300)
                c = b + an / c or 1e-300
                fraction *= d * c
                if abs(d * c - 1.0) < 1e-16:
                    break
            excess = (1.0 - probability) - scale * fraction
        return excess, scale / x

    z = NormalDist().inv_cdf(probability)
    x = max(dof * (1.0 - 2.0 / (9.0 * dof) + z * sqrt(2.0 / (9.0 * dof))) ** 3, 1e-3)
    for _ in range(100):
        excess, density = excess_and_density(x)
        step = excess / density
        x = max(x - step, x / 10.0)
        if abs(step) <= 1e-14 * x:
            break
    return x


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
            chi2_quantile(probability, n) for n in range(1, max(window_bearings, 1) + 1)
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


class KidnapEvidence:
    """Gated (True) or accepted (False) for the last `window_bearings` new bearings, and the test of a
    ToTal pose against the estimate.

    The filter is suspected kidnapped when at least `gated_bearings` of them were gated out (a filter
    initialised a little wrong, and overconfident, still accepts some bearings in between); a ToTal pose
    is then taken when it is elsewhere: inconsistent with the estimate (chi-square, 3 dof, at
    `probability`, the two covariances summed) or farther than `distance_m` / `heading_rad`.
    """

    def __init__(
        self,
        window_bearings: int,
        gated_bearings: int,
        probability: float,
        distance_m: float,
        heading_rad: float,
    ) -> None:
        self._recent_gated: deque[bool] = deque(maxlen=window_bearings)
        self._gated_bearings = gated_bearings
        self._threshold = chi2_quantile(probability, 3)
        self._distance_m = distance_m
        self._heading_rad = heading_rad

    def add(self, gated: bool) -> None:
        """Record one new bearing: gated out (True) or accepted (False)."""
        self._recent_gated.append(gated)

    @property
    def recent_gated_bearings(self) -> int:
        """Gated bearings among the last window_bearings new ones (a diagnostic)."""
        return sum(self._recent_gated)

    @property
    def suspected(self) -> bool:
        """True when at least gated_bearings of the last window_bearings were gated out."""
        return self.recent_gated_bearings >= self._gated_bearings

    def elsewhere(
        self, pose: Pose2D, covariance: np.ndarray, estimate: Pose2D, estimate_covariance: np.ndarray
    ) -> bool:
        """True when `pose` (of `covariance`) is inconsistent with the estimate or beyond the absolute
        thresholds: the squared Mahalanobis distance of the difference, under the sum of the two
        covariances, above the chi-square (3 dof) quantile at the kidnap probability."""
        x, y, theta = estimate
        difference = np.array([pose[0] - x, pose[1] - y, wrap_to_pi(pose[2] - theta)])
        combined = estimate_covariance + np.asarray(covariance, dtype=float).reshape(3, 3)
        try:
            distance2 = float(difference @ np.linalg.solve(combined, difference))
        except np.linalg.LinAlgError:
            distance2 = float("inf")
        return (
            not distance2 <= self._threshold
            or hypot(difference[0], difference[1]) > self._distance_m
            or abs(difference[2]) > self._heading_rad
        )

    def clear(self) -> None:
        self._recent_gated.clear()


# An excluded beacon's bearings in a row within the gate after which ToTal's fixes (which use it) may
# re-initialise a lost filter again: one revolution of it is a single draw, three are evidence.
AGREEING_AGAIN = 3
# A gated bearing is a fault detected until its beacon's next bearing is accepted, or until this many
# bearings of the other beacons (three revolutions of two) were accepted without it: it was not applied, a
# beacon hidden after it leaves the others to judge the estimate.
DETECTION_HOLD_BEARINGS = 6


class BeaconExclusion:
    """Fault detection and exclusion of one beacon, as RAIM excludes one satellite.

    `add` records each new bearing the filter judged. `gated_bearings` gated bearings of one beacon in a
    row, with another beacon's bearing accepted since the first of them, make it the suspect while the
    estimate is trusted (confirmed, not kidnapped): the estimate agrees with the other beacons and not
    with it (when every beacon's bearings are gated the robot moved: `KidnapEvidence`'s case);
    `LateBearings` then excludes the beacon the history blames (`exclude`). An excluded
    beacon's bearings are judged without being applied (`PoseFilter.excluded_beacons`) and readmit it when
    `readmission_bearings` of them in a row pass the gate with normalised residuals r / sqrt(S) whose
    mean is zero within 3 sigma (|sum| <= 3 sqrt(n)): a bias that lets single bearings through (a moved
    beacon seen along its displacement) is not readmitted. One beacon at most (a single fault: with two
    beacons left, a second disagreeing one cannot be told from the first). Each gated bearing is a fault
    detected at once (`problem`, DETECTION_HOLD_BEARINGS). `gated_bearings` 0 switches the detection and
    the exclusion off.
    """

    def __init__(self, pose_filter: PoseFilter, gated_bearings: int, readmission_bearings: int) -> None:
        self._filter = pose_filter
        self._gated_bearings = gated_bearings
        self._readmission_bearings = readmission_bearings
        self.excluded: int | None = None
        # the beacon whose gated bearings call for an exclusion; `exclude` names the one excluded
        self.suspect: int | None = None
        self._gated_in_a_row: dict[int, int] = {}
        self._others_agreed: dict[int, bool] = {}  # since the first of the beacon's gated bearings
        self._detected: dict[int, int] = {}  # a gated beacon: the others' bearings accepted since
        self._agreeing: list[float] = []  # the excluded beacon's normalised residuals in a row

    def add(self, beacon_id: int, outcome: BearingOutcome, trusted: bool = True) -> str:
        """One new bearing the filter judged (accepted, gated or excluded); `trusted`: the estimate may be
        held against a beacon (its gated bearings then make it the `suspect`). Returns 'readmitted' when
        that readmits the excluded beacon, '' otherwise."""
        if outcome.reason is BearingReason.EXCLUDED:
            normalised_residual = copysign(sqrt(outcome.nis), outcome.residual_rad)
            within = outcome.nis <= self._filter.gate
            self._agreeing = [*self._agreeing, normalised_residual] if within else []
            n = len(self._agreeing)
            if n < self._readmission_bearings or abs(sum(self._agreeing)) > 3.0 * sqrt(n):
                return ""
            self.clear()
            return "readmitted"
        if outcome.reason is not BearingReason.GATED:
            self._gated_in_a_row[beacon_id] = 0
            self._detected.pop(beacon_id, None)
            for other in self._others_agreed:
                self._others_agreed[other] = self._others_agreed[other] or other != beacon_id
            for other, accepted in list(self._detected.items()):
                self._detected[other] = accepted + 1
                if accepted + 1 >= DETECTION_HOLD_BEARINGS:
                    del self._detected[other]
            return ""
        if self._gated_bearings:
            self._detected[beacon_id] = 0
        in_a_row = self._gated_in_a_row.get(beacon_id, 0) + 1
        self._gated_in_a_row[beacon_id] = in_a_row
        if in_a_row == 1:
            self._others_agreed[beacon_id] = False
        if self.excluded is not None or not self._gated_bearings or in_a_row < self._gated_bearings:
            return ""
        if trusted and self._others_agreed[beacon_id]:
            self.suspect = beacon_id
        return ""

    def exclude(self, beacon_id: int) -> None:
        """Exclude this beacon (the suspect or, on the history's evidence, the one that pulled the estimate
        towards the suspect's disagreement: `LateBearings`)."""
        self.excluded, self.suspect, self._agreeing = beacon_id, None, []
        self._filter.excluded_beacons = {beacon_id}

    @property
    def agrees_again(self) -> bool:
        """True when no beacon is excluded, or the excluded one's last AGREEING_AGAIN bearings passed the
        gate: a filter lost then (the two other beacons' solution drifted) may take ToTal's fix again."""
        return self.excluded is None or len(self._agreeing) >= AGREEING_AGAIN

    @property
    def problem(self) -> str:
        """Why the status is degraded while a beacon is excluded, or while a beacon's newest bearing was
        gated (a fault detected, as RAIM's test alerts before its exclusion: the bias it shows may already
        be in the estimate, within the gate), or ''."""
        if self.excluded is None:
            if not self._detected:
                return ""
            detected = ", ".join(str(b) for b in sorted(self._detected))
            return f"newest bearing of beacon {detected} gated: a fault detected, not yet excluded"
        return (
            f"beacon {self.excluded} excluded: its bearings disagree with the other beacons' (moved, "
            f"biased or reflected?); {len(self._agreeing)} of {self._readmission_bearings} agreeing "
            "bearings to readmit it"
        )

    def clear(self) -> None:
        """Every beacon's bearings applied again (a new estimate, a new beacon map or gate)."""
        self.excluded = self.suspect = None
        self._filter.excluded_beacons = set()
        self._gated_in_a_row.clear()
        self._others_agreed.clear()
        self._detected.clear()
        self._agreeing = []


# The bearings that confirm a pose (LocaliserConfig.confirming_bearings) come from at least this many
# beacons: the bearings of a single beacon leave the position free along the line to it.
CONFIRMING_BEACONS = 2
# Odometry silent this long (s) leaves the estimate behind a moving robot (25 samples of 50 Hz odometry,
# 0.25 m at 0.5 m/s): in data time it breaks the estimate's continuity (a restarted odometry source that
# jumped within its speed limit over the silence, a simulator's new match, is not refused as a jump); on
# the receiving clock it is ekf_health's "no odometry" (lost).
ODOMETRY_SILENCE_S = 0.5


class PoseConfirmation:
    """Whether the bearings have confirmed the estimate since the last break of its continuity.

    `broken(event)` makes the estimate unconfirmed; `add(beacon_id, gated)` records each new bearing the
    filter judged (accepted or gated out): `confirming_bearings` accepted in a row, from at least
    CONFIRMING_BEACONS beacons, confirm it; a gated one starts the count again. `confirming_bearings` 0
    switches the check off (every pose confirmed at once). The very first initialisation from ToTal
    needs no confirmation: its pose is the bearings' own (one revolution triangulated and gated by ToTal),
    while an operator's is no sensor's, and a re-initialisation after a kidnap or a lost test follows
    evidence that the world broke the estimate (the fix may straddle it).

    A break within RELAPSE_BEARINGS accepted bearings of the last confirmation is a relapse: that
    confirmation rested on too little (bearings wrong alike, a wrong calibration, agree with the wrong
    pose ToTal made of them), so each relapse multiplies the bearings needed by RELAPSE_FACTOR (at most
    MAX_RELAPSES times); RELAPSE_BEARINGS accepted after a confirmation forgive them.
    """

    RELAPSE_BEARINGS = 90
    RELAPSE_FACTOR = 3
    MAX_RELAPSES = 2

    def __init__(self, confirming_bearings: int) -> None:
        self.confirming_bearings = confirming_bearings
        self._event = ""  # '' when confirmed
        self._run: list[int] = []  # beacon ids of the accepted bearings in a row since the event
        self._relapses = 0
        self._since_confirmed: int | None = None  # accepted bearings since the last confirmation

    @property
    def confirmed(self) -> bool:
        return not self._event

    @property
    def event(self) -> str:
        """The event since which the estimate is unconfirmed ('' when confirmed)."""
        return self._event

    @property
    def needed(self) -> int:
        """The accepted bearings in a row that confirm the estimate now."""
        return self.confirming_bearings * self.RELAPSE_FACTOR**self._relapses

    def broken(self, event: str) -> None:
        """An event broke the estimate's continuity (no effect when the check is off)."""
        if self.confirming_bearings:
            relapse = self._since_confirmed is not None and self._since_confirmed < self.RELAPSE_BEARINGS
            self._relapses = min(self._relapses + 1, self.MAX_RELAPSES) if relapse else 0
            self._event, self._since_confirmed = event, None
            self._run.clear()

    def add(self, beacon_id: int, gated: bool) -> bool:
        """One new bearing judged by the filter; True when it completes the confirmation."""
        if self.confirmed:
            if self._since_confirmed is not None and not gated:  # `broken` judges a relapse by it
                self._since_confirmed = min(self._since_confirmed + 1, self.RELAPSE_BEARINGS)
            return False
        if gated:
            self._run.clear()
            return False
        self._run.append(beacon_id)
        if len(self._run) >= self.needed and len(set(self._run)) >= CONFIRMING_BEACONS:
            self._event, self._since_confirmed = "", 0
            self._run.clear()
            return True
        return False

    @property
    def problem(self) -> str:
        """Why the estimate is not confirmed, or ''."""
        if self.confirmed:
            return ""
        relapse = f", {self._relapses} break(s) soon after a confirmation" if self._relapses else ""
        return (
            f"pose not yet confirmed by the bearings since {self._event} "
            f"({len(self._run)} of {self.needed} agreeing bearings{relapse})"
        )

    def clear(self) -> None:
        """Confirmed, relapses forgotten (a reset: the next initialisation from ToTal is a first one)."""
        self._event, self._relapses, self._since_confirmed = "", 0, None
        self._run.clear()
