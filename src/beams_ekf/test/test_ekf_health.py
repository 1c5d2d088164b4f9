"""ekf_node's status model (issue 18): tracking only while the filter's tests, the input rates and the
plausibility checks pass; a sequence of inputs drives it through every status."""

import numpy as np

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.intake.pose_intake import PoseSource, planar_pose_intake
from beams_common.status.health import BEARING_RATE_SPECS, ODOMETRY_RATE_SPEC, Status
from beams_common.status.protection_level import INTEGRITY_SPECS
from beams_ekf.ekf_health import WAITING_FOR_ODOMETRY, WAITING_FOR_POSE, EkfHealth
from beams_ekf.localiser import FilterSettings, build_localiser
from beams_ekf.outcomes import PoseOutcome

VALUES = {spec.name: spec.default for spec in (*BEARING_RATE_SPECS, ODOMETRY_RATE_SPEC, *INTEGRITY_SPECS)}
HEALTHY = {"nis_lost": False, "kidnap_suspected": False, "bearing_silence_s": 0.05}


def _run(health: EkfHealth, start_s: float, end_s: float, *, bearings=True, odometry=True) -> None:
    """10 Hz revolutions and 50 Hz odometry received from start_s to end_s."""
    for k in range(round((end_s - start_s) * 50)):
        now = start_s + k * 0.02
        if odometry:
            health.on_odometry(now)
        if bearings and k % 5 == 0:
            health.on_bearings(now)


def test_a_match_goes_waiting_tracking_degraded_lost_and_back():
    health = EkfHealth(VALUES, 0.0)
    localiser = build_localiser(EUROBOT_BEACON_MAP.as_dict(), (0.0, 0.0), FilterSettings())
    assert health.judge(0.0, localiser, None)[2].status is Status.WAITING
    _run(health, 0.0, 3.0)
    assert health.verdict(3.0, **HEALTHY).status is Status.TRACKING
    # bearings restamped 1 s late: refused, the status degraded with the reason while it lasts
    health.fault("bearings_late", 3.1, "revolution 31 stamped 1.000 s behind the receiving clock")
    verdict = health.verdict(3.2, **HEALTHY)
    assert verdict.status is Status.DEGRADED and "1.000 s behind" in verdict.message
    _run(health, 3.0, 6.0)
    assert health.verdict(6.0, **HEALTHY).status is Status.TRACKING  # the fault held 2 s, then cleared
    # the filter's NIS test fails: lost whatever the rest says
    assert health.verdict(6.0, **{**HEALTHY, "nis_lost": True}).status is Status.LOST
    assert health.verdict(6.0, **{**HEALTHY, "kidnap_suspected": True}).level == "error"
    # the odometry stops: lost within ODOMETRY_SILENCE_S
    _run(health, 6.0, 7.0, odometry=False)
    verdict = health.verdict(7.0, **HEALTHY)
    assert verdict.status is Status.LOST and "no odometry for 1.0 s" in verdict.message
    _run(health, 7.0, 10.0)
    assert health.verdict(10.0, **HEALTHY).status is Status.TRACKING


def test_slow_doubled_or_silent_bearings_degrade_the_status():
    health = EkfHealth(VALUES, 0.0)
    _run(health, 0.0, 3.0, bearings=False)
    verdict = health.verdict(3.0, **HEALTHY)
    assert verdict.status is Status.DEGRADED and "bearings at 0.0 Hz" in verdict.message
    _run(health, 3.0, 6.0)
    for k in range(20):  # a second driver in the namespace: 20 Hz
        health.on_bearings(6.0 + 0.1 * k)
        health.on_bearings(6.0 + 0.1 * k + 0.05)
    _run(health, 6.0, 8.0, bearings=False)  # odometry as usual
    assert "above 15 Hz" in health.verdict(8.0, **HEALTHY).message
    assert "odometry only" in health.verdict(20.0, **{**HEALTHY, "bearing_silence_s": 1.5}).message


