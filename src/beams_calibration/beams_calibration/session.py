"""The guided calibration session (thesis section 7.3.1): which pose next, how far the capture is, whether
it took, what is left, and the calibration's before/after table. Pure: `calibration_session` wires it to
a running calibration_node over its services.

The plan follows table 7.2 and eq. 7.3: reference positions spread over the table, each visited at
evenly spaced orientations (12 x 4 = 48 configurations in the thesis). Table 7.2's positions are taken
as fractions of the bounding box of table 7.1's beacons (they stand on the grid's border) and placed
in the bounding box of this table's beacons (or an area given by hand): on the thesis's setup the plan
is table 7.2 itself.
"""

import math
import re
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass, field
from enum import Enum
from itertools import combinations
from typing import Protocol, TextIO

import numpy as np

from beams_calibration.calibrate import CoverageRequirements
from beams_calibration.dataset import capture_pose_problem, pose_of_summary
from beams_calibration.reference_layout import PRIOR_BEACONS, REFERENCE_POSITIONS
from beams_common.config.command_line import EXIT_REFUSED
from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import BeaconMap

# The turret turns at about 10 Hz (section 3.2): a capture of N revolutions lasts about N / 10 s.
NOMINAL_TURRET_RATE_HZ = 10.0
# A recorded pose is a planned one when it lies this close: the dataset's position groups are 1 mm
# wide (calibrate.position_groups) and a summary line states the heading to 0.1 deg.
POSITION_TOLERANCE_M = 1e-3
HEADING_TOLERANCE_RAD = math.radians(0.5)
# In --yes mode a refused capture is tried this many times in all, then skipped.
DEFAULT_MAX_ATTEMPTS = 3
MAX_ORIENTATIONS = 36
# A position closer than this fraction of the radius to a critical circumference is left out of the plan:
# table 7.2's positions keep at least 0.145 of it on the thesis's setup.
CRITICAL_MARGIN = 0.1

Pose = tuple[float, float, float]


# --- the plan --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TableArea:
    """An axis-aligned rectangle of the map frame (m) over which the reference positions are spread."""

    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float

    def __post_init__(self) -> None:
        values = (self.x_min_m, self.x_max_m, self.y_min_m, self.y_max_m)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"the table area {values} is not finite")
        if self.x_max_m - self.x_min_m < 0.1 or self.y_max_m - self.y_min_m < 0.1:
            raise ValueError(
                f"the table area x [{self.x_min_m}, {self.x_max_m}] m, y [{self.y_min_m}, {self.y_max_m}] m "
                "is less than 0.1 m wide or tall: give it as x_min,x_max,y_min,y_max"
            )

    @classmethod
    def of_beacons(cls, beacon_map: BeaconMap) -> "TableArea":
        """The beacons' bounding box: they stand on the table's border (section 7.3.1, table 7.1)."""
        low, high = beacon_map.xy.min(axis=0), beacon_map.xy.max(axis=0)
        return cls(float(low[0]), float(high[0]), float(low[1]), float(high[1]))

    @classmethod
    def parse(cls, text: str) -> "TableArea":
        """'x_min,x_max,y_min,y_max' in metres."""
        try:
            values = [float(part) for part in text.split(",")]
        except ValueError:
            values = []
        if len(values) != 4:
            raise ValueError(f"the table area must be x_min,x_max,y_min,y_max (m), got {text!r}")
        return cls(*values)

    def place(self, fractions: np.ndarray) -> np.ndarray:
        """Points given as fractions (0..1) of the width and height, in metres."""
        low = np.array([self.x_min_m, self.y_min_m])
        size = np.array([self.x_max_m - self.x_min_m, self.y_max_m - self.y_min_m])
        return low + np.asarray(fractions, dtype=float) * size

    def fractions(self, points: np.ndarray) -> np.ndarray:
        low = np.array([self.x_min_m, self.y_min_m])
        size = np.array([self.x_max_m - self.x_min_m, self.y_max_m - self.y_min_m])
        return (np.asarray(points, dtype=float) - low) / size


# The thesis's grid as seen from its beacons (table 7.1): the frame table 7.2 is scaled from.
THESIS_AREA = TableArea.of_beacons(PRIOR_BEACONS)


