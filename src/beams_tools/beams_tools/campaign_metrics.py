"""The fault campaign's figures from recorded series and its result's report: pure, so they are tested on
synthetic data. Their definitions (hazardously misleading time, availability): docs/fault_campaign.md.

Every time is a ROS stamp in seconds. The series: the EKF's estimates, rows (stamp, x, y, var_xx, cov_xy,
var_yy); the truth, rows (stamp, x, y); the EKF's status reports on beams/ekf/status, rows (report stamp,
tracking 1/0, the stamp of the estimate it judges: `estimate_stamp`, NaN when unknown), and optionally their
messages (report stamp, message), which say why the time that was not available was not
(`unavailable_reasons`)."""

import math
import pathlib
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from beams_common.status.health import STATUS_VALIDITY_S
from beams_tools.fault_schedule import Fault

MISLEADING_FLOOR_M = 0.05
MISLEADING_SIGMAS = 5.0
# an estimate stands for at most this long (s): the EKF publishes at the odometry's 50 Hz
MAX_SAMPLE_SPAN_S = 0.1
# the truth is interpolated only between samples at most this far apart (s): a restarted simulator's
# robot starts elsewhere, and across the silence the truth is unknown
MAX_TRUTH_GAP_S = 0.2
# an estimate older than this (s) does not make the time available
FRESH_S = 0.25
GRID_STEP_S = 0.02
# the reason given for unavailable time while the EKF published nothing fresh
SILENT_REASON = "no fresh estimate (the EKF silent)"
NO_REPORT_REASON = "no status report in force (none yet, or past its validity: the EKF hung)"


def truth_at(stamps: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions (n, 2), known mask) of the truth at the stamps, interpolated between truth samples at
    most MAX_TRUTH_GAP_S apart; unknown elsewhere."""
    truth = np.asarray(truth, dtype=float).reshape(-1, 3)
    stamps = np.asarray(stamps, dtype=float)
    if len(truth) < 2:
        return np.full((len(stamps), 2), np.nan), np.zeros(len(stamps), dtype=bool)
    truth = truth[np.argsort(truth[:, 0], kind="stable")]
    after = np.clip(np.searchsorted(truth[:, 0], stamps, side="left"), 1, len(truth) - 1)
    before = after - 1
    inside = (stamps >= truth[0, 0]) & (stamps <= truth[-1, 0])
    known = inside & (truth[after, 0] - truth[before, 0] <= MAX_TRUTH_GAP_S)
    span = np.maximum(truth[after, 0] - truth[before, 0], 1e-12)
    weight = np.clip((stamps - truth[before, 0]) / span, 0.0, 1.0)[:, None]
    positions = truth[before, 1:3] * (1.0 - weight) + truth[after, 1:3] * weight
    return positions, known


def sigma_along(error_xy: np.ndarray, covariance_rows: np.ndarray) -> np.ndarray:
    """Standard deviation (m) of each 2x2 position covariance (var_xx, cov_xy, var_yy) along its error
    vector; along x where the error is zero."""
    error_xy = np.asarray(error_xy, dtype=float).reshape(-1, 2)
    var_xx, cov_xy, var_yy = (np.asarray(covariance_rows, dtype=float).reshape(-1, 3)[:, k] for k in range(3))
    norm = np.hypot(error_xy[:, 0], error_xy[:, 1])
    safe = np.where(norm > 0.0, norm, 1.0)
    ux = np.where(norm > 0.0, error_xy[:, 0] / safe, 1.0)
    uy = np.where(norm > 0.0, error_xy[:, 1] / safe, 0.0)
    variance = ux * ux * var_xx + 2.0 * ux * uy * cov_xy + uy * uy * var_yy
    return np.sqrt(np.maximum(variance, 0.0))


def _status_rows(status: np.ndarray) -> np.ndarray:
    """Status reports as rows (report stamp, tracking, estimate stamp) in the order received; a report
    without its estimate's stamp (two columns) names none."""
    status = np.asarray(status, dtype=float)
    status = status.reshape(-1, status.shape[-1] if status.ndim == 2 else 2)
    if status.shape[1] == 2:
        status = np.column_stack([status, np.full(len(status), np.nan)])
    return status


