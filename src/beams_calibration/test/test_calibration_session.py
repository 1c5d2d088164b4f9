"""The guided session's pure parts: the plan (table 7.2, eq. 7.3) scaled to a table, resuming from the
node's summaries, the capture progress, the hints, the before/after table, and the whole walk through
the plan against a scripted node and scripted answers."""

import io
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_calibration.dataset import BeaconObservation, Configuration, capture_pose_problem, pose_of_summary
from beams_calibration.session import (
    THESIS_AREA,
    CalibrationReport,
    CaptureAnswer,
    CaptureProgress,
    Console,
    PlannedPose,
    TableArea,
    capture_hint,
    captured_poses,
    critical_distance,
    critical_positions,
    exit_status,
    plan_problems,
    progress_bar,
    reference_orientations,
    reference_plan,
    report_table,
    run_session,
    split_plan,
)
from beams_common.geometry.beacon_map import BeaconMap
from beams_thesis import thesis_setup

EUROBOT = BeaconMap.from_lists((1, 2, 3), (-0.062, -0.062, 3.062), (-0.062, 2.062, 1.0))


def test_the_full_plan_on_the_thesis_setup_is_table_7_2_at_eq_7_3():
    plan = reference_plan(TableArea.of_beacons(thesis_setup.PRIOR_BEACONS))
    np.testing.assert_allclose([p.pose for p in plan], thesis_setup.reference_poses(), atol=1e-12)
    assert [p.label for p in plan[:5]] == ["P1 O1", "P1 O2", "P1 O3", "P1 O4", "P2 O1"]
    np.testing.assert_allclose(reference_orientations(4), thesis_setup.REFERENCE_ORIENTATIONS, atol=1e-15)
    assert critical_positions(THESIS_AREA, thesis_setup.PRIOR_BEACONS) == []


def test_a_reduced_plan_takes_the_four_corners_of_table_7_2():
    plan = reference_plan(THESIS_AREA, positions=4, orientations=2)
    assert [p.label for p in plan] == [f"P{k} O{j}" for k in (1, 2, 10, 11) for j in (1, 2)]
    assert {p.theta_rad for p in plan} == {0.0, math.pi}


def test_the_plan_scales_to_a_eurobot_table_and_leaves_out_the_critical_circumference():
    area = TableArea.of_beacons(EUROBOT)
    assert (area.x_min_m, area.x_max_m, area.y_min_m, area.y_max_m) == (-0.062, 3.062, -0.062, 2.062)
    # P2 (1.08, 0.84) scales to (2.861, 1.896): 2.3 % of the radius outside the circle through the beacons
    assert critical_positions(area, EUROBOT) == [2]
    assert critical_distance(np.array([2.861, 1.896]), EUROBOT) == pytest.approx(0.023, abs=1e-3)
    plan = reference_plan(area, positions=11, orientations=1, excluded=[2])
    assert "P2 O1" not in [p.label for p in plan] and len(plan) == 11
    p12 = next(p for p in plan if p.position == 12)
    # (0.60, 0.12) is at (0.5, 0.083) of the thesis's beacons' box
    assert (p12.x_m, p12.y_m) == pytest.approx((-0.062 + 0.5 * 3.124, -0.062 + (0.071 / 0.858) * 2.124))
    with pytest.raises(ValueError, match=r"between 1 and 11 \(table 7.2 less P2\)"):
        reference_plan(area, positions=12, excluded=[2])


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3),
    st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3),
    st.integers(1, 12),
    st.integers(1, 8),
)
def test_every_planned_pose_is_one_the_node_accepts(xs, ys, positions, orientations):
    try:
        beacons = BeaconMap.from_lists((1, 2, 3), xs, ys)
    except ValueError:  # collinear beacons: the node refuses the map itself
        return
    try:
        area = TableArea.of_beacons(beacons)
    except ValueError as error:  # a flat table is refused with its reason
        assert "less than 0.1 m" in str(error)
        return
    plan = reference_plan(area, positions, orientations)
    assert len(plan) == positions * orientations
    assert len({(p.x_m, p.y_m) for p in plan}) == positions
    assert all(capture_pose_problem(*p.pose, beacons) == "" for p in plan)
    assert all(-math.pi < p.theta_rad <= math.pi for p in plan)


def test_plan_problems_name_what_the_node_would_refuse():
    plan = reference_plan(THESIS_AREA, positions=3, orientations=2)
    problems = plan_problems(plan, thesis_setup.PRIOR_BEACONS, min_configurations=12)
    assert problems == [
        "the plan has 6 poses and the node's calibration needs min_configurations = 12: plan more positions "
        "or orientations, or lower min_configurations",
        "the plan has 3 positions, the calibration needs at least 4",
    ]
    far = reference_plan(TableArea(0.0, 3.0, 0.0, 2.0), positions=4)
    (problem, *_) = plan_problems(far, thesis_setup.PRIOR_BEACONS, 12)
    assert problem.startswith("P1 O1: the node would refuse it: the position (0.1933, 1.844) m is outside")
    with pytest.raises(ValueError, match="x_min,x_max,y_min,y_max"):
        TableArea.parse("1,2,3")