@dataclass(frozen=True)
class PlannedPose:
    """One reference configuration C_k (eq. 7.5): position P_i of table 7.2 at orientation O_j."""

    position: int  # 1-based number in table 7.2
    orientation: int  # 1-based number among the plan's orientations
    x_m: float
    y_m: float
    theta_rad: float

    @property
    def label(self) -> str:
        return f"P{self.position} O{self.orientation}"

    @property
    def pose(self) -> Pose:
        return (self.x_m, self.y_m, self.theta_rad)

    def instruction(self) -> str:
        """What the person does: where the robot centre goes and where its x axis points."""
        return (
            f"{self.label}: robot centre (base_link) at x = {self.x_m:.3f} m, y = {self.y_m:.3f} m, "
            f"heading {math.degrees(self.theta_rad):.1f} deg ({heading_words(self.theta_rad)})"
        )


def heading_words(theta_rad: float) -> str:
    """The heading in words when it is along a table axis (eq. 7.3's orientations)."""
    axes = {0: "x axis along +x", 90: "x axis along +y", 180: "x axis along -x", -90: "x axis along -y"}
    degrees = math.degrees(float(wrap_to_pi(theta_rad)))
    for axis, words in axes.items():
        if abs(math.remainder(degrees - axis, 360.0)) < 0.05:
            return words
    return f"x axis {degrees:.1f} deg counter-clockwise from +x"


def spread_positions(positions: np.ndarray, count: int) -> list[int]:
    """Indices of `count` positions spread over the table (farthest-point selection from the first),
    in table order: a reduced plan still covers near and far windows and every side of the beacons."""
    positions = np.asarray(positions, dtype=float)
    if not 1 <= count <= len(positions):
        raise ValueError(f"positions must be between 1 and {len(positions)}, got {count}")
    chosen = [0]
    while len(chosen) < count:
        distances = np.min(np.hypot(*(positions[:, None, :] - positions[None, chosen, :]).T), axis=0)
        distances[chosen] = -1.0
        chosen.append(int(np.argmax(distances)))
    return sorted(chosen)


def reference_orientations(count: int) -> tuple[float, ...]:
    """`count` headings evenly spaced from 0, wrapped to (-pi, pi]: four give eq. 7.3's
    {0, pi/2, pi, -pi/2}."""
    if not 1 <= count <= MAX_ORIENTATIONS:
        raise ValueError(f"orientations must be between 1 and {MAX_ORIENTATIONS}, got {count}")
    return tuple(float(wrap_to_pi(2.0 * math.pi * k / count)) for k in range(count))


def scaled_positions(area: TableArea) -> np.ndarray:
    """Table 7.2's twelve positions, scaled from the thesis's beacons' box to `area` (m)."""
    return area.place(THESIS_AREA.fractions(REFERENCE_POSITIONS))


def critical_distance(point: np.ndarray, beacon_map: BeaconMap) -> float:
    """Distance of a point from the nearest critical circumference (section 6.3: the circle through three
    beacons, where ToTal has no fix), relative to that circle's radius; inf when no three beacons
    span a circle."""
    nearest = math.inf
    xy = beacon_map.xy
    for a, b, c in combinations(range(len(xy)), 3):
        (ax, ay), (bx, by), (cx, cy) = xy[a], xy[b], xy[c]
        d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
        if abs(d) < 1e-12:
            continue  # collinear beacons: no circle
        sa, sb, sc = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
        centre = np.array(
            [
                (sa * (by - cy) + sb * (cy - ay) + sc * (ay - by)) / d,
                (sa * (cx - bx) + sb * (ax - cx) + sc * (bx - ax)) / d,
            ]
        )
        radius = math.hypot(ax - centre[0], ay - centre[1])
        nearest = min(nearest, abs(math.hypot(*(np.asarray(point) - centre)) / radius - 1.0))
    return nearest


def critical_positions(area: TableArea, beacon_map: BeaconMap, margin: float = CRITICAL_MARGIN) -> list[int]:
    """Table 7.2 position numbers that, scaled to `area`, lie within `margin` (relative) of a critical
    circumference: their poses would carry large triangulation errors (fig. 7.1 keeps clear of it)."""
    placed = scaled_positions(area)
    return [k + 1 for k, point in enumerate(placed) if critical_distance(point, beacon_map) < margin]


def reference_plan(
    area: TableArea, positions: int = 12, orientations: int = 4, excluded: Collection[int] = ()
) -> tuple[PlannedPose, ...]:
    """The configurations to capture, position-major (one placement, then the turns on the spot):
    table 7.2's positions (less the `excluded` numbers) scaled from the thesis's beacons' box to `area`,
    `positions` of them spread over the table, at eq. 7.3's orientations."""
    placed = scaled_positions(area)
    candidates = [k for k in range(len(placed)) if k + 1 not in set(excluded)]
    if not 1 <= positions <= len(candidates):
        raise ValueError(
            f"positions must be between 1 and {len(candidates)} "
            + (f"(table 7.2 less P{', P'.join(map(str, sorted(excluded)))}), " if excluded else "")
            + f"got {positions}"
        )
    headings = reference_orientations(orientations)
    chosen = [candidates[k] for k in spread_positions(placed[candidates], positions)]
    return tuple(
        PlannedPose(index + 1, number + 1, float(placed[index, 0]), float(placed[index, 1]), theta)
        for index in chosen
        for number, theta in enumerate(headings)
    )


