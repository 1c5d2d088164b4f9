"""The fault campaign's pure parts (issue 18): the seeded schedule and the figures on synthetic series."""

import itertools
import math

import numpy as np
import pytest

from beams_common.status.health import STATUS_VALIDITY_S
from beams_tools.campaign_metrics import (
    FRESH_S,
    MAX_SAMPLE_SPAN_S,
    NO_REPORT_REASON,
    SILENT_REASON,
    campaign_figures,
    judge,
    sigma_along,
    status_of,
    times_to_alert_s,
    truth_at,
)
from beams_tools.fault_schedule import (
    DRAWS,
    DUPLICATE_EKF_EXTRA_S,
    FAULT_CLASSES,
    LINK_CLASS,
    SERIAL_CLASS,
    SERVICE_NODES,
    ScheduleSettings,
    draw_schedule,
    fixed_schedule,
)

RATE_HZ = 50.0


def test_the_same_seed_draws_the_same_schedule_and_another_seed_another():
    assert draw_schedule(18) == draw_schedule(18)
    assert draw_schedule(18) != draw_schedule(19)


@pytest.mark.parametrize("seed", range(20))
def test_a_150_s_campaign_draws_every_class_without_overlap(seed):
    settings = ScheduleSettings()
    faults = draw_schedule(seed, settings)
    assert {fault.kind for fault in faults} == set(FAULT_CLASSES)
    assert faults[0].start_s >= settings.warmup_s
    assert faults[-1].window[1] <= settings.duration_s - settings.tail_s
    for earlier, later in itertools.pairwise(faults):
        assert later.start_s > earlier.window[1], (earlier.describe(), later.describe())


@pytest.mark.parametrize("seed", range(20))
def test_with_the_serial_line_every_class_still_fits_150_s(seed):
    classes = (*FAULT_CLASSES, SERIAL_CLASS)
    assert {fault.kind for fault in draw_schedule(seed, ScheduleSettings(), classes)} == set(classes)


@pytest.mark.parametrize("seed", range(20))
def test_with_the_serial_line_and_the_hosts_link_every_class_still_fits_150_s(seed):
    classes = (*FAULT_CLASSES, SERIAL_CLASS, LINK_CLASS)
    faults = draw_schedule(seed, ScheduleSettings(), classes)
    assert {fault.kind for fault in faults} == set(classes)
    for earlier, later in itertools.pairwise(faults):
        assert later.start_s > earlier.window[1]


def test_twenty_minutes_draw_every_variant_of_issue_18s_last_classes():
    """The link between hosts cut 1.5-4 s (shorter than the 5-s DDS lease), a second ekf_node (kept long
    enough to start), a spurious zero reference on the serial line: each drawn, in the windows stated."""
    classes = (*FAULT_CLASSES, SERIAL_CLASS, LINK_CLASS)
    faults = draw_schedule(18, ScheduleSettings(duration_s=1200.0), classes)
    links = [f for f in faults if f.kind == LINK_CLASS]
    assert len(links) >= 8
    assert all(f.variant == "sensor_link" and 1.5 <= f.duration_s <= 4.0 for f in links)
    assert all(f.window[1] - f.end_s == 4.0 for f in links)  # its recovery time
    duplicates = {f.variant: [] for f in faults if f.kind == "duplicate_publisher"}
    for f in faults:
        if f.kind == "duplicate_publisher":
            duplicates[f.variant].append(f.duration_s)
    assert set(duplicates) == {"driver", "sim_world", "ekf"}
    assert min(duplicates["ekf"]) >= 2.0 + DUPLICATE_EKF_EXTRA_S
    assert max(duplicates["driver"] + duplicates["sim_world"]) <= 4.0
    serial = {f.variant for f in faults if f.kind == SERIAL_CLASS}
    assert serial == {"noise", "spurious_zero", "silence", "unplug"}


def test_twenty_minutes_draw_every_variant_of_the_wrong_calibration_capture_hung_node_and_burst_classes():
    """Issue 27's classes: each variant drawn; a wrong calibration goes to the driver (the node that applies
    a bias); a node hangs longer than its status's validity, so that the latched status expires."""
    faults = draw_schedule(18, ScheduleSettings(duration_s=1200.0))
    for kind in ("wrong_calibration", "capture_blunder", "hung_node", "service_burst"):
        assert {f.variant for f in faults if f.kind == kind} == set(DRAWS[kind][0]), kind
    assert {f.value("node") for f in faults if f.kind == "wrong_calibration"} == {"driver"}
    hung = [f for f in faults if f.kind == "hung_node"]
    assert {f.variant for f in hung} == set(SERVICE_NODES)
    assert min(f.duration_s for f in hung) > STATUS_VALIDITY_S


