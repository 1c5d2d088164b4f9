"""The fault campaign's schedule: a seeded, reproducible list of faults that never overlap, so that a figure
measured in a fault's window ([start, end + the class's recovery time]) is that fault class's. Each pass
through the classes draws them all in a shuffled order."""

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from beams_tools.robot_processes import ROBOT_NODES

# The fault classes the campaign plays everywhere (the serial line's and the hosts' link below need
# a serial sensor and network namespaces).
FAULT_CLASSES = (
    "bad_message",
    "bad_service_call",
    "parameter_change",
    "calibration_reload",
    "lifecycle",
    "odometry_jump",
    "odometry_delay",
    "bearing_stamp_offset",
    "duplicate_publisher",
    "node_kill",
)
# the serial line's faults, drawn when driver_node reads a (simulated) sensor on a serial port
SERIAL_CLASS = "serial_line"
SERIAL_LINE_FAULTS = ("noise", "spurious_zero", "silence", "unplug")
# a link down between two network namespaces (hosts): driver_node on the sensor's host, the rest of the
# robot on the main computer's, joined by one veth link (campaign_hosts.Hosts; root and iproute2)
LINK_CLASS = "link_down"
LINKS = ("sensor_link",)
# After a fault ends, its effects still count as its own for this long (s): a killed node's restart and
# the EKF's re-initialisation take a few seconds on a loaded 2-core machine; a second sim_world's
# odometry leaves the filter off until a ToTal pose brings it back.
DEFAULT_RECOVERY_S = 3.0
RECOVERY_S = {
    "node_kill": 8.0,
    "duplicate_publisher": 6.0,
    "calibration_reload": 4.0,
    "lifecycle": 4.0,
    SERIAL_CLASS: 4.0,
    LINK_CLASS: 4.0,
}

BAD_MESSAGES = (
    "nan_bearings",
    "unknown_beacon",
    "empty_revolution",
    "oversized_revolution",
    "nan_odometry",
    "initialpose_huge_covariance",
    "initialpose_nan",
)
BAD_SERVICE_CALLS = (
    "set_pose_nan",
    "set_pose_huge_covariance",
    "set_pose_wrong_frame",
    "set_pose_wrong_place",
    "reload_empty_then_set_pose_nan",
    "reload_missing_file",
)
PARAMETER_CHANGES = ("good", "out_of_range", "wrong_type", "read_only")
CALIBRATION_FILES = ("good", "rotation_bias_3rad", "power_bias_1e300", "malformed")
LIFECYCLE_SEQUENCES = ("deactivate_activate", "cleanup_configure_activate", "invalid_transition")
DUPLICATED_NODES = ("driver", "sim_world", "ekf")
# a second ekf_node runs this much longer (s): its start-up (imports, its first fix) takes 1.5-3 s
DUPLICATE_EKF_EXTRA_S = 3.0


@dataclass(frozen=True)
class Fault:
    """One fault: its class, which variant, when (s from the campaign's start) and its values."""

    kind: str
    variant: str
    start_s: float
    duration_s: float
    values: tuple[tuple[str, Any], ...] = ()

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    @property
    def recovery_s(self) -> float:
        return RECOVERY_S.get(self.kind, DEFAULT_RECOVERY_S)

    @property
    def window(self) -> tuple[float, float]:
        """The span whose figures are this fault's: from its start to its end plus its recovery time."""
        return self.start_s, self.end_s + self.recovery_s

    def value(self, name: str) -> Any:
        return dict(self.values)[name]

    def describe(self) -> str:
        values = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in self.values)
        return (
            f"{self.start_s:7.1f} s +{self.duration_s:4.1f} s  {self.kind}/{self.variant} {values}".rstrip()
        )


@dataclass(frozen=True)
class ScheduleSettings:
    """The campaign's length (s), the start-up left alone (s), the quiet end (s) and the gaps (s)."""

    duration_s: float = 120.0
    warmup_s: float = 10.0
    tail_s: float = 3.0
    gap_s: tuple[float, float] = (0.5, 1.5)


def _pick(rng: np.random.Generator, choices: Sequence[Any]) -> Any:
    return choices[int(rng.integers(len(choices)))]