def plan_problems(plan: Sequence[PlannedPose], beacon_map: BeaconMap, min_configurations: int) -> list[str]:
    """Why the plan cannot give a calibration the node accepts, or a pose the node would refuse."""
    problems = []
    if len(plan) < min_configurations:
        problems.append(
            f"the plan has {len(plan)} poses and the node's calibration needs min_configurations = "
            f"{min_configurations}: plan more positions or orientations, or lower min_configurations"
        )
    positions = {(p.x_m, p.y_m) for p in plan}
    needed = CoverageRequirements().min_positions
    if len(positions) < needed:
        problems.append(f"the plan has {len(positions)} positions, the calibration needs at least {needed}")
    for planned in plan:
        problem = capture_pose_problem(*planned.pose, beacon_map)
        if problem:
            problems.append(f"{planned.label}: the node would refuse it: {problem}")
    return problems


# --- resuming ---------------------------------------------------------------------------------------


def poses_match(a: Pose, b: Pose) -> bool:
    return (
        math.hypot(a[0] - b[0], a[1] - b[1]) <= POSITION_TOLERANCE_M
        and abs(float(wrap_to_pi(a[2] - b[2]))) <= HEADING_TOLERANCE_RAD
    )


def captured_poses(summaries: Iterable[str]) -> list[Pose]:
    """The poses a ListConfigurations answer holds (its summary lines)."""
    return [pose for pose in map(pose_of_summary, summaries) if pose is not None]


def split_plan(
    plan: Sequence[PlannedPose], recorded: Sequence[Pose]
) -> tuple[list[PlannedPose], list[PlannedPose], int]:
    """(already captured, still to capture, recorded configurations outside the plan)."""
    done = [p for p in plan if any(poses_match(p.pose, r) for r in recorded)]
    todo = [p for p in plan if p not in done]
    outside = sum(not any(poses_match(p.pose, r) for p in plan) for r in recorded)
    return done, todo, outside


# --- capture progress -------------------------------------------------------------------------------


@dataclass
class CaptureProgress:
    """How far a capture of `revolutions` revolutions is: from the node's `revolutions_received`
    diagnostic when it is published (once a second), else from the elapsed time at the turret's rate."""

    revolutions: int
    started_s: float
    count_at_start: int | None = None
    latest_count: int | None = None
    rate_hz: float = NOMINAL_TURRET_RATE_HZ

    def received(self, now_s: float) -> float:
        """Revolutions received so far (estimated), below `revolutions` until the node answers."""
        if self.count_at_start is not None and self.latest_count is not None:
            received = float(self.latest_count - self.count_at_start)
        else:
            received = (now_s - self.started_s) * self.rate_hz
        return min(max(received, 0.0), self.revolutions - 0.5)

    def fraction(self, now_s: float) -> float:
        return self.received(now_s) / self.revolutions

    def line(self, now_s: float, width: int = 30) -> str:
        return progress_bar(self.fraction(now_s), width) + (
            f" ~{self.received(now_s):.0f}/{self.revolutions} revolutions, {now_s - self.started_s:.1f} s"
        )


def progress_bar(fraction: float, width: int = 30) -> str:
    """'[#####.....]  50%' for a fraction in [0, 1]."""
    fraction = min(max(fraction, 0.0), 1.0)
    filled = round(fraction * width)
    return f"[{'#' * filled}{'.' * (width - filled)}] {fraction * 100:3.0f}%"


# --- checks on a capture ----------------------------------------------------------------------------

# No bearings reached the node: every other capture would be refused the same way.
NO_DRIVER = re.compile(r"revolutions received in time|no revolution")
# A refusal's reason (dataset.average_capture, calibration_node) and what the person does about it.
_HINTS = (
    (re.compile(r"beacon (\d+) seen in"), "clear the line of sight to beacon {0}, check it is powered"),
    (re.compile(r"did the robot move|spread"), "keep the robot still (nobody touching it or the table)"),
    (NO_DRIVER, "start the driver (without calibration_file)"),
    (
        re.compile(r"outside the beacons' table|beyond one turn|its bearings give"),
        "check the pose; --force records it anyway",
    ),
    (re.compile(r"busy"), "another capture or calibration is running: wait and retry"),
)