def test_the_wrong_calibrations_pass_every_check_and_the_absurd_ones_do_not(tmp_path):
    """A plausible-but-wrong calibration is one the start-up and reload checks accept (load_calibration);
    the cubic's extrapolation is the issue's: about 0 at 5 and 13 deg, -1.2 rad at a 0.04 rad window and
    +2.6 rad at 0.3 rad, held at its edges by the file's window range."""
    from beams_common.calibration.calibration_file import CalibrationFileError, load_calibration
    from beams_tools.campaign_faults import CORRECTIONS, write_calibration_files

    files = write_calibration_files(tmp_path)
    for variant in DRAWS["wrong_calibration"][0]:
        correction = load_calibration(files[variant]).bearing_correction
        assert not correction.is_identity, variant
    for variant in ("rotation_bias_3rad", "power_bias_1e300", "malformed"):
        with pytest.raises(CalibrationFileError):
            load_calibration(files[variant])
    cubic = CORRECTIONS["power_bias_outside_windows"]
    assert cubic.power_bias([math.radians(5.0), math.radians(13.0)]) == pytest.approx([0.0, 0.0], abs=1e-9)
    assert cubic.power_bias([0.04, 0.3]) == pytest.approx([-1.2, 2.6], abs=0.05)
    held = load_calibration(files["power_bias_outside_windows"]).bearing_correction
    assert held.power_bias([0.04, 0.3]) == pytest.approx([0.0, 0.0], abs=1e-9)


@pytest.mark.parametrize("variant", DRAWS["capture_blunder"][0])
def test_a_capture_blunder_is_refused_by_calibration_nodes_check(variant):
    """The pose the campaign gives calibration_node's ~/capture_reference, against bearings of the true
    pose: beams_calibration.dataset.capture_bearing_problem refuses it, naming both poses."""
    from beams_calibration.dataset import BeaconObservation, capture_bearing_problem
    from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
    from beams_tools.campaign_faults import blunder_pose

    x, y, theta = 0.8, 1.3, 0.4
    observations = [
        BeaconObservation(i, math.atan2(by - y, bx - x) - theta, 0.15, 0.0, 3)
        for i, (bx, by) in EUROBOT_BEACON_MAP.as_dict().items()
    ]
    assert capture_bearing_problem((x, y, theta), observations, EUROBOT_BEACON_MAP) == ""
    problem = capture_bearing_problem(blunder_pose(variant, x, y, theta), observations, EUROBOT_BEACON_MAP)
    assert "the pose its bearings give (0.800 m, 1.300 m, 22.9 deg)" in problem


def test_the_classes_a_campaign_draws_and_why_the_hosts_link_is_skipped(monkeypatch, tmp_path):
    from beams_tools import campaign_command, campaign_hosts

    assert campaign_command.campaign_classes(False) == FAULT_CLASSES
    assert campaign_command.campaign_classes(True, hosts=True) == (*FAULT_CLASSES, SERIAL_CLASS, LINK_CLASS)
    assert campaign_command.campaign_classes(False, hosts=True) == (*FAULT_CLASSES, LINK_CLASS)
    monkeypatch.setattr(campaign_hosts.os, "geteuid", lambda: 1000)
    assert "need root" in campaign_hosts.hosts_problem()
    monkeypatch.setattr(campaign_hosts.os, "geteuid", lambda: 0)
    monkeypatch.setattr(campaign_hosts.shutil, "which", lambda _name: None)
    assert "`ip` is missing" in campaign_hosts.hosts_problem()
    monkeypatch.setattr(campaign_hosts.shutil, "which", lambda _name: "/usr/sbin/ip")
    assert campaign_hosts.hosts_problem() == ""
    # a campaign asked for hosts where they cannot be made says so in its notes and draws no link fault
    monkeypatch.setattr(campaign_hosts.os, "geteuid", lambda: 1000)
    campaign = campaign_command.Campaign(
        campaign_command.CampaignConfig(
            hosts=True, install_base=_fake_install(monkeypatch), output_dir=tmp_path
        )
    )
    assert campaign.hosts is None
    assert campaign.notes == [
        f"{LINK_CLASS}: skipped here, network namespaces need root (CAP_NET_ADMIN, CAP_SYS_ADMIN)"
    ]
    assert LINK_CLASS not in {fault.kind for fault in campaign.schedule}


