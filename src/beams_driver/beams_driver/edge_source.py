"""Where the driver's edges come from: the EdgeSource protocol and its kinds (`EdgeSourceKind`: parameters
declared when chosen, a factory), this package's `serial`, other packages' from ENTRY_POINT_GROUP (beams_sim's
`sim`), any other as `source:=package.module:EDGE_SOURCE`."""

import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Protocol

from beams_common.config.parameters import ParameterSpec
from beams_common.geometry.pose2d import Pose2D
from beams_driver.codes import BeaconCode
from beams_driver.edges import RevolutionEdges
from beams_driver.receiver import ReceiverModel

# A pose stream sample: (stamp s, pose (x, y, theta) m/rad, twist (speed m/s, yaw rate rad/s)).
PoseCallback = Callable[[float, Pose2D, tuple[float, float]], None]


@dataclass
class SourcePoll:
    """What a source delivered since the last poll; continuity_broken: the first revolution does not follow
    the last one decoded (a reconnection, a skip, a clock jump), so no window is joined across it."""

    revolutions: list[RevolutionEdges] = field(default_factory=list)
    continuity_broken: bool = False


@dataclass
class SourceHealth:
    """How the source is doing, for /diagnostics: level ('ok', 'warn', 'error'), a message (None: the
    driver says how many bearings the last revolution gave) and counters."""

    level: str = "ok"
    message: str | None = None
    values: dict[str, Any] = field(default_factory=dict)


class SourceHost(Protocol):
    """What a source may ask of the node hosting it (driver_node implements it with ROS)."""

    def subscribe_poses(self, topic: str, callback: PoseCallback) -> None:
        """Call back with every nav_msgs/Odometry message on topic (stamp, pose, twist)."""

    def resolve_topic(self, topic: str) -> str:
        """The fully qualified name of topic in the node's namespace."""

    def log_info(self, message: str) -> None:
        """A line in the node's log."""

    def log_warning(self, message: str) -> None:
        """A warning in the node's log."""

    def now_s(self) -> float:
        """The node's clock (s): the ROS time, simulated under use_sim_time."""

    def wake(self) -> None:
        """Have the driver poll soon (a source's own thread may call it: revolutions waiting)."""


class EdgeSource(Protocol):
    """A stream of revolutions of edges (the BeAMS sensor, its simulation, a recording)."""

    def poll(self, now_s: float) -> SourcePoll:
        """The revolutions completed since the last poll (every turret period, and when woken)."""

    def health(self) -> SourceHealth:
        """The source's state and counters, read for /diagnostics once a second."""

    def close(self) -> None:
        """Release what the source holds (a serial port); called once when the driver stops."""


SourceFactory = Callable[[Mapping[str, Any], Sequence[BeaconCode], SourceHost], EdgeSource]


@dataclass(frozen=True)
class EdgeSourceKind:
    """A kind of source: its name, its parameters, their start-up checks, its factory and the receiver model
    of its edges. The factory raises ValueError or OSError with the reason when the source cannot start:
    the driver exits 2 with that line."""

    name: str
    parameters: tuple[ParameterSpec, ...]
    create: SourceFactory
    together: tuple[Callable[[Mapping[str, Any]], str | None], ...] = ()
    # the receiver the edges come through (its minimum burst shapes the window correction and the
    # variance): the thesis hardware's unless the source says otherwise (a simulation of another one)
    receiver: Callable[[Mapping[str, Any], Sequence[BeaconCode]], ReceiverModel] = lambda _values, _codes: (
        ReceiverModel.thesis_hardware()
    )


ENTRY_POINT_GROUP = "beams_driver.edge_sources"
OWN_SOURCES = {"serial": "beams_driver.serial_source:EDGE_SOURCE"}


def named_sources() -> dict[str, str]:
    """Every source name and its `package.module:ATTRIBUTE`: the installed packages' entry points, ours."""
    declared = {point.name: point.value for point in entry_points(group=ENTRY_POINT_GROUP)}
    return declared | OWN_SOURCES


def source_kind(name: str) -> EdgeSourceKind:
    """The kind named by `source` (a named source or `package.module:ATTRIBUTE`); ValueError if none."""
    sources = named_sources()
    target = sources.get(name, name)
    module_name, _, attribute = target.partition(":")
    if not module_name or not attribute:
        raise ValueError(
            f"source must be one of {sorted(sources)} or 'package.module:ATTRIBUTE', got {name!r}"
        )
    try:
        kind = getattr(importlib.import_module(module_name), attribute)
    except (ImportError, AttributeError) as error:
        raise ValueError(f"source {name!r}: {error}") from None
    if not isinstance(kind, EdgeSourceKind):
        raise ValueError(f"source {name!r}: {target} is not an EdgeSourceKind")
    return kind