def capture_hint(message: str) -> str:
    """What to do about a refused capture, from its reason; '' when none applies."""
    for pattern, hint in _HINTS:
        match = pattern.search(message)
        if match:
            return hint.format(*match.groups())
    return ""


# --- the calibration's table ------------------------------------------------------------------------


@dataclass(frozen=True)
class CalibrationReport:
    """The Calibrate service's answer (section 7.3.5-7.3.6, table 7.5's first and last lines)."""

    success: bool
    message: str
    position_rms_before_m: float = math.nan
    position_rms_after_m: float = math.nan
    orientation_rms_before_rad: float = math.nan
    orientation_rms_after_rad: float = math.nan
    leave_one_out_position_m: float = math.nan
    leave_one_out_orientation_rad: float = math.nan
    warnings: tuple[str, ...] = ()
    files_written: tuple[str, ...] = ()
    calibration_file: str = ""

    @property
    def improved(self) -> bool:
        return (
            self.position_rms_after_m < self.position_rms_before_m
            and self.orientation_rms_after_rad < self.orientation_rms_before_rad
        )


def report_table(report: CalibrationReport) -> str:
    """Before / after / leave-one-position-out, position (mm, eq. 7.10) and orientation (deg, eq. 7.11);
    the warnings and the files written."""

    def cell(value: float, scale: float) -> str:
        return f"{value * scale:>12.3f}" if math.isfinite(value) else f"{'-':>12}"

    lines = [
        f"{'':<24}{'before':>12}{'after':>12}{'left out':>12}",
        f"{'position RMS (mm)':<24}{cell(report.position_rms_before_m, 1e3)}"
        f"{cell(report.position_rms_after_m, 1e3)}{cell(report.leave_one_out_position_m, 1e3)}",
        f"{'orientation RMS (deg)':<24}{cell(report.orientation_rms_before_rad, 180 / math.pi)}"
        f"{cell(report.orientation_rms_after_rad, 180 / math.pi)}"
        f"{cell(report.leave_one_out_orientation_rad, 180 / math.pi)}",
        "('left out': each reference position predicted by a fit on the others)",
    ]
    lines += [f"WARNING: {warning}" for warning in report.warnings] or ["no warning"]
    lines += [f"written: {path}" for path in report.files_written] or ["no file written (dry run)"]
    return "\n".join(lines)


# --- the person at the table ------------------------------------------------------------------------


class Answer(Enum):
    GO = "go"  # Enter: capture (or retry, or calibrate)
    SKIP = "skip"
    LIST = "list"
    QUIT = "quit"


_ANSWERS = {
    "": Answer.GO,
    "r": Answer.GO,
    "y": Answer.GO,
    "s": Answer.SKIP,
    "l": Answer.LIST,
    "q": Answer.QUIT,
}


def parse_answer(text: str) -> Answer | None:
    """An answer typed at a prompt (first letter, any case); None when it means nothing."""
    word = text.strip().lower()
    return _ANSWERS.get(word[:1] if word else "")


class Console:
    """Prompts and progress on text streams: a terminal, or pipes (a test, a script).

    Without a terminal the answers are read line by line from `input` (end of input: quit) and the
    progress is printed a line per quarter instead of redrawn; with `assume_yes` no answer is read.
    """

    def __init__(self, input: TextIO, output: TextIO, *, assume_yes: bool = False, tty: bool = False) -> None:
        self.input = input
        self.output = output
        self.assume_yes = assume_yes
        self.tty = tty
        self._quarter = -1

    def say(self, line: str = "") -> None:
        self.end_progress()
        print(line, file=self.output, flush=True)

    def ask(self, question: str) -> Answer:
        """Ask until the answer means something; Enter (and --yes) is GO, end of input QUIT."""
        while True:
            self.say(question)
            if self.assume_yes:
                return Answer.GO
            line = self.input.readline()
            if not line:
                self.say("(end of input: stopping; the captured poses stay in the dataset)")
                return Answer.QUIT
            answer = parse_answer(line)
            if answer is not None:
                return answer
            self.say(f"'{line.strip()}' is not an answer")

    def progress(self, line: str, fraction: float) -> None:
        if self.tty:
            print(f"\r{line}", end="", file=self.output, flush=True)
            self._quarter = 0
            return
        quarter = int(fraction * 4)
        if quarter > self._quarter:
            self._quarter = quarter
            print(line, file=self.output, flush=True)

    def end_progress(self) -> None:
        if self.tty and self._quarter >= 0:
            print(file=self.output, flush=True)
        self._quarter = -1


