"""A pose the filter has not verified with its own bearings is not "tracking" (issue 18): after an event
that breaks the estimate's continuity (an operator's pose, an odometry jump or silence, a time jump, a
re-initialisation from ToTal after a kidnap) ekf_node's status model (`Localiser.unconfirmed` judged by
`EkfHealth.verdict`, as ekf_node wires them) says degraded until confirming_bearings accepted bearings in
a row (three revolutions of the three beacons) confirm it; bearings that disagree keep it unconfirmed
and the kidnap evidence re-initialises from ToTal."""

from dataclasses import dataclass, replace
from itertools import groupby
from math import hypot, sqrt

import numpy as np
import pytest

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.bearing import Bearing
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake
from beams_common.status.health import BEARING_RATE_SPECS, ODOMETRY_RATE_SPEC, Status
from beams_common.status.protection_level import INTEGRITY_SPECS
from beams_ekf.consistency import DETECTION_HOLD_BEARINGS, BeaconExclusion, PoseConfirmation
from beams_ekf.ekf_health import EkfHealth
from beams_ekf.localiser import Localiser, build_localiser, revolution_of
from beams_ekf.outcomes import OdometryOutcome, PoseOutcome
from beams_ekf.parameters import filter_settings
from beams_ekf.pose_filter import BearingOutcome, BearingReason
from beams_ekf.settings import FilterSettings, LocaliserConfig
from beams_thesis.synthetic import SyntheticMatch, synthetic_match

VALUES = {spec.name: spec.default for spec in (*BEARING_RATE_SPECS, ODOMETRY_RATE_SPEC, *INTEGRITY_SPECS)}
EVENT_S = 2.0  # the break of continuity, once the filter tracks
CONFIRMING_BEARINGS = LocaliserConfig().confirming_bearings
ONE_CM = np.diag([1e-4, 1e-4, 1e-4])  # 1 cm, 0.6 deg: ToTal's fixes and the operators' poses
# the fault campaign's hazardously misleading error: beyond max(5 cm, 5 sigma) while tracking
MISLEADING_FLOOR_M, MISLEADING_SIGMAS = 0.05, 5.0


@dataclass(frozen=True)
class Step:
    """The status model's verdict after one revolution, with the estimate's error."""

    arrival_s: float
    status: Status
    message: str
    error_m: float
    sigma_m: float

    @property
    def misleading(self) -> bool:
        return self.status is Status.TRACKING and self.error_m > max(
            MISLEADING_FLOOR_M, MISLEADING_SIGMAS * self.sigma_m
        )


def _localiser(**localiser_settings) -> Localiser:
    settings = FilterSettings()
    settings = replace(settings, localiser=replace(settings.localiser, **localiser_settings))
    return build_localiser(EUROBOT_BEACON_MAP.as_dict(), (0.0, 0.0), settings)