def _fake_install(monkeypatch):
    """An install base whose executables 'exist' (the campaign only builds their commands here)."""
    import pathlib

    from beams_tools.robot_processes import RobotNode

    monkeypatch.setattr(RobotNode, "installed", lambda node, base: node.executable)
    return pathlib.Path("/nonexistent")


def test_a_longer_campaign_repeats_the_classes_in_passes():
    faults = draw_schedule(3, ScheduleSettings(duration_s=1200.0))
    counts = {kind: sum(f.kind == kind for f in faults) for kind in FAULT_CLASSES}
    # each pass draws every class once: the counts differ by at most one
    assert max(counts.values()) - min(counts.values()) <= 1
    assert min(counts.values()) >= 8


def test_a_campaign_too_short_for_every_class_is_refused():
    with pytest.raises(ValueError, match="no room for every fault class"):
        draw_schedule(18, ScheduleSettings(duration_s=50.0))


def test_a_hand_written_schedule_with_overlapping_faults_is_refused():
    rows = [
        {"kind": "odometry_jump", "variant": "offset_x", "start_s": 10.0, "duration_s": 2.0},
        {"kind": "node_kill", "variant": "ekf", "start_s": 13.0, "duration_s": 1.0},
    ]
    with pytest.raises(ValueError, match="overlap"):
        fixed_schedule(rows)


def _straight_truth(start_s: float, end_s: float) -> np.ndarray:
    """The robot driving along x at 0.5 m/s, sampled at 50 Hz: rows (t, x, y)."""
    t = np.arange(start_s, end_s, 1.0 / RATE_HZ)
    return np.column_stack([t, 0.5 * t, np.ones_like(t)])


def _estimates(
    truth: np.ndarray, error_x_m: float, sigma_m: float, start_s: float, end_s: float
) -> np.ndarray:
    """EKF rows (t, x, y, var_xx, cov_xy, var_yy) offset along x by error_x_m, isotropic sigma."""
    rows = truth[(truth[:, 0] >= start_s) & (truth[:, 0] < end_s)]
    variance = sigma_m**2
    return np.column_stack(
        [
            rows[:, 0],
            rows[:, 1] + error_x_m,
            rows[:, 2],
            np.full(len(rows), variance),
            np.zeros(len(rows)),
            np.full(len(rows), variance),
        ]
    )


def _status(reports: list[tuple[float, bool]]) -> np.ndarray:
    return np.array([(t, 1.0 if tracking else 0.0) for t, tracking in reports])


def test_an_error_of_6_cm_with_1_cm_sigma_is_misleading_while_tracking_and_not_while_lost():
    truth = _straight_truth(0.0, 10.0)
    ekf = _estimates(truth, 0.06, 0.01, 2.0, 4.0)
    tracking = judge(ekf, truth, _status([(t, True) for t in range(11)]))
    assert np.all(tracking.misleading)
    assert np.sum(tracking.spans_s[tracking.misleading]) == pytest.approx(2.0, abs=1.5 / RATE_HZ)
    lost = judge(ekf, truth, _status([(t, False) for t in range(11)]))
    assert not np.any(lost.misleading)


@pytest.mark.parametrize(
    ("error_m", "sigma_m", "misleading"),
    [(0.04, 0.001, False), (0.06, 0.02, False), (0.11, 0.02, True), (math.nan, 0.01, True)],
)
def test_the_threshold_is_the_larger_of_5_cm_and_5_sigma(error_m, sigma_m, misleading):
    truth = _straight_truth(0.0, 3.0)
    judged = judge(_estimates(truth, error_m, sigma_m, 1.0, 2.0), truth, _status([(3.0, True)]))
    assert np.all(judged.misleading == misleading)


def test_sigma_is_taken_along_the_error():
    covariance = np.array([[1e-4, 0.0, 1e-6], [1e-4, 0.0, 1e-6]])
    sigma = sigma_along(np.array([[0.1, 0.0], [0.0, 0.1]]), covariance)
    assert sigma == pytest.approx([0.01, 0.001])


def test_an_estimate_takes_the_status_of_the_next_report_and_availability_the_last():
    status = _status([(1.0, True), (2.0, False), (3.0, True)])
    stamps = np.array([0.5, 1.0, 1.5, 2.5, 3.5])
    assert list(status_of(stamps, status)) == [True, True, False, True, False]
    assert list(status_of(stamps, status, report="last")) == [False, True, True, False, True]