@settings(max_examples=100, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-math.pi, math.pi))
def test_a_summary_line_gives_back_its_pose(x, y, theta):
    observation = BeaconObservation(1, 0.5, 0.1, 0.001, 20)
    line = f"7: {Configuration(x, y, theta, (observation,), 20).summary()}"
    parsed = pose_of_summary(line)
    assert parsed is not None
    assert parsed[:2] == pytest.approx((x, y), abs=0.5e-4 + 1e-12)
    assert math.remainder(parsed[2] - theta, 2 * math.pi) == pytest.approx(
        0.0, abs=math.radians(0.05) + 1e-12
    )


def test_resuming_skips_the_poses_the_dataset_holds():
    plan = reference_plan(THESIS_AREA, positions=4, orientations=4)
    summaries = [
        "1: x=0.1200 m y=0.8400 m theta=0.0 deg, 100 revolutions: B1 ...",
        "2: x=0.1200 m y=0.8400 m theta=-270.0 deg, 100 revolutions",  # +90 deg written another way
        "3: x=0.1205 m y=0.8400 m theta=180.0 deg, 100 revolutions",  # 0.5 mm off: the same grid point
        "4: x=0.5000 m y=0.5000 m theta=0.0 deg, 100 revolutions",  # a pose outside the plan
        "error: not a configuration",
    ]
    done, todo, outside = split_plan(plan, captured_poses(summaries))
    assert [p.label for p in done] == ["P1 O1", "P1 O2", "P1 O3"]
    assert [p.label for p in todo][:2] == ["P1 O4", "P2 O1"] and len(todo) == 13
    assert outside == 1
    # 2 mm away is another position, 1 deg another heading
    moved = captured_poses(["x=0.1220 m y=0.8400 m theta=0.0 deg", "x=0.1200 m y=0.8400 m theta=91.0 deg"])
    assert split_plan(plan, moved)[0] == []


def test_capture_progress_counts_the_node_revolutions_or_the_time():
    by_time = CaptureProgress(revolutions=100, started_s=10.0)
    assert by_time.fraction(13.0) == pytest.approx(0.30)
    assert by_time.fraction(30.0) == pytest.approx(0.995)  # never 100 % before the node answers
    by_count = CaptureProgress(revolutions=100, started_s=10.0, count_at_start=500)
    by_count.latest_count = 540
    assert by_count.fraction(11.0) == pytest.approx(0.40)
    assert by_count.line(11.0, width=10) == "[####......]  40% ~40/100 revolutions, 1.0 s"
    assert progress_bar(1.5, width=4) == "[####] 100%"


def test_hints_say_what_to_do_about_a_refused_capture():
    occluded = "refused: beacon 3 seen in 0 of 20 revolutions (at least 80% needed): is it occluded?"
    assert capture_hint(occluded) == "clear the line of sight to beacon 3, check it is powered"
    moved = "refused: beacon 1: bearing spread 0.512 deg exceeds 0.300 deg: did the robot move?"
    assert capture_hint(moved).startswith("keep the robot still")
    assert capture_hint(
        "refused: 0 of 20 revolutions received in time: is the driver publishing?"
    ).startswith("start the driver")
    assert capture_hint("something new") == ""


def test_the_report_table_shows_before_after_and_left_out():
    report = CalibrationReport(
        True,
        "ok",
        position_rms_before_m=0.00875,
        position_rms_after_m=0.00216,
        orientation_rms_before_rad=math.radians(0.4297),
        orientation_rms_after_rad=math.radians(0.1806),
        leave_one_out_position_m=0.0031,
        warnings=("beacon 2 moved by 25.0 mm",),
        files_written=("/tmp/plots/calibration_positions.png", "/tmp/calibration.yaml"),
    )
    lines = report_table(report).splitlines()
    assert lines[1].split()[-3:] == ["8.750", "2.160", "3.100"]
    assert lines[2].split()[-3:] == ["0.430", "0.181", "-"]
    assert "WARNING: beacon 2 moved by 25.0 mm" in lines
    assert lines[-2:] == ["written: /tmp/plots/calibration_positions.png", "written: /tmp/calibration.yaml"]
    assert report.improved