def status_of(stamps: np.ndarray, status: np.ndarray, report: str = "next") -> np.ndarray:
    """Tracking (bool) at each stamp: by the report about the estimate of that stamp, else the first
    report stamped at or after it (report="next"; False after the last report), or by the last report
    stamped at or before it (report="last"; False before the first).

    "next" judges an estimate as a consumer comparing `estimate_stamp` does (docs/status.md): when
    reports name its stamp, the last of them received (an estimate re-made at the instant of one already
    published, an operator's pose, is judged by what the node said of the new one); otherwise by the
    report that followed it, so that a node finding a fault at its next report is not blamed for the
    report it had not made yet. A report holds STATUS_VALIDITY_S (its valid_until): past it the node
    stopped saying it (hung, dead) and a consumer takes it as lost, so a stamp the last report no longer
    covers is not tracking either way."""
    rows = _status_rows(status)
    stamps = np.asarray(stamps, dtype=float)
    if len(rows) == 0:
        return np.zeros(len(stamps), dtype=bool)
    order = np.argsort(rows[:, 0], kind="stable")
    said_s, tracking = rows[order, 0], rows[order, 1] > 0.5
    last = np.searchsorted(said_s, stamps, side="right") - 1
    expired = (last >= 0) & (stamps > said_s[np.maximum(last, 0)] + STATUS_VALIDITY_S)
    if report == "last":
        return np.insert(tracking, 0, False)[last + 1] & ~expired
    if report != "next":
        raise ValueError(f"report must be 'next' or 'last', got {report!r}")
    result = np.append(tracking, False)[np.searchsorted(said_s, stamps, side="left")]
    about = {
        stamp: value > 0.5
        for stamp, value in zip(rows[:, 2], rows[:, 1], strict=True)
        if math.isfinite(stamp)
    }
    if about:  # the last report received about each stamp
        result = np.array(
            [about.get(stamp, default) for stamp, default in zip(stamps, result, strict=True)], dtype=bool
        )
    return result & ~expired


def sample_spans(stamps: np.ndarray) -> np.ndarray:
    """The time (s) each estimate stands for: to the next one (the last: as long as the one before), at
    most MAX_SAMPLE_SPAN_S."""
    stamps = np.asarray(stamps, dtype=float)
    if len(stamps) == 0:
        return np.empty(0)
    gaps = np.diff(stamps)
    spans = np.append(gaps, gaps[-1] if len(gaps) else MAX_SAMPLE_SPAN_S)
    return np.clip(spans, 0.0, MAX_SAMPLE_SPAN_S)


@dataclass(frozen=True)
class Judged:
    """Each estimate judged against the truth and the status: stamps, error (m), threshold (m), whether
    the truth was known, tracking, misleading, and the time each stands for (s)."""

    stamps: np.ndarray
    error_m: np.ndarray
    threshold_m: np.ndarray
    known: np.ndarray
    tracking: np.ndarray
    misleading: np.ndarray
    spans_s: np.ndarray


def judge(ekf: np.ndarray, truth: np.ndarray, status: np.ndarray) -> Judged:
    """Every estimate against the truth at its stamp and the EKF's status (see the module docstring)."""
    ekf = np.asarray(ekf, dtype=float).reshape(-1, 6)
    ekf = ekf[np.argsort(ekf[:, 0], kind="stable")]
    stamps = ekf[:, 0]
    true_xy, known = truth_at(stamps, truth)
    error_xy = ekf[:, 1:3] - true_xy
    error_m = np.hypot(error_xy[:, 0], error_xy[:, 1])
    threshold_m = np.maximum(MISLEADING_FLOOR_M, MISLEADING_SIGMAS * sigma_along(error_xy, ekf[:, 3:6]))
    tracking = status_of(stamps, status)
    with np.errstate(invalid="ignore"):
        wrong = known & ~(error_m <= threshold_m)  # a non-finite estimate is wrong too
    return Judged(stamps, error_m, threshold_m, known, tracking, wrong & tracking, sample_spans(stamps))


def in_windows(times: np.ndarray, windows: Iterable[tuple[float, float]]) -> np.ndarray:
    """Mask of the times inside any [start, end) window."""
    times = np.asarray(times, dtype=float)
    inside = np.zeros(len(times), dtype=bool)
    for start, end in windows:
        inside |= (times >= start) & (times < end)
    return inside


def misleading_time_s(judged: Judged, mask: np.ndarray | None = None) -> float:
    """Hazardously misleading time (s) over the estimates selected by mask (all by default)."""
    selected = judged.misleading if mask is None else judged.misleading & mask
    return float(np.sum(judged.spans_s[selected]))


def fresh_at(judged: Judged, times: np.ndarray) -> np.ndarray:
    """Whether the newest estimate at each time is at most FRESH_S old."""
    if len(judged.stamps) == 0:
        return np.zeros(len(times), dtype=bool)
    newest = np.searchsorted(judged.stamps, times, side="right") - 1
    return (newest >= 0) & (times - judged.stamps[np.maximum(newest, 0)] <= FRESH_S)