def test_an_estimate_re_made_at_a_published_instant_takes_the_last_report_that_names_its_stamp():
    """An operator's pose 0.5 m off taken at the newest odometry's instant (3.0 s), where a good estimate
    was published: a tracking report about 3.0 s came before it, a degraded one after. Both estimates
    of 3.0 s take the degraded one (a consumer comparing estimate_stamp reads it), stamped later than
    the tracking report the next-report rule would pick; were the last report about 3.0 s tracking,
    the wrong one is misleading."""
    truth = _straight_truth(0.0, 5.0)
    ekf = _estimates(truth, 0.0, 0.01, 0.0, 5.0)
    at = np.flatnonzero(np.isclose(ekf[:, 0], 3.0))[0]
    wrong = ekf[at].copy()
    wrong[1] += 0.5
    ekf = np.insert(ekf, at + 1, wrong, axis=0)
    t3 = ekf[at, 0]
    said = [(t, True, t) for t in (1.0, 2.0)] + [(3.01, True, t3), (3.016, False, t3), (4.0, True, 4.0)]
    judged = judge(ekf, truth, np.array(said, dtype=float))
    assert not np.any(judged.misleading)
    assert list(status_of(np.array([t3, 3.5]), np.array(said, dtype=float))) == [False, True]
    said[3] = (3.016, True, t3)
    judged = judge(ekf, truth, np.array(said, dtype=float))
    assert judged.error_m[judged.misleading] == pytest.approx([0.5], abs=1e-6)


def test_the_truth_is_unknown_across_a_silence_and_such_estimates_are_not_judged():
    truth = _straight_truth(0.0, 10.0)
    truth = truth[(truth[:, 0] < 4.0) | (truth[:, 0] > 5.0)]  # a restarted simulator: one second of silence
    _, known = truth_at(np.array([3.0, 4.5, 6.0, 11.0]), truth)
    assert list(known) == [True, False, True, False]
    ekf = _estimates(_straight_truth(0.0, 10.0), 1.0, 0.01, 4.2, 4.8)
    judged = judge(ekf, truth, _status([(t, True) for t in range(11)]))
    assert not np.any(judged.misleading)


def test_an_outage_is_not_misleading_time():
    truth = _straight_truth(0.0, 10.0)
    ekf = np.vstack([_estimates(truth, 0.5, 0.01, 1.0, 1.1), _estimates(truth, 0.5, 0.01, 5.0, 5.1)])
    judged = judge(ekf, truth, _status([(t, True) for t in range(11)]))
    # 10 estimates, each standing for at most MAX_SAMPLE_SPAN_S: never the 3.9 s silence between them
    assert np.sum(judged.spans_s[judged.misleading]) <= 10 * MAX_SAMPLE_SPAN_S


def test_figures_attribute_misleading_time_and_availability_to_the_fault_windows():
    truth = _straight_truth(0.0, 40.0)
    good = _estimates(truth, 0.0, 0.01, 0.0, 40.0)
    wrong = (good[:, 0] >= 12.0) & (good[:, 0] < 13.0)
    good[wrong, 1] += 1.0  # one second 1 m off, inside the odometry jump's window
    silent = (good[:, 0] >= 25.0) & (good[:, 0] < 27.0)  # two seconds without an estimate (a kill)
    ekf = good[~silent]
    status = _status([(t + 0.5, True) for t in range(40)])
    windows = [("odometry_jump", 11.0, 15.0), ("node_kill", 24.0, 30.0)]
    figures = campaign_figures(ekf, truth, status, windows, 5.0, 39.0)
    assert figures.misleading_s == pytest.approx(1.0, abs=0.05)
    assert figures.misleading_outside_s == 0.0
    assert figures.per_class["odometry_jump"].misleading_s == pytest.approx(1.0, abs=0.05)
    assert figures.per_class["odometry_jump"].max_misleading_error_m == pytest.approx(1.0, abs=0.01)
    assert figures.per_class["node_kill"].misleading_s == 0.0
    # the kill's window: 2 s - FRESH_S of its 6 s without a fresh estimate
    kill_availability = figures.per_class["node_kill"].availability
    assert kill_availability == pytest.approx(1.0 - (2.0 - FRESH_S) / 6.0, abs=0.02)
    assert figures.availability_outside == pytest.approx(1.0)
    assert figures.outside_s == pytest.approx(34.0 - 4.0 - 6.0, abs=0.05)