class ScriptedNode:
    """A calibration node that refuses the captures listed in `refusals` (by label, once each)."""

    def __init__(self, recorded: list[str] | None = None, refusals: dict[str, list[str]] | None = None):
        self.summaries = list(recorded or [])
        self.refusals = refusals or {}
        self.placed: list[str] = []
        self.captures: list[str] = []
        self.calibrated = 0

    def place(self, planned: PlannedPose) -> None:
        self.placed.append(planned.label)

    def capture(self, planned: PlannedPose, console: Console) -> CaptureAnswer:
        self.captures.append(planned.label)
        pending = self.refusals.get(planned.label, [])
        if pending:
            return CaptureAnswer(False, pending.pop(0), len(self.summaries))
        configuration = Configuration(*planned.pose, (), 20)
        self.summaries.append(f"{len(self.summaries) + 1}: {configuration.summary()}")
        return CaptureAnswer(True, f"configuration {len(self.summaries)} recorded", len(self.summaries))

    def list_configurations(self) -> tuple[list[str], str]:
        return list(self.summaries), "/data/dataset.yaml"

    def calibrate(self, console: Console) -> CalibrationReport:
        self.calibrated += 1
        return CalibrationReport(True, "ok", 0.008, 0.002, 0.007, 0.003)


def _console(answers: str, assume_yes: bool = False) -> tuple[Console, io.StringIO]:
    output = io.StringIO()
    return Console(io.StringIO(answers), output, assume_yes=assume_yes), output


PLAN = reference_plan(THESIS_AREA, positions=4, orientations=1)
BEACON_3 = "refused: beacon 3 seen in 2 of 20 revolutions"


def test_a_session_retries_skips_lists_and_calibrates():
    node = ScriptedNode(refusals={"P2 O1": [BEACON_3]})
    # P1: capture; P2: capture (refused), retry; P10: list, then skip; P11: nonsense, capture; calibrate
    console, output = _console("\n\n\nl\ns\nwhat\n\n\n")
    outcome = run_session(PLAN, node, console)
    assert node.captures == ["P1 O1", "P2 O1", "P2 O1", "P11 O1"]
    assert [p.label for p in outcome.captured] == ["P1 O1", "P2 O1", "P11 O1"]
    assert [p.label for p in outcome.skipped] == ["P10 O1"]
    assert node.calibrated == 1 and exit_status(outcome) == 0
    text = output.getvalue()
    assert "pose 2 of 4: P2 O1: robot centre (base_link) at x = 1.080 m, y = 0.840 m" in text
    assert "REFUSED " + BEACON_3 + "\n  -> clear the line of sight to beacon 3" in text
    assert "'what' is not an answer" in text
    assert "plan: 3 of 4 poses captured, 1 skipped" in text
    assert "position RMS (mm)" in text


def test_end_of_input_stops_and_the_next_session_resumes():
    node = ScriptedNode()
    console, output = _console("\n")  # one capture, then the input ends
    first = run_session(PLAN, node, console)
    assert first.stopped and [p.label for p in first.captured] == ["P1 O1"] and exit_status(first) == 1
    assert "run the same command again to resume" in output.getvalue() and node.calibrated == 0

    console, output = _console("", assume_yes=True)
    second = run_session(PLAN, node, console)
    assert [p.label for p in second.already] == ["P1 O1"]
    assert [p.label for p in second.captured] == ["P2 O1", "P10 O1", "P11 O1"]
    assert node.captures.count("P1 O1") == 1 and node.calibrated == 1
    assert "1 of the 4 planned poses already captured, skipped" in output.getvalue()


def test_yes_mode_gives_up_a_pose_after_its_attempts():
    node = ScriptedNode(refusals={"P10 O1": [BEACON_3] * 5})
    console, output = _console("", assume_yes=True)
    outcome = run_session(PLAN, node, console, max_attempts=3)
    assert node.captures.count("P10 O1") == 3
    assert [p.label for p in outcome.skipped] == ["P10 O1"]
    assert "P10 O1 skipped after 3 attempts" in output.getvalue()


def test_a_refused_calibration_exits_2():
    class Refusing(ScriptedNode):
        def calibrate(self, console: Console) -> CalibrationReport:
            return CalibrationReport(False, "not calibrated, no file changed: calibration refused: 4 usable")

    console, output = _console("", assume_yes=True)
    outcome = run_session(PLAN, Refusing(), console)
    assert exit_status(outcome) == 2
    assert "calibration refused: not calibrated, no file changed" in output.getvalue()


def test_yes_mode_stops_when_no_bearings_reach_the_node():
    silent = "refused: 0 of 20 revolutions received in time: is the driver publishing /beams/bearings?"
    node = ScriptedNode(refusals={"P1 O1": [silent] * 5})
    console, output = _console("", assume_yes=True)
    outcome = run_session(PLAN, node, console, max_attempts=2)
    assert node.captures == ["P1 O1", "P1 O1"] and outcome.stopped and exit_status(outcome) == 1
    assert "no bearings after 2 attempts: stopping" in output.getvalue()
