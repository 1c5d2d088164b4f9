"""The fault campaign's schedule: a seeded, reproducible list of faults that never overlap, so that a figure
measured in a fault's window ([start, end + the class's recovery time]) is that fault class's. Each pass
through the classes draws them all in a shuffled order."""

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from beams_tools.robot_processes import ROBOT_NODES

# the serial line's faults, drawn when driver_node reads a (simulated) sensor on a serial port
SERIAL_CLASS = "serial_line"
# a link down between two network namespaces (hosts): driver_node on the sensor's host, the rest of the
# robot on the main computer's, joined by one veth link (campaign_hosts.Hosts; root and iproute2)
LINK_CLASS = "link_down"
# the nodes whose services and parameters the faults use, a SIGSTOP hangs (of the EKF's pair, the one
# holding the role) and a burst of calls hits
SERVICE_NODES = ("driver", "triangulation", "ekf")
# Each class's variants (one drawn at random), duration range (s, drawn uniformly) and recovery time (s):
# after a fault ends its effects still count as its own for this long (a killed node's restart and the
# EKF's re-initialisation take a few seconds on a loaded 2-core machine; a second sim_world's odometry
# leaves the filter off until a ToTal pose brings it back). `_draw` adds the values some classes take.
DRAWS: dict[str, tuple[tuple[str, ...], tuple[float, float], float]] = {
    "bad_message": (
        (
            "nan_bearings",
            "unknown_beacon",
            "empty_revolution",
            "oversized_revolution",
            "nan_odometry",
            "initialpose_huge_covariance",
            "initialpose_nan",
        ),
        (1.0, 3.0),
        3.0,
    ),
    "bad_service_call": (
        (
            "set_pose_nan",
            "set_pose_huge_covariance",
            "set_pose_wrong_frame",
            "set_pose_wrong_place",
            "reload_empty_then_set_pose_nan",
            "reload_missing_file",
        ),
        (2.0, 2.0),
        3.0,
    ),
    "parameter_change": (("good", "out_of_range", "wrong_type", "read_only"), (3.0, 3.0), 3.0),
    "calibration_reload": (("good", "rotation_bias_3rad", "power_bias_1e300", "malformed"), (3.0, 6.0), 4.0),
    # files every start-up and reload check accepts, wrong for this sensor (campaign_faults.CORRECTIONS);
    # after the good file is back, the EKF unlearns the bias its self-calibration took from the wrong one:
    # lost, re-initialised and lost again for several seconds (the CI campaign of 2026-11-27)
    "wrong_calibration": (
        ("power_bias_outside_windows", "rotation_bias_under_limit", "power_bias_plausible"),
        (3.0, 6.0),
        10.0,
    ),
    "lifecycle": (
        ("deactivate_activate", "cleanup_configure_activate", "invalid_transition"),
        (1.0, 3.0),
        4.0,
    ),
    "odometry_jump": (("offset_x",), (1.5, 3.5), 3.0),
    "odometry_delay": (("held_back",), (2.0, 4.0), 3.0),
    # stamped 0.3-3 s late (in the past) or 0.5 s early (in the future)
    "bearing_stamp_offset": (("late", "early"), (2.0, 4.0), 3.0),
    "duplicate_publisher": (("driver", "sim_world", "ekf"), (2.0, 4.0), 6.0),
    # kill -9, restarted after the fault's duration as a launch respawn would
    "node_kill": (tuple(node.name for node in ROBOT_NODES), (0.5, 2.0), 8.0),
    # an operator's reference pose off (calibration_node's capture): it touches nothing else
    "capture_blunder": (("theta_off_by_pi", "half_metre_off", "mirrored"), (1.0, 1.0), 1.0),
    # longer than a status's validity (2 s, docs/status.md), so that the latched status expires; a node
    # back from SIGSTOP works through what queued meanwhile
    "hung_node": (SERVICE_NODES, (2.5, 4.0), 4.0),
    "service_burst": (SERVICE_NODES, (1.5, 1.5), 3.0),
    SERIAL_CLASS: (("noise", "spurious_zero", "silence", "unplug"), (2.0, 5.0), 4.0),
    # a Wi-Fi or cable drop shorter than the DDS lease (5 s): the participants stay matched
    LINK_CLASS: (("sensor_link",), (1.5, 4.0), 4.0),
}
# The fault classes the campaign plays everywhere (the serial line's and the hosts' link need a serial
# sensor and network namespaces).
FAULT_CLASSES = tuple(kind for kind in DRAWS if kind not in (SERIAL_CLASS, LINK_CLASS))
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
        return DRAWS[self.kind][2]

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

    duration_s: float = 150.0
    warmup_s: float = 10.0
    tail_s: float = 3.0
    gap_s: tuple[float, float] = (0.5, 1.5)


def _pick(rng: np.random.Generator, choices: Sequence[Any]) -> Any:
    return choices[int(rng.integers(len(choices)))]


def _draw(kind: str, rng: np.random.Generator) -> tuple[str, float, dict[str, Any]]:
    """(variant, duration s, values) of one fault of a class."""
    if kind not in DRAWS:
        raise ValueError(f"unknown fault class {kind!r}; expected one of {tuple(DRAWS)}")
    variants, (low_s, high_s), _ = DRAWS[kind]
    variant, duration_s, values = _pick(rng, variants), float(rng.uniform(low_s, high_s)), {}
    if kind == "bad_service_call":  # set_pose is the EKF's; a reload goes to either filter
        values["node"] = _pick(rng, ("ekf", "triangulation")) if variant.startswith("reload") else "ekf"
    elif kind in ("parameter_change", "calibration_reload", "wrong_calibration"):
        # a bias correction is the driver's alone (the filters take the file's geometry)
        values["node"] = "driver" if "bias" in variant else _pick(rng, SERVICE_NODES)
    elif kind == "odometry_jump":
        values["offset_x_m"] = 100.0 if rng.random() < 0.5 else float(rng.uniform(0.3, 5.0))
    elif kind == "odometry_delay":
        values["delay_s"] = float(rng.uniform(0.2, 1.0))
    elif kind == "bearing_stamp_offset":
        values["offset_s"] = -float(rng.uniform(0.3, 3.0)) if variant == "late" else 0.5
    elif kind == "duplicate_publisher":
        duration_s += DUPLICATE_EKF_EXTRA_S if variant == "ekf" else 0.0
        values["seed"] = int(rng.integers(1000))
    return variant, duration_s, values


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