def reason_of(message: str) -> str:
    """A status message as a reason to sum time under: its counts and figures replaced by '#' (so that
    "3 of 9 agreeing bearings" and "5 of 9 ..." are one reason)."""
    return re.sub(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", "#", message.strip()) or "(empty message)"


def unavailable_reasons(
    judged: Judged,
    available: np.ndarray,
    messages: Sequence[tuple[float, str]],
    grid: np.ndarray,
    mask: np.ndarray,
) -> dict[str, float]:
    """Time (s) of the grid points selected by mask that were not available, by reason, longest first:
    no fresh estimate, or the message of the status report a user saw then (the last at or before)."""
    fresh = fresh_at(judged, grid)
    ordered = sorted(messages, key=lambda row: row[0])
    report = np.searchsorted(np.array([stamp for stamp, _ in ordered], dtype=float), grid, side="right") - 1
    totals: dict[str, float] = {}
    for k in np.flatnonzero(mask & ~available):
        if not fresh[k]:
            reason = SILENT_REASON
        elif report[k] < 0 or grid[k] > ordered[report[k]][0] + STATUS_VALIDITY_S:
            reason = NO_REPORT_REASON
        else:
            reason = reason_of(ordered[report[k]][1])
        totals[reason] = totals.get(reason, 0.0) + GRID_STEP_S
    return dict(sorted(totals.items(), key=lambda item: -item[1]))


def fraction(mask: np.ndarray) -> float:
    return float(np.mean(mask)) if len(mask) else float("nan")


@dataclass
class ClassFigures:
    """One fault class's figures over its faults' windows."""

    kind: str
    faults: int = 0
    window_s: float = 0.0
    misleading_s: float = 0.0
    availability: float = float("nan")
    max_misleading_error_m: float = 0.0
    # the faults' times to alert (s): onset to the first report not tracking within the window, for the
    # faults that raised one (a refused call or a fault the nodes absorb need none)
    alerts_s: list[float] = field(default_factory=list)

    @property
    def alert_p50_s(self) -> float:
        return float(np.median(self.alerts_s)) if self.alerts_s else float("nan")

    def alert_summary(self) -> str:
        if not self.alerts_s:
            return f"0 of {self.faults} alerted"
        alerted, p50, worst = len(self.alerts_s), self.alert_p50_s, max(self.alerts_s)
        return f"{alerted} of {self.faults} alerted, p50 {p50:.2f} s, worst {worst:.2f} s"


def times_to_alert_s(status: np.ndarray, windows: Sequence[tuple[float, float]]) -> list[float]:
    """Each window's (start, end) time from its start to the first report not tracking in it, for the
    windows that had one."""
    rows = _status_rows(status)
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    alerts = rows[rows[:, 1] <= 0.5, 0]
    first = np.searchsorted(alerts, [start for start, _ in windows], side="left")
    return [
        float(alerts[k] - start)
        for k, (start, end) in zip(first, windows, strict=True)
        if k < len(alerts) and alerts[k] < end
    ]


@dataclass
class CampaignFigures:
    """A campaign's figures: over its measured span (from the warm-up's end), outside every fault's
    window, and per fault class."""

    span_s: float
    misleading_s: float
    misleading_outside_s: float
    availability: float
    availability_outside: float
    outside_s: float
    max_misleading_error_m: float
    per_class: dict[str, ClassFigures] = field(default_factory=dict)
    # outside every fault's window, the time not available (s) by the reason the EKF's status gave
    unavailable_outside_by_reason: dict[str, float] = field(default_factory=dict)


def campaign_figures(
    ekf: np.ndarray,
    truth: np.ndarray,
    status: np.ndarray,
    windows: Sequence[tuple[str, float, float]],
    start_s: float,
    end_s: float,
    messages: Sequence[tuple[float, str]] = (),
) -> CampaignFigures:
    """The figures of one run over [start_s, end_s) (stamps); windows: (fault class, start, end);
    messages: the EKF's status reports (stamp, message), to attribute the unavailable time."""
    judged = judge(ekf, truth, status)
    measured = (judged.stamps >= start_s) & (judged.stamps < end_s)
    spans = [(start, end) for _, start, end in windows]
    inside = in_windows(judged.stamps, spans)
    # available: a fresh estimate and a tracking status in force (the last report)
    grid = np.arange(start_s, end_s, GRID_STEP_S)
    available = fresh_at(judged, grid) & status_of(grid, status, report="last")
    grid_outside = ~in_windows(grid, spans)

    def max_error(mask: np.ndarray) -> float:
        errors = judged.error_m[judged.misleading & mask]
        return float(np.max(errors)) if len(errors) else 0.0

    figures = CampaignFigures(
        span_s=end_s - start_s,
        misleading_s=misleading_time_s(judged, measured),
        misleading_outside_s=misleading_time_s(judged, measured & ~inside),
        availability=fraction(available),
        availability_outside=fraction(available[grid_outside]),
        outside_s=float(np.sum(grid_outside) * GRID_STEP_S),
        max_misleading_error_m=max_error(measured),
        unavailable_outside_by_reason=unavailable_reasons(judged, available, messages, grid, grid_outside),
    )
    for kind in dict.fromkeys(kind for kind, _, _ in windows):
        own = [(start, end) for other, start, end in windows if other == kind]
        mask = in_windows(judged.stamps, own)
        grid_mask = in_windows(grid, own)
        figures.per_class[kind] = ClassFigures(
            kind=kind,
            faults=len(own),
            window_s=float(np.sum(grid_mask) * GRID_STEP_S),
            misleading_s=misleading_time_s(judged, mask),
            availability=fraction(available[grid_mask]),
            max_misleading_error_m=max_error(mask),
            alerts_s=times_to_alert_s(status, own),
        )
    return figures


def rss_growth_mb(samples: Sequence[tuple[float, float]]) -> float:
    """Growth (MB) of a process's resident set from its first to its last (time, RSS MB) sample."""
    return samples[-1][1] - samples[0][1] if len(samples) >= 2 else 0.0


@dataclass
class CallRecord:
    """One service call (or parameter change, or lifecycle transition) and its answer."""

    fault: str
    service: str
    answered: bool = False
    success: bool | None = None
    expected_success: bool | None = None
    detail: str = ""
    latency_s: float = math.nan


@dataclass
class Death:
    """A process that exited without the campaign killing it."""

    name: str
    campaign_s: float
    status: int
    fault: str
    log_tail: str


@dataclass
class CampaignResult:
    schedule: tuple[Fault, ...]
    figures: CampaignFigures
    calls: list[CallRecord]
    deaths: list[Death]
    rss_growth_mb: dict[str, float]
    output_dir: pathlib.Path
    notes: tuple[str, ...] = ()  # what the campaign left out, and why (a class it could not play here)

    @property
    def unanswered(self) -> list[CallRecord]:
        return [call for call in self.calls if not call.answered]

    @property
    def unexpected_answers(self) -> list[CallRecord]:
        """Answered, but not as expected: a bad change accepted, a good one refused."""
        return [c for c in self.calls if c.answered and c.expected_success not in (None, c.success)]

    def report(self) -> str:
        f = self.figures
        lines = [
            "schedule:",
            *("  " + fault.describe() for fault in self.schedule),
            f"fault campaign: {len(self.schedule)} faults over {f.span_s:.0f} s measured "
            f"(logs in {self.output_dir})",
            f"misleading time {f.misleading_s:.2f} s (outside fault windows {f.misleading_outside_s:.2f} s, "
            f"largest misleading error {f.max_misleading_error_m:.3g} m)",
            f"availability {100 * f.availability:.1f} % (outside fault windows "
            f"{100 * f.availability_outside:.1f} % of {f.outside_s:.0f} s)",
            f"nodes dead {len(self.deaths)}, service calls {len(self.calls)}, unanswered "
            f"{len(self.unanswered)}, answered against expectation {len(self.unexpected_answers)}",
            "RSS growth (MB): " + ", ".join(f"{k} {v:+.1f}" for k, v in self.rss_growth_mb.items()),
            *self.notes,
            "per class: class | faults | window s | misleading s | availability % | "
            "largest misleading error m | time to alert",
        ]
        for figures in f.per_class.values():
            lines.append(
                f"  {figures.kind} | {figures.faults} | {figures.window_s:.1f} | "
                f"{figures.misleading_s:.2f} | {100 * figures.availability:.1f} | "
                f"{figures.max_misleading_error_m:.3g} | {figures.alert_summary()}"
            )
        if f.unavailable_outside_by_reason:
            lines.append("unavailable outside fault windows, by the EKF's status: seconds | reason")
            lines += [
                f"  {seconds:.2f} | {reason}" for reason, seconds in f.unavailable_outside_by_reason.items()
            ]
        lines += [
            f"  dead: {d.name} at {d.campaign_s:.1f} s (exit {d.status}) during {d.fault}"
            for d in self.deaths
        ]
        lines += [f"  unanswered: {c.service} during {c.fault} ({c.detail})" for c in self.unanswered]
        lines += [
            f"  unexpected answer: {c.service} during {c.fault}: success={c.success} ({c.detail})"
            for c in self.unexpected_answers
        ]
        return "\n".join(lines)