def test_without_odometry_the_odometry_checks_stay_off_until_it_comes():
    health = EkfHealth(VALUES, 0.0)
    _run(health, 0.0, 3.0, odometry=False)
    assert health.verdict(3.0, **HEALTHY).status is Status.TRACKING
    health.on_odometry(3.0)
    assert "no odometry" in health.verdict(3.6, **HEALTHY).message
    health.reset()
    assert "odometry" not in health.verdict(3.6, **HEALTHY).message


def test_a_flagged_calibration_degrades_for_its_own_hold():
    health = EkfHealth(VALUES, 0.0)
    _run(health, 0.0, 3.0)
    health.fault("calibration_worse", 3.0, "the new calibration makes the recent bearings worse", 10.0)
    _run(health, 3.0, 12.0)
    assert "worse" in health.verdict(12.0, **HEALTHY).message
    _run(health, 12.0, 14.0)
    assert health.verdict(14.0, **HEALTHY).status is Status.TRACKING


def test_innovations_inconsistent_after_a_calibration_name_it_past_the_re_initialisation():
    """A calibration applied at runtime is judged by the innovations that follow: the NIS test failing
    within CALIBRATION_WATCH_S names it, and the status stays degraded naming it for FAULT_HOLD_S after."""
    health = EkfHealth(VALUES, 0.0)
    _run(health, 0.0, 3.0)
    health.calibration_applied(3.0, "the new beacon geometry (calibration_file 'wild.yaml')")
    _run(health, 3.0, 5.0)
    lost = health.verdict(5.0, **{**HEALTHY, "nis_lost": True})
    assert lost.status is Status.LOST
    assert "innovations inconsistent 2.0 s after the new beacon geometry (calibration_file 'wild.yaml')" in (
        lost.message
    )
    _run(health, 5.0, 6.5)  # re-initialised from ToTal, its innovations consistent again
    degraded = health.verdict(6.5, **HEALTHY)
    assert degraded.status is Status.DEGRADED and "'wild.yaml') was applied: check it" in degraded.message
    _run(health, 6.5, 7.5)
    assert health.verdict(7.5, **HEALTHY).status is Status.TRACKING  # FAULT_HOLD_S after the last failure
    _run(health, 7.5, 16.0)
    assert health.verdict(16.0, **HEALTHY).status is Status.TRACKING
    # lost long after the calibration: the NIS test alone, no calibration named
    late = health.verdict(16.0, **{**HEALTHY, "nis_lost": True})
    assert late.status is Status.LOST and "calibration" not in late.message


def test_without_odometry_the_ekf_says_it_waits_for_odometry_which_every_total_fix_needs():
    """ToTal's fix is brought to the filter's instant by the odometry since its stamp: without odometry
    every one is refused, so the status names odometry, not a pose, until odometry comes."""
    localiser = build_localiser(EUROBOT_BEACON_MAP.as_dict(), (0.0, 0.0), FilterSettings())
    health = EkfHealth(VALUES, 0.0)
    covariance = np.diag([1e-4, 1e-4, 1e-3])
    for k in range(5):
        fix = planar_pose_intake(PoseSource.TOTAL, 0.1 * k, (1.0, 1.0, 0.0), covariance)
        assert localiser.on_pose(fix) is PoseOutcome.OUTSIDE_HISTORY
        _, _, verdict = health.judge(0.1 * k, localiser, localiser.estimate())
        assert (verdict.status, verdict.reasons) == (Status.WAITING, (WAITING_FOR_ODOMETRY,))
    assert localiser.stats.counts["poses_outside_history"] == 5
    localiser.on_odometry(0.5, (0.0, 0.0, 0.0))
    localiser.on_odometry(0.6, (0.01, 0.0, 0.0))
    _, _, verdict = health.judge(0.6, localiser, localiser.estimate())
    assert verdict.reasons == (WAITING_FOR_POSE,)
    fix = planar_pose_intake(PoseSource.TOTAL, 0.55, (1.0, 1.0, 0.0), covariance)
    assert localiser.on_pose(fix) is PoseOutcome.INITIALISED
    _, _, verdict = health.judge(0.6, localiser, localiser.estimate())
    assert verdict.status is not Status.WAITING