class Drive:
    """The match fed to a Localiser and its EkfHealth as ekf_node feeds them (odometry at 50 Hz, a
    revolution at 10 Hz, ToTal's fix of each revolution: the truth at its middle, 1 cm), the verdict taken
    after each revolution (ekf_node publishes after each) and after a ToTal fix that (re-)initialised the
    filter. `odometry_of(t, pose)` corrupts the odometry; nothing at all comes during
    `silence` (start, end), s (a simulator killed and restarted)."""

    def __init__(self, match: SyntheticMatch, localiser: Localiser, odometry_of=None, silence=(0.0, 0.0)):
        self.match, self.localiser = match, localiser
        self.health = EkfHealth(VALUES, 0.0)
        self.odometry_of = odometry_of or (lambda t, pose: pose)
        self.silence = silence
        by_arrival = groupby(match.bearings, key=lambda b: b.arrival_s)
        self.revolutions = [(arrival_s, list(group)) for arrival_s, group in by_arrival]
        self.next_revolution = 0
        self.next_odometry = 0

    def until(self, end_s: float, *, fixes: bool = True) -> list[Step]:
        steps = []
        while self.next_revolution < len(self.revolutions):
            arrival_s, group = self.revolutions[self.next_revolution]
            if arrival_s > end_s:
                break
            self.next_revolution += 1
            self._odometry_until(arrival_s)
            if self._silent(arrival_s):
                continue
            self.health.on_bearings(arrival_s)
            revolution = [Bearing(b.stamp_s, b.beacon_id, b.bearing_rad, b.variance_rad2) for b in group]
            self.localiser.on_bearings(revolution_of(self.localiser, revolution))
            steps.append(self.step(arrival_s))
            if fixes:
                stamp_s = arrival_s - 0.05
                truth = self.match.truth_at(stamp_s)
                fix = self.localiser.on_pose(planar_pose_intake(PoseSource.TOTAL, stamp_s, truth, ONE_CM))
                if fix.taken:
                    steps.append(self.step(arrival_s))
        return steps

    def _odometry_until(self, end_s: float) -> None:
        times = self.match.times_s
        while self.next_odometry < len(times) and times[self.next_odometry] <= end_s:
            t = float(times[self.next_odometry])
            pose = self.odometry_of(t, np.array(self.match.odometry[self.next_odometry]))
            self.next_odometry += 1
            if self._silent(t):
                continue
            self.health.on_odometry(t)
            if self.localiser.on_odometry(t, tuple(pose)) is OdometryOutcome.JUMPED:  # as ekf_node does
                self.health.fault("odometry_jump", t, self.localiser.last_odometry_jump)

    def _silent(self, t: float) -> bool:
        return self.silence[0] < t <= self.silence[1]

    def operator_pose(self, pose) -> PoseOutcome:
        """An operator's pose taken "now" (the newest odometry), as ~/set_pose with a zero stamp."""
        return self.localiser.on_pose(planar_pose_intake(PoseSource.OPERATOR, 0.0, pose, ONE_CM))

    def step(self, now_s: float) -> Step:
        """The verdict as ekf_node forms it (`EkfHealth.judge`), with the estimate's error."""
        estimate = self.localiser.estimate()
        _, _, verdict = self.health.judge(now_s, self.localiser, estimate)
        if estimate is None:
            return Step(now_s, verdict.status, verdict.message, float("nan"), float("nan"))
        truth = self.match.truth_at(estimate.stamp_s)
        offset = np.array([estimate.pose[0] - truth[0], estimate.pose[1] - truth[1]])
        error = hypot(*offset)
        along = offset / error if error > 0.0 else np.array([1.0, 0.0])
        sigma = sqrt(float(along @ estimate.covariance[:2, :2] @ along))  # along the error, as the campaign
        return Step(now_s, verdict.status, verdict.message, error, sigma)


@pytest.fixture(scope="module")
def match() -> SyntheticMatch:
    return synthetic_match(5.0, seed=18)


def _statuses(steps: list[Step]) -> list[Status]:
    return [step.status for step in steps]


