"""The fault campaign over DDS: a seeded 150-s schedule of faults from every class played
against the whole running suite (sim_world, driver, triangulation, EKF, each its own process; the driver
reads a simulated sensor on a pseudo-terminal, so the serial line's faults are drawn too, and runs on a
host of its own, a network namespace, so the link_down faults cut its link: where namespaces cannot be
made, root and iproute2, that class is skipped and the report says so), measured against the
simulator's truth (beams_tools.campaign_command; docs/fault_campaign.md).

The campaign must hold: no hazardously misleading time (an EKF error beyond max(5 cm, 5 sigma) while its
status says tracking), no node dead, every service call answered as expected, and the EKF tracking most
of the time outside the faults' own windows (MIN_AVAILABILITY_OUTSIDE). And it must be able to fail: with
the EKF's lost detection switched off, its kidnap gating loosened and its confirmation of a pose by the
bearings off, an operator's wrong pose (well-formed, 0.5 m off, claiming 1 cm) is never found out, and the
campaign measures seconds of misleading time, each second of it an error of about those 0.5 m inside those
faults' windows.
"""

import math

import numpy as np
import pytest

# The campaign runs the whole suite (eight processes) on the machine's two cores: beside another DDS
# worker its revolutions and ToTal poses come more than the 0.25 s stamp tolerance late and are refused
# (35.9-71.3 % available outside the windows in make test on 2026-11-27, 88.0 % alone): make test runs it
# alone, after the others.
pytestmark = pytest.mark.alone

CAMPAIGN_SEED = 18
CAMPAIGN_S = 150.0
# The goals of this 150-s campaign are zero misleading time, no node dead, every call answered; the
# 95 % availability outside the fault windows is the 20-minute bench's goal. Here only about 22 s lie
# outside the windows of the 16 classes (one second is 4.5 %): the bound guards against a status that
# stays off after its fault. What it measures is mostly the EKF's lost -> re-initialised from ToTal ->
# lost again loops just after a fault's window, each one to two seconds of "pose not yet confirmed", and
# the protection level after such a re-initialisation (the solutions without each beacon carry the jump:
# a faulty beacon's pull on ToTal's fix is bounded) (88.0 % alone on 2026-11-27 with 12 classes and one
# hypothesis per recent bearing; 74.0 % alone with 16 classes and the separations carried over the run).
MIN_AVAILABILITY_OUTSIDE = 0.60
# lost detection off (its NIS window 0), the kidnap test never reached, the per-bearing gate at its widest,
# an operator's pose taken as confirmed at once (issue 18's confirmation by the bearings off), the
# protection level's alert limits at their widest, no beacon excluded
CHECKS_OFF = {
    "confirming_bearings": 0,
    "exclusion_gated_bearings": 0,
    "horizontal_alert_limit_m": 100.0,
    "heading_alert_limit_rad": math.pi,
    "lost_nis_window_bearings": 0,
    "kidnap_gated_bearings": 1000,
    "kidnap_window_bearings": 1000,
    "gate_probability": 0.999999,
}
WRONG_POSES = 3
# with the checks on, main measured 0.06-0.08 s per wrong pose (the time ToTal takes to correct it);
# with them off a wrong pose misleads for seconds
MIN_MISLEADING_CHECKS_OFF_S = 3.0


def _config(ros_domain_id, tmp_path, **fields):
    from beams_tools.campaign_command import CampaignConfig

    return CampaignConfig(domain_id=ros_domain_id, output_dir=tmp_path / "campaign", **fields)


def test_two_minute_campaign_holds(ros_env, ros_domain_id, tmp_path):
    from beams_tools.campaign_command import run_campaign

    config = _config(
        ros_domain_id, tmp_path, seed=CAMPAIGN_SEED, duration_s=CAMPAIGN_S, serial=True, hosts=True
    )
    result = run_campaign(config)
    report = result.report()
    print(report)
    figures = result.figures
    assert {fault.kind for fault in result.schedule} == set(figures.per_class)
    assert figures.misleading_s == 0.0, report
    assert not result.deaths, report + "\n" + "\n".join(d.log_tail for d in result.deaths)
    assert not result.unanswered, report
    # a refusal answered success (a capture blunder recorded, a NaN set_pose taken) is a failure too
    assert not result.unexpected_answers, report
    assert figures.availability_outside >= MIN_AVAILABILITY_OUTSIDE, report


def test_the_campaign_fails_when_the_lost_detection_is_off(ros_env, ros_domain_id, tmp_path):
    from beams_tools.campaign_command import run_campaign
    from beams_tools.campaign_faults import WRONG_PLACE_M
    from beams_tools.campaign_metrics import judge
    from beams_tools.fault_schedule import fixed_schedule

    rows = [
        {
            "kind": "bad_service_call",
            "variant": "set_pose_wrong_place",
            "start_s": 8.0 + 6.0 * k,
            "duration_s": 2.0,
            "values": {"node": "ekf"},
        }
        for k in range(WRONG_POSES)
    ]
    schedule = fixed_schedule(rows)
    duration_s = schedule[-1].window[1] + 1.0
    config = _config(
        ros_domain_id,
        tmp_path,
        duration_s=duration_s,
        warmup_s=5.0,
        schedule=schedule,
        overrides={"ekf": CHECKS_OFF},
    )
    result = run_campaign(config)
    report = result.report()
    print(report)
    wrong_poses = result.figures.per_class["bad_service_call"]
    assert all(call.answered and call.success for call in result.calls), report
    assert wrong_poses.misleading_s >= MIN_MISLEADING_CHECKS_OFF_S, report
    # the right reason: the misleading estimates are the operator's offset, not some other failure
    series = np.load(result.output_dir / "series.npz")
    judged = judge(series["ekf"], series["truth"], series["status"])
    errors = judged.error_m[judged.misleading]
    assert np.median(errors) == pytest.approx(WRONG_PLACE_M, abs=0.1), report
    assert not result.deaths, report