# --- the session ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CaptureAnswer:
    success: bool
    message: str
    configurations: int


class CalibrationServices(Protocol):
    """The calibration node as the session uses it (`calibration_session` implements it over ROS)."""

    def place(self, planned: PlannedPose) -> None:
        """The robot is about to be placed at `planned` (a rehearsal moves the simulated robot)."""

    def capture(self, planned: PlannedPose, console: Console) -> CaptureAnswer:
        """capture_reference at the planned pose, showing its progress on the console."""

    def list_configurations(self) -> tuple[list[str], str]:
        """(summary lines, dataset file) of list_configurations."""

    def calibrate(self, console: Console) -> CalibrationReport:
        """calibrate, showing that it runs."""


@dataclass
class SessionOutcome:
    captured: list[PlannedPose] = field(default_factory=list)
    skipped: list[PlannedPose] = field(default_factory=list)
    already: list[PlannedPose] = field(default_factory=list)
    stopped: bool = False
    report: CalibrationReport | None = None


EXIT_CALIBRATED = 0
EXIT_STOPPED = 1


def exit_status(outcome: SessionOutcome) -> int:
    """0 calibrated, 1 stopped by the person before the calibration, 2 calibration refused."""
    if outcome.report is None:
        return EXIT_STOPPED
    return EXIT_CALIBRATED if outcome.report.success else EXIT_REFUSED


def run_session(
    plan: Sequence[PlannedPose],
    services: CalibrationServices,
    console: Console,
    *,
    max_attempts: int = DEFAULT_MAX_ATTEMPTS,
    calibrate: bool = True,
) -> SessionOutcome:
    """Walk the person through the plan (section 7.3.1), then calibrate (Algorithm 7.1 in the node)."""
    outcome = SessionOutcome()
    summaries, dataset_file = services.list_configurations()
    outcome.already, todo, outside = split_plan(plan, captured_poses(summaries))
    console.say(
        f"dataset {dataset_file}: {len(summaries)} configurations; {len(outcome.already)} of the "
        f"{len(plan)} planned poses already captured" + (", skipped" if outcome.already else "")
    )
    if outside:
        console.say(f"({outside} recorded configurations are not in the plan: they stay in the dataset)")
    for number, planned in enumerate(todo, start=1):
        console.say()
        console.say(f"pose {number} of {len(todo)}: {planned.instruction()}")
        services.place(planned)
        if not _capture_pose(planned, services, console, outcome, max_attempts):
            outcome.stopped = True
            break
    _show_list(services, console)
    done = len(outcome.already) + len(outcome.captured)
    console.say(f"plan: {done} of {len(plan)} poses captured, {len(outcome.skipped)} skipped")
    if outcome.stopped or not calibrate:
        console.say("run the same command again to resume: the captured poses are skipped")
        return outcome
    if console.ask("calibrate now? [Enter: calibrate, q: stop here]") is not Answer.GO:
        return outcome
    outcome.report = services.calibrate(console)
    if outcome.report.success:
        console.say(report_table(outcome.report))
    else:
        console.say(f"calibration refused: {outcome.report.message}")
    return outcome


def _capture_pose(
    planned: PlannedPose,
    services: CalibrationServices,
    console: Console,
    outcome: SessionOutcome,
    max_attempts: int,
) -> bool:
    """Capture one pose until it takes or is skipped; False when the person stops the session."""
    question = "place the robot, keep it still, then [Enter: capture, s: skip, l: list, q: quit]"
    attempts = 0
    while True:
        answer = console.ask(question)
        if answer is Answer.LIST:
            _show_list(services, console)
            continue
        if answer is Answer.QUIT:
            return False
        if answer is Answer.SKIP:
            outcome.skipped.append(planned)
            return True
        attempts += 1
        result = services.capture(planned, console)
        if result.success:
            console.say(f"OK {result.message}")
            outcome.captured.append(planned)
            return True
        hint = capture_hint(result.message)
        console.say(f"REFUSED {result.message}" + (f"\n  -> {hint}" if hint else ""))
        if console.assume_yes and attempts >= max_attempts:
            if NO_DRIVER.search(result.message):
                console.say(f"no bearings after {attempts} attempts: stopping (nothing else would take)")
                return False
            console.say(f"{planned.label} skipped after {attempts} attempts")
            outcome.skipped.append(planned)
            return True
        question = "[Enter: retry, s: skip, l: list, q: quit]"


def _show_list(services: CalibrationServices, console: Console) -> None:
    summaries, dataset_file = services.list_configurations()
    console.say(f"dataset {dataset_file}: {len(summaries)} configurations")
    for line in summaries:
        console.say(f"  {line}")