def _tracking_but_detections(steps: list[Step]) -> bool:
    """Tracking at every step but those degraded by a gated bearing alone (a fault detected, for a
    revolution or a few: the gate takes out a bearing now and then), at most one step in ten (or one)."""
    detected = [s for s in steps if s.status is not Status.TRACKING]
    only = "degraded: newest bearing of beacon"
    return all(s.message.startswith(only) and ";" not in s.message for s in detected) and (
        len(detected) <= max(1, len(steps) // 10)
    )


def _tracking(drive: Drive) -> None:
    """Drive to EVENT_S: ToTal's first fix initialises the filter, tracking from its first bearings on."""
    steps = drive.until(EVENT_S)
    assert _statuses(steps[:2]) == [Status.WAITING, Status.DEGRADED]  # before and after the first fix
    assert "no accepted bearing" in steps[1].message and "confirmed" not in steps[1].message
    assert _tracking_but_detections(steps[2:])
    assert drive.localiser.stats.counts["initialisations"] == 1
    assert drive.localiser.stats.counts["continuity_breaks"] == 0


def test_the_first_initialisation_from_total_is_tracking_at_once(match):
    drive = Drive(match, _localiser())
    steps = drive.until(1.0)
    # ToTal's fix of the first revolution: the bearings' own pose, nothing to confirm; degraded only
    # until the filter's first bearing (no accepted bearing yet), tracking from the next revolution on
    assert _statuses(steps[:3]) == [Status.WAITING, Status.DEGRADED, Status.TRACKING]
    assert steps[1].message == "degraded: no accepted bearing yet: odometry only"
    assert _tracking_but_detections(steps[2:])
    assert not any(step.misleading for step in steps)


def test_a_right_operator_pose_is_degraded_until_three_revolutions_agree(match):
    drive = Drive(match, _localiser())
    _tracking(drive)
    assert drive.operator_pose(match.truth_at(drive.localiser.history.latest[0])) is PoseOutcome.INITIALISED
    at_once = drive.step(EVENT_S)
    assert at_once.status is Status.DEGRADED
    assert "pose not yet confirmed by the bearings since an operator's pose (0 of 9" in at_once.message
    steps = drive.until(EVENT_S + 1.0)
    # three bearings a revolution: 3 and 6 agreeing after the first two, confirmed by the third
    assert _statuses(steps[:3]) == [Status.DEGRADED, Status.DEGRADED, Status.TRACKING]
    assert "(3 of 9 agreeing bearings)" in steps[0].message
    assert "(6 of 9 agreeing bearings)" in steps[1].message
    assert _tracking_but_detections(steps[2:])
    assert drive.localiser.stats.counts["pose_confirmations"] == 1
    assert max(step.error_m for step in steps) < 0.02


def test_an_operator_pose_half_a_metre_off_stays_degraded_until_the_kidnap_evidence_reinitialises(match):
    drive = Drive(match, _localiser())
    _tracking(drive)
    x, y, theta = match.truth_at(drive.localiser.history.latest[0])
    drive.operator_pose((x + 0.5, y, theta))  # the campaign's set_pose_wrong_place: 0.5 m off, 1 cm
    steps = [drive.step(EVENT_S), *drive.until(EVENT_S + 2.0)]
    counts = drive.localiser.stats.counts
    assert counts["kidnap_reinitialisations"] + counts["lost_reinitialisations"] == 1
    assert counts["pose_confirmations"] == 1
    wrong = [step for step in steps if step.error_m > 0.25]  # the operator's pose, before ToTal's
    assert steps[: len(wrong)] == wrong and 2 <= len(wrong) <= 4, [(s.arrival_s, s.error_m) for s in steps]
    # not tracking one instant while wrong: degraded (unconfirmed), then lost (its bearings gated out)
    assert _statuses(wrong)[0] is Status.DEGRADED and _statuses(wrong)[-1] is Status.LOST
    assert all("not yet confirmed by the bearings since an operator's pose" in step.message for step in wrong)
    # ToTal's re-initialisation is unconfirmed in turn: three revolutions, then tracking to the end
    after = steps[len(wrong) :]
    assert "since a re-initialisation from ToTal after" in after[0].message
    assert _statuses(after[:4]) == [Status.DEGRADED] * 3 + [Status.TRACKING]
    assert _tracking_but_detections(after[3:])
    assert not any(step.misleading for step in steps)


def test_without_total_an_operator_pose_half_a_metre_off_is_never_tracking(match):
    drive = Drive(match, _localiser())
    _tracking(drive)
    x, y, theta = match.truth_at(drive.localiser.history.latest[0])
    drive.operator_pose((x + 0.5, y, theta))
    steps = drive.until(EVENT_S + 2.0, fixes=False)
    assert Status.TRACKING not in _statuses(steps)
    assert drive.localiser.stats.counts["pose_confirmations"] == 0
    assert min(step.error_m for step in steps) > 0.2  # nothing corrected it, and nothing called it right


def test_with_the_check_off_an_operator_pose_is_tracking_at_once(match):
    """confirming_bearings 0 (the fault campaign's check-disabled run): the status of main before issue 18's
    confirmation, a wrong operator pose "tracking" until the kidnap evidence finds it out."""
    drive = Drive(match, _localiser(confirming_bearings=0))
    _tracking(drive)
    x, y, theta = match.truth_at(drive.localiser.history.latest[0])
    drive.operator_pose((x + 0.5, y, theta))
    assert drive.step(EVENT_S).status is Status.TRACKING
    assert drive.step(EVENT_S).misleading


def _jump(t: float, pose: np.ndarray) -> np.ndarray:
    return pose + np.array([100.0, 0.0, 0.0]) if t > EVENT_S else pose


@pytest.mark.parametrize(
    ("odometry_of", "silence", "event"),
    [
        (_jump, (0.0, 0.0), "since an odometry jump"),
        (None, (EVENT_S, EVENT_S + 0.8), "since an odometry silence of 0.8 s"),
    ],
    ids=["+100 m jump", "0.8 s silence"],
)
def test_an_odometry_jump_or_silence_is_degraded_until_confirmed(match, odometry_of, silence, event):
    drive = Drive(match, _localiser(), odometry_of, silence)
    _tracking(drive)
    steps = drive.until(EVENT_S + 3.0)
    broken = [k for k, step in enumerate(steps) if event in step.message]
    assert broken, [step.message for step in steps[:12]]
    first = broken[0]
    # unconfirmed for the two revolutions after the event's first, the third confirms it
    assert broken == [first, first + 1, first + 2] or broken == [first, first + 1], broken
    assert all(steps[k].status is not Status.TRACKING for k in broken)
    assert drive.localiser.stats.counts["continuity_breaks"] == 1
    assert drive.localiser.stats.counts["pose_confirmations"] == 1
    assert steps[-1].status is Status.TRACKING  # after the jump's 2-s fault hold too
    assert not any(step.misleading for step in steps)


def test_the_first_fix_after_a_time_jump_is_confirmed_by_the_bearings(match):
    localiser = _localiser()
    _tracking(Drive(match, localiser))
    # the bag loops: the same match again, stamps back at 0 (time_jump_confirmations messages confirm it)
    again = Drive(match, localiser)
    steps = again.until(1.0)
    assert localiser.stats.counts["time_jump_resets"] == 1
    assert localiser.stats.counts["initialisations"] == 2
    initialised = [step for step in steps if step.status is not Status.WAITING]
    assert "since a time jump (odometry stamps went back) (0 of 9" in initialised[0].message
    assert _statuses(initialised[:4]) == [Status.DEGRADED] * 3 + [Status.TRACKING]


def test_a_manual_reset_forgets_the_break():
    confirmation = PoseConfirmation(CONFIRMING_BEARINGS)
    confirmation.broken("an operator's pose")
    assert not confirmation.confirmed
    confirmation.clear()
    assert confirmation.confirmed and confirmation.problem == ""


def test_a_gated_bearing_starts_the_count_again_and_one_beacon_never_confirms():
    confirmation = PoseConfirmation(CONFIRMING_BEARINGS)
    confirmation.broken("an operator's pose")
    for beacon_id in (1, 2, 3) * 2 + (1, 2):
        assert not confirmation.add(beacon_id, gated=False)
    assert "(8 of 9" in confirmation.problem
    assert not confirmation.add(3, gated=True)  # one disagreeing bearing: the run starts over
    assert "(0 of 9" in confirmation.problem
    for _ in range(3 * CONFIRMING_BEARINGS):  # one beacon's bearings alone leave the position free
        assert not confirmation.add(1, gated=False)
    assert not confirmation.confirmed
    assert confirmation.add(2, gated=False)  # a second beacon: confirmed
    assert confirmation.confirmed and confirmation.problem == ""
    assert not confirmation.add(3, gated=True)  # once confirmed, the kidnap and NIS tests judge


def test_the_check_switched_off_never_breaks():
    confirmation = PoseConfirmation(0)
    confirmation.broken("an operator's pose")
    assert confirmation.confirmed
    with pytest.raises(ValueError, match="confirming_bearings"):
        filter_settings({"confirming_bearings": -1})


# -- one beacon that disagrees: excluded, not a reason to re-initialise ------------------------------------
FAULT_S = (2.5, 4.5)
FAULTY_BEACON = 2


def _faulty(match: SyntheticMatch, offset_rad) -> SyntheticMatch:
    """FAULTY_BEACON's bearings moved by offset_rad(bearing) (0 outside the fault)."""
    bearings = [
        replace(b, bearing_rad=b.bearing_rad + offset_rad(b)) if b.beacon_id == FAULTY_BEACON else b
        for b in match.bearings
    ]
    return replace(match, bearings=bearings)


@pytest.fixture(scope="module")
def long_match() -> SyntheticMatch:
    return synthetic_match(10.0, seed=18)


def test_a_beacon_biased_half_a_degree_is_excluded_and_never_misleads(long_match):
    """0.5 deg on beacon 2 for 2 s (a reflection, a bent mount): its bearings are gated, two in a row with
    the others' accepted between exclude it within two revolutions (degraded, saying which beacon), the
    filter goes on with the other two, right, and no ToTal fix (which uses it) re-initialises it while the
    beacon disagrees; after the fault the beacon is back (readmitted by its agreeing bearings, or by a
    re-initialisation once they agree, when the two beacons' solution drifted) and the status tracking."""
    start_s, end_s = FAULT_S
    biased = _faulty(long_match, lambda b: np.radians(0.5) if start_s <= b.stamp_s < end_s else 0.0)
    drive = Drive(biased, _localiser())
    _tracking(drive)
    steps = drive.until(10.0)
    counts = drive.localiser.stats.counts
    assert counts["beacons_excluded"] == 1, counts
    assert counts["beacons_readmitted"] + counts["lost_reinitialisations"] == 1, counts
    assert counts["kidnap_reinitialisations"] == 0
    excluded = [step for step in steps if f"beacon {FAULTY_BEACON} excluded" in step.message]
    assert excluded[0].arrival_s - start_s <= 0.25, [(s.arrival_s, s.message) for s in steps[:8]]
    assert Status.TRACKING not in _statuses(excluded)
    assert end_s < excluded[-1].arrival_s < end_s + 4.0
    after = [step for step in steps if step.arrival_s > excluded[-1].arrival_s + 0.5]
    assert after and _tracking_but_detections(after)
    assert max(step.error_m for step in steps) < 0.01
    assert not any(step.misleading for step in steps)


def test_a_moved_beacon_is_never_misleading(long_match):
    """Beacon 2 moved 3 cm along x at FAULT_S[0] (the map not told): its bearings shift by 2 mrad at first,
    within the gate, and pull the estimate until another beacon's are gated: a beacon is excluded (here
    beacon 3, the wrong one: a bias that grows from inside the gate is not told from the beacon it pulls
    away from; docs/protection_level.md, "Not covered"), the estimate 1-2 cm off but never beyond the
    campaign's misleading bound while tracking, and degraded at the end."""
    x, y = EUROBOT_BEACON_MAP.as_dict()[FAULTY_BEACON]

    def shift(b) -> float:
        if b.stamp_s < FAULT_S[0]:
            return 0.0
        tx, ty, _ = long_match.truth_at(b.stamp_s)
        return float(np.arctan2(y - ty, x + 0.03 - tx) - np.arctan2(y - ty, x - tx))

    drive = Drive(_faulty(long_match, shift), _localiser())
    _tracking(drive)
    steps = drive.until(10.0)
    counts = drive.localiser.stats.counts
    assert counts["beacons_excluded"] == 1 and counts["beacons_readmitted"] == 0, counts
    assert steps[-1].status is Status.DEGRADED and "excluded" in steps[-1].message
    assert not any(step.misleading for step in steps)


class _Gate:
    """The part of a PoseFilter that BeaconExclusion uses."""

    def __init__(self) -> None:
        self.gate = 10.83
        self.excluded_beacons: set[int] = set()


def _exclusion(gated_bearings: int = 2, readmission_bearings: int = 4) -> BeaconExclusion:
    return BeaconExclusion(_Gate(), gated_bearings, readmission_bearings)


def _judged(reason: BearingReason, normalised_residual: float = 5.0) -> BearingOutcome:
    return BearingOutcome(
        reason is BearingReason.ACCEPTED, normalised_residual**2, normalised_residual, reason
    )


GATED, ACCEPTED = _judged(BearingReason.GATED), _judged(BearingReason.ACCEPTED, 0.5)


def test_the_exclusion_needs_another_beacon_agreeing_and_a_trusted_estimate():
    """Every beacon gated (the robot moved: the kidnap evidence's case) or an unconfirmed estimate: no
    beacon is blamed; one beacon gated twice with another accepted between: excluded (the filter told),
    one at most."""
    exclusion = _exclusion()
    for beacon in (1, 2, 3, 1, 2, 3):
        exclusion.add(beacon, GATED)
    assert exclusion.suspect is None
    exclusion = _exclusion()
    for beacon in (1, 2, 3, 1, 2, 3):
        exclusion.add(beacon, GATED if beacon == 2 else ACCEPTED, trusted=False)
    assert exclusion.suspect is None
    exclusion = _exclusion()
    suspects = []
    for beacon in (1, 2, 3, 1, 2):
        exclusion.add(beacon, ACCEPTED if beacon == 1 else GATED)
        suspects.append(exclusion.suspect)
    assert suspects == [None, None, None, None, 2] and exclusion.excluded is None
    exclusion.exclude(2)  # LateBearings' choice on the history's evidence
    assert exclusion.excluded == 2 and exclusion.suspect is None
    assert exclusion._filter.excluded_beacons == {2} and "beacon 2 excluded" in exclusion.problem
    exclusion.add(3, GATED)
    exclusion.add(3, GATED)  # one beacon at most
    assert exclusion.suspect is None
    off = _exclusion(gated_bearings=0)
    for beacon in (2, 1, 2):
        off.add(beacon, GATED if beacon == 2 else ACCEPTED)
    assert off.suspect is None and not off.problem


def test_a_break_soon_after_a_confirmation_needs_three_times_the_bearings_until_they_hold():
    """A relapse (the campaign's wrong calibration: bearings wrong alike confirmed ToTal's wrong pose, which
    broke again 1.6 s later, then was confirmed and 6.8 cm off while tracking): 27 bearings, then 81
    (at most), then forgiven after RELAPSE_BEARINGS accepted."""
    confirmation = PoseConfirmation(9)

    def confirm(bearings: int) -> list[bool]:
        return [confirmation.add(1 + k % 3, gated=False) for k in range(bearings)]

    confirmation.broken("a re-initialisation from ToTal after a kidnap")
    assert confirm(9)[-1] and confirmation.confirmed
    confirm(30)
    needed = []
    for _ in range(3):
        confirmation.broken("a re-initialisation from ToTal after a kidnap")
        needed.append(confirmation.needed)
        relapses = min(len(needed), PoseConfirmation.MAX_RELAPSES)
        assert confirmation.problem.endswith(
            f"(0 of {needed[-1]} agreeing bearings, {relapses} break(s) soon after a confirmation)"
        )
        assert not any(confirm(needed[-1] - 1)) and confirm(1) == [True]
    assert needed == [27, 81, 81]
    confirm(PoseConfirmation.RELAPSE_BEARINGS)
    confirmation.broken("an operator's pose")
    assert confirmation.needed == 9 and "break(s)" not in confirmation.problem


def test_a_gated_bearing_is_a_fault_detected_until_its_beacon_agrees_or_the_others_carry_on():
    """The alert comes with the first gated bearing (the time to alert: one revolution), before the
    exclusion's second: it ends with the beacon's next accepted bearing, or after DETECTION_HOLD_BEARINGS
    of the other beacons' accepted without it (hidden after its gated bearing)."""
    exclusion = _exclusion()
    exclusion.add(1, ACCEPTED)
    assert not exclusion.problem
    exclusion.add(2, GATED)
    assert "newest bearing of beacon 2 gated: a fault detected" in exclusion.problem
    exclusion.add(2, ACCEPTED)
    assert not exclusion.problem
    exclusion.add(3, GATED)
    held = []
    for k in range(DETECTION_HOLD_BEARINGS):
        held.append("beacon 3 gated" in exclusion.problem)
        exclusion.add(1 + k % 2, ACCEPTED)
    assert held == [True] * DETECTION_HOLD_BEARINGS and not exclusion.problem
    exclusion.add(2, GATED)
    exclusion.add(1, ACCEPTED)
    exclusion.add(2, GATED)  # the second: the suspect, then excluded; its reason replaces the detection
    exclusion.exclude(exclusion.suspect)
    assert "beacon 2 excluded" in exclusion.problem and "a fault detected" not in exclusion.problem


def test_an_excluded_beacon_is_readmitted_by_agreeing_bearings_of_zero_mean_only():
    """Within the gate but all on one side (a bias smaller than the gate): never readmitted; zero-mean
    ones: after readmission_bearings in a row; one beyond the gate starts the count again."""
    exclusion = _exclusion()
    exclusion.exclude(2)
    biased = _judged(BearingReason.EXCLUDED, 2.5)
    assert [exclusion.add(2, biased) for _ in range(20)] == [""] * 20
    events = [
        exclusion.add(2, _judged(BearingReason.EXCLUDED, z)) for z in (1.0, -1.0, 5.0, 0.5, -0.5, 1.0, -1.0)
    ]
    assert events == ["", "", "", "", "", "", "readmitted"] and exclusion.excluded is None
    assert exclusion._filter.excluded_beacons == set()