def test_a_faults_time_to_alert_is_its_onset_to_the_first_report_not_tracking_in_its_window():
    said = _status([(t, True) for t in (1.0, 2.0, 3.0)] + [(3.3, False), (4.0, False), (5.0, True)])
    windows = [(2.95, 4.5), (4.8, 6.0), (0.0, 0.5)]  # alerted 0.35 s after; never; no report
    assert times_to_alert_s(said, windows) == pytest.approx([0.35])
    truth = _straight_truth(0.0, 7.0)
    figures = campaign_figures(
        _estimates(truth, 0.0, 0.01, 0.0, 7.0), truth, said, [("hung_node", 2.95, 4.5)], 0.5, 6.5
    )
    assert figures.per_class["hung_node"].alert_summary() == "1 of 1 alerted, p50 0.35 s, worst 0.35 s"


def test_unavailable_time_outside_the_windows_is_attributed_to_the_status_the_user_saw():
    truth = _straight_truth(0.0, 40.0)
    ekf = _estimates(truth, 0.0, 0.01, 0.0, 40.0)
    ekf = ekf[~((ekf[:, 0] >= 30.0) & (ekf[:, 0] < 32.0))]  # two silent seconds outside any window
    reports = [(t + 0.5, True) for t in range(40)]
    # 10.5-13.5 s: unconfirmed (the count changes from report to report), 20.5-21.5 s: lost
    texts = {t: "tracking" for t in range(40)}
    for t, k in ((10, 2), (11, 5), (12, 8)):
        reports[t] = (t + 0.5, False)
        texts[t] = f"degraded: pose not yet confirmed by the bearings since operator pose ({k} of 9)"
    reports[20] = (20.5, False)
    texts[20] = "lost: 12 bearings gated in a row"
    messages = [
        (t + 0.5, f"{'OK' if tracking else 'WARN'}: {texts[t]}") for t, (_, tracking) in enumerate(reports)
    ]
    figures = campaign_figures(ekf, truth, _status(reports), [("node_kill", 2.0, 4.0)], 5.0, 39.0, messages)
    reasons = figures.unavailable_outside_by_reason
    unconfirmed = "WARN: degraded: pose not yet confirmed by the bearings since operator pose (# of #)"
    assert reasons[unconfirmed] == pytest.approx(3.0, abs=0.05)
    assert reasons["WARN: lost: # bearings gated in a row"] == pytest.approx(1.0, abs=0.05)
    assert reasons[SILENT_REASON] == pytest.approx(2.0 - FRESH_S, abs=0.05)
    assert next(iter(reasons)) == unconfirmed  # longest first
    # every unavailable second outside the windows has its reason
    unavailable_s = (1.0 - figures.availability_outside) * figures.outside_s
    assert sum(reasons.values()) == pytest.approx(unavailable_s, abs=0.05)


def test_a_status_past_its_validity_is_neither_available_nor_misleading():
    """A hung EKF (SIGSTOP 5-9 s): its last report, tracking at 5 s, holds until 7 s (STATUS_VALIDITY_S,
    the status topic's valid_until); estimates stamped after that (published once it continues) are not
    trusted, however wrong, and the time is not available, however fresh; before 7 s they are judged."""
    truth = _straight_truth(0.0, 20.0)
    ekf = _estimates(truth, 0.0, 0.01, 0.0, 20.0)
    ekf[(ekf[:, 0] >= 6.0) & (ekf[:, 0] < 9.0), 1] += 0.5
    status = _status([(t, True) for t in (1.0, 2.0, 3.0, 4.0, 5.0, 9.0, 10.0, 11.0)])
    judged = judge(ekf, truth, status)
    wrong = (judged.stamps >= 6.0) & (judged.stamps < 9.0)
    in_force = judged.stamps <= 5.0 + STATUS_VALIDITY_S
    assert np.all(judged.misleading[wrong & in_force])
    assert not np.any(judged.misleading[wrong & ~in_force])
    figures = campaign_figures(ekf, truth, status, [("hung_node", 5.0, 9.0)], 2.0, 11.0)
    assert figures.per_class["hung_node"].misleading_s == pytest.approx(1.0, abs=0.05)
    assert figures.per_class["hung_node"].availability == pytest.approx(0.5, abs=0.02)
    assert list(status_of(np.array([6.9, 7.1, 9.0]), status, report="last")) == [True, False, True]


def test_without_messages_unavailable_time_has_no_report_reason_unless_the_ekf_was_silent():
    truth = _straight_truth(0.0, 20.0)
    ekf = _estimates(truth, 0.0, 0.01, 0.0, 20.0)
    status = _status([(t + 0.5, t != 10) for t in range(20)])
    figures = campaign_figures(ekf, truth, status, [], 5.0, 19.0)
    assert figures.unavailable_outside_by_reason == {NO_REPORT_REASON: pytest.approx(1.0, abs=0.05)}