def _draw(kind: str, rng: np.random.Generator) -> tuple[str, float, dict[str, Any]]:
    """(variant, duration s, values) of one fault of a class."""
    if kind == "bad_message":
        return _pick(rng, BAD_MESSAGES), float(rng.uniform(1.0, 3.0)), {}
    if kind == "bad_service_call":
        variant = _pick(rng, BAD_SERVICE_CALLS)
        # set_pose is the EKF's; a reload goes to either filter
        node = _pick(rng, ("ekf", "triangulation")) if variant.startswith("reload") else "ekf"
        return variant, 2.0, {"node": node}
    if kind == "parameter_change":
        return _pick(rng, PARAMETER_CHANGES), 3.0, {"node": _pick(rng, ("driver", "triangulation", "ekf"))}
    if kind == "calibration_reload":
        variant = _pick(rng, CALIBRATION_FILES)
        # a bias correction is the driver's alone (the filters take the file's geometry)
        biased = variant in ("rotation_bias_3rad", "power_bias_1e300")
        node = "driver" if biased else _pick(rng, ("driver", "triangulation", "ekf"))
        return variant, float(rng.uniform(3.0, 6.0)), {"node": node}
    if kind == "lifecycle":
        return _pick(rng, LIFECYCLE_SEQUENCES), float(rng.uniform(1.0, 3.0)), {}
    if kind == "odometry_jump":
        offset_m = 100.0 if rng.random() < 0.5 else float(rng.uniform(0.3, 5.0))
        return "offset_x", float(rng.uniform(1.5, 3.5)), {"offset_x_m": offset_m}
    if kind == "odometry_delay":
        return "held_back", float(rng.uniform(2.0, 4.0)), {"delay_s": float(rng.uniform(0.2, 1.0))}
    if kind == "bearing_stamp_offset":
        # the cases: stamped 0.3-3 s late (in the past) or 0.5 s early (in the future)
        late = rng.random() < 0.7
        offset_s = -float(rng.uniform(0.3, 3.0)) if late else 0.5
        return ("late" if late else "early"), float(rng.uniform(2.0, 4.0)), {"offset_s": offset_s}
    if kind == "duplicate_publisher":
        node, duration_s = _pick(rng, DUPLICATED_NODES), float(rng.uniform(2.0, 4.0))
        extra_s = DUPLICATE_EKF_EXTRA_S if node == "ekf" else 0.0
        return node, duration_s + extra_s, {"seed": int(rng.integers(1000))}
    if kind == SERIAL_CLASS:
        return _pick(rng, SERIAL_LINE_FAULTS), float(rng.uniform(2.0, 5.0)), {}
    if kind == LINK_CLASS:
        # a Wi-Fi or cable drop shorter than the DDS lease (5 s): the participants stay matched
        return _pick(rng, LINKS), float(rng.uniform(1.5, 4.0)), {}
    if kind == "node_kill":
        # one of the robot's nodes: kill -9, restarted after this delay as a launch respawn would
        return _pick(rng, tuple(node.name for node in ROBOT_NODES)), float(rng.uniform(0.5, 2.0)), {}
    known = (*FAULT_CLASSES, SERIAL_CLASS, LINK_CLASS)
    raise ValueError(f"unknown fault class {kind!r}; expected one of {known}")


def draw_schedule(
    seed: int, settings: ScheduleSettings = ScheduleSettings(), classes: Sequence[str] = FAULT_CLASSES
) -> tuple[Fault, ...]:
    """The faults of a campaign, the same for the same seed and settings; ValueError when it is too short for
    one fault of every class."""
    rng = np.random.default_rng(seed)
    last_end_s = settings.duration_s - settings.tail_s
    faults: list[Fault] = []
    order: list[str] = []
    start_s = settings.warmup_s
    while True:
        if not order:
            order = [classes[i] for i in rng.permutation(len(classes))]
        kind = order.pop(0)
        variant, duration_s, values = _draw(kind, rng)
        fault = Fault(kind, variant, round(start_s, 3), round(duration_s, 3), tuple(sorted(values.items())))
        if fault.window[1] > last_end_s:
            break
        faults.append(fault)
        start_s = fault.window[1] + float(rng.uniform(*settings.gap_s))
    missing = sorted(set(classes) - {fault.kind for fault in faults})
    if missing:
        raise ValueError(
            f"a {settings.duration_s:.0f} s campaign has no room for every fault class: {missing} left out"
        )
    return tuple(faults)


def fixed_schedule(rows: Sequence[Mapping[str, Any]]) -> tuple[Fault, ...]:
    """A schedule written by hand (a test that needs one fault class): rows of Fault's fields."""
    faults = tuple(
        Fault(
            row["kind"],
            row["variant"],
            float(row["start_s"]),
            float(row["duration_s"]),
            tuple(sorted(row.get("values", {}).items())),
        )
        for row in rows
    )
    for earlier, later in itertools.pairwise(faults):
        if later.start_s < earlier.window[1]:
            raise ValueError(f"faults overlap: {earlier.describe()} and {later.describe()}")
    return faults
