"""The small ROS helpers every BeAMS node uses: start-up, parameters, diagnostics, clean shutdown.

This is the only module of beams_driver besides the nodes that imports rclpy.
"""

import math
import os
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from beams_driver.beacon_map import EUROBOT_BEACON_MAP, BeaconMap
from beams_driver.calibration_file import SensorCalibration, load_calibration
from beams_driver.validation import bounded, revolution_size_problem

EXIT_INVALID_PARAMETERS = 2
# beams/bearings: reliable, so no revolution is lost between the driver and the filters (a best-effort
# subscriber, such as `ros2 topic echo`, still connects); the depth covers a second of revolutions.
BEARINGS_QOS = QoSProfile(
    depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE
)
# /tf as tf2's TransformBroadcaster publishes it: reliable, volatile, depth 100
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
# BEAMS_EXECUTOR=single_threaded: every node on rclpy's SingleThreadedExecutor (see run_node)
EXECUTOR_VARIABLE = "BEAMS_EXECUTOR"
EXECUTOR_CHOICES = ("events", "single_threaded")
_LEVELS = {"ok": DiagnosticStatus.OK, "warn": DiagnosticStatus.WARN, "error": DiagnosticStatus.ERROR}


class ParameterValidationError(ValueError):
    """A parameter value the node cannot run with; the message tells the user what to change."""


def run_node(node_class: Callable[[], Node], args: list[str] | None = None, *,
             events_executor: bool = True) -> int:
    """Create the node, spin it until SIGINT or SIGTERM, and return the process exit status.

    The streaming nodes spin in rclpy's EventsExecutor (its event queue is in C++): on the 2-core
    benchmark machine it took a third off each node's CPU and the latency p99 from a revolution to the
    EKF's output from 4.2-6.2 ms to 2.5-3.8 ms (bench/bench_system.py). A node with coroutine (async)
    callbacks passes events_executor=False: Jazzy's EventsExecutor does not run them. The environment
    variable BEAMS_EXECUTOR=single_threaded puts every node back on rclpy's SingleThreadedExecutor.

    Returns 0 on a normal shutdown (no traceback) and EXIT_INVALID_PARAMETERS when the node
    refused its parameters at start-up.
    """
    rclpy.init(args=args)
    node: Node | None = None
    try:
        node = node_class()
        _spin(node, _executor(events_executor))
    except ParameterValidationError as error:
        rclpy.logging.get_logger("beams").fatal(f"invalid parameters: {error}")
        return EXIT_INVALID_PARAMETERS
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _executor(events_executor: bool) -> Executor:
    """The executor run_node spins a node in (see run_node)."""
    choice = os.environ.get(EXECUTOR_VARIABLE, "")
    if choice not in ("", *EXECUTOR_CHOICES):
        raise ParameterValidationError(f"{EXECUTOR_VARIABLE}={choice!r}: expected one of {EXECUTOR_CHOICES}")
    if events_executor and choice != "single_threaded":
        return EventsExecutor()
    return SingleThreadedExecutor()


def _spin(node: Node, executor: Executor) -> None:
    """Spin until shutdown, surviving rclpy's rare failure to convert a taken message (a lost message)."""
    executor.add_node(node)
    lost_messages = 0
    while rclpy.ok():
        try:
            executor.spin_once(timeout_sec=0.5)
        except (_rclpy.RCLError, RuntimeError) as error:
            # A signal shuts the context down under the executor, which may then fail to build its
            # wait set: that is a shutdown, not a fault.
            if not rclpy.ok():
                return
            # Under load rclpy occasionally fails to convert a message it has taken (the frame is
            # `_take_subscription`); the message is lost, the node must not die for it.
            if traceback.extract_tb(error.__traceback__)[-1].name != "_take_subscription":
                raise
            lost_messages += 1
            node.get_logger().warning(
                f"rclpy could not convert a received message ({lost_messages} lost): {error}"
            )


def declare_parameter(
    node: Node,
    name: str,
    default: Any,
    description: str,
    *,
    minimum: float | None = None,
    maximum: float | None = None,
) -> Any:
    """Declare a parameter with its description and range, and return its value.

    A value outside [minimum, maximum] raises ParameterValidationError naming the parameter.
    """
    descriptor = ParameterDescriptor(description=description)
    if minimum is not None and maximum is not None and not isinstance(default, bool):
        if isinstance(default, int):
            descriptor.integer_range = [IntegerRange(from_value=int(minimum), to_value=int(maximum), step=0)]
        elif isinstance(default, float):
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(minimum), to_value=float(maximum), step=0.0)
            ]
    try:
        value = node.declare_parameter(name, default, descriptor).value
    except Exception as error:  # rclpy raises several types for out-of-range or mistyped overrides
        raise ParameterValidationError(f"{name}: {error}") from None
    _check_range(name, value, minimum, maximum)
    return value


def declare_choice(node: Node, name: str, default: str, choices: Sequence[str], description: str) -> str:
    """A string parameter that must be one of `choices`; ParameterValidationError names them otherwise."""
    value = declare_parameter(node, name, default, f"{description} One of {list(choices)}.")
    if value not in choices:
        raise ParameterValidationError(f"{name} must be one of {list(choices)}, got {value!r}")
    return value


def _check_range(name: str, value: Any, minimum: float | None, maximum: float | None) -> None:
    values = value if isinstance(value, list | tuple) else [value]
    for item in values:
        if not isinstance(item, int | float) or isinstance(item, bool):
            continue
        if minimum is not None and item < minimum:
            raise ParameterValidationError(f"{name} = {value} is below its minimum {minimum}")
        if maximum is not None and item > maximum:
            raise ParameterValidationError(f"{name} = {value} is above its maximum {maximum}")


def load_calibration_parameter(node: Node) -> SensorCalibration | None:
    """Read the `calibration_file` parameter and load that file (None when the parameter is empty)."""
    path = declare_parameter(
        node,
        "calibration_file",
        "",
        "Calibration file written by beams_calibration (YAML); empty for none.",
    )
    if not path:
        return None
    try:
        calibration = load_calibration(path)
    except (OSError, ValueError) as error:
        raise ParameterValidationError(f"calibration_file: {error}") from None
    node.get_logger().info(f"calibration loaded from {path}")
    return calibration


def serve_calibration_reload(node: Node, apply: Callable[[SensorCalibration], str]) -> None:
    """Service `~/reload_calibration` (std_srvs/Trigger): read the `calibration_file` again and apply it.

    `apply` installs the new calibration and returns what changed; a missing or malformed file is refused
    with its reason and the calibration in use stays.
    """

    def reload(_request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        path = node.get_parameter("calibration_file").value
        try:
            if not path:
                raise ValueError("the calibration_file parameter is empty")
            response.message = apply(load_calibration(path))
            response.success = True
            node.get_logger().info(f"calibration reloaded from {path}: {response.message}")
        except (OSError, ValueError) as error:  # the file's schema turns any malformed entry into these
            response.success = False
            response.message = bounded(f"calibration not reloaded, the one in use stays: {error}")
            diagnostics = getattr(node, "diagnostics", None)
            if isinstance(diagnostics, Diagnostics):
                diagnostics.refuse("calibration_reloads_refused", response.message, level="error")
            else:
                node.get_logger().error(response.message)
        return response

    node.create_service(Trigger, "~/reload_calibration", reload)


def declare_beacon_map(node: Node, prefix: str = "beacon_", what: str = "Beacon") -> BeaconMap:
    """The parameters <prefix>ids, <prefix>x, <prefix>y (map frame, m; the Eurobot table by default)."""
    ids = declare_parameter(node, f"{prefix}ids", list(EUROBOT_BEACON_MAP.ids), f"{what} ids (their codes).")
    xs = declare_parameter(
        node, f"{prefix}x", EUROBOT_BEACON_MAP.xy[:, 0].tolist(), f"{what} x, map frame (m)."
    )
    ys = declare_parameter(
        node, f"{prefix}y", EUROBOT_BEACON_MAP.xy[:, 1].tolist(), f"{what} y, map frame (m)."
    )
    try:
        return BeaconMap.from_lists(ids, xs, ys)
    except ValueError as error:
        raise ParameterValidationError(f"{prefix}*: {error}") from None


def declare_beacon_geometry(node: Node) -> tuple[BeaconMap, tuple[float, float]]:
    """Beacon map and turret offset (base_link, m) from parameters; a calibration file replaces both."""
    calibration = load_calibration_parameter(node)
    beacon_map = declare_beacon_map(node)
    offset = declare_parameter(
        node,
        "turret_offset_m",
        [0.0, 0.0],
        "Turret centre (x, y) in base_link (m); a calibration file overrides it.",
    )
    if calibration is not None:
        return calibration.beacon_map, (
            float(calibration.turret_offset_m[0]),
            float(calibration.turret_offset_m[1]),
        )
    if len(offset) != 2 or not all(math.isfinite(v) for v in offset):
        raise ParameterValidationError(f"turret_offset_m needs 2 finite values, got {offset}")
    return beacon_map, (float(offset[0]), float(offset[1]))


class Diagnostics:
    """Counters and a status published on /diagnostics once a second (diagnostic_msgs).

    A refusal (`refuse`) is counted, logged (throttled) and shown: the next publication is at least WARN
    with its reason, whatever the node's status became meanwhile. Every text is bounded in length
    (`validation.bounded`). Under use_sim_time, while no /clock has come, a status "waiting for /clock"
    is published on the steady (wall) clock, with a log line every WAITING_LOG_PERIOD publications.
    """

    WAITING_FOR_CLOCK = "waiting for /clock (use_sim_time is true): no time, nothing processed"
    WAITING_LOG_PERIOD = 5

    def __init__(self, node: Node, name: str, period_s: float = 1.0) -> None:
        self._node = node
        self._name = f"{node.get_fully_qualified_name()}: {name}"
        self._values: dict[str, Any] = {}
        self._level = "ok"
        self._message = "running"
        self._refusal: tuple[str, str] | None = None  # (level, reason) not yet published
        self._publisher = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._timer = node.create_timer(period_s, self.publish)
        self._clock_waits = 0
        if node.get_parameter("use_sim_time").value:
            # the node's timers run on /clock: without it they never fire, so watch on the steady clock
            self._clock_watch = node.create_timer(period_s, self._watch_clock,
                                                  clock=Clock(clock_type=ClockType.STEADY_TIME))

    def increment(self, key: str, count: int = 1) -> None:
        self._values[key] = self._values.get(key, 0) + count

    def set(self, key: str, value: Any) -> None:
        self._values[key] = value

    def get(self, key: str, default: Any = 0) -> Any:
        return self._values.get(key, default)

    def set_level(self, level: str, message: str) -> None:
        if level not in _LEVELS:
            raise ValueError(f"diagnostic level must be one of {sorted(_LEVELS)}, got {level!r}")
        self._level = level
        self._message = bounded(message)

    def refuse(self, key: str, reason: str, level: str = "warn") -> None:
        """Count a refused input under `key`, keep its reason in `last_refusal`, make the next status at
        least `level` with it, and log it (at most once a second)."""
        if level not in ("warn", "error"):
            raise ValueError(f"a refusal is 'warn' or 'error', got {level!r}")
        reason = bounded(reason)
        self.increment(key)
        self._values["last_refusal"] = f"{key}: {reason}"
        if self._refusal is None or _LEVELS[level] >= _LEVELS[self._refusal[0]]:
            self._refusal = (level, f"{key}: {reason}")
        log = self._node.get_logger().error if level == "error" else self._node.get_logger().warning
        log(f"refused ({key}, {self._values[key]} so far): {reason}", throttle_duration_sec=1.0)

    def oversized_revolution(self, message: Any) -> bool:
        """True, the message refused and counted, when a beams/bearings message holds more bearings than a
        revolution can (`validation.MAX_BEARINGS_PER_REVOLUTION`): checked before any per-bearing work."""
        problem = revolution_size_problem(len(message.bearings))
        if problem:
            self.refuse("revolutions_too_many_bearings", f"revolution {message.revolution}: {problem}")
        return bool(problem)

    def publish(self) -> None:
        level, message = self._level, self._message
        if self._refusal is not None:
            refusal_level, reason = self._refusal
            self._refusal = None
            level = refusal_level if _LEVELS[refusal_level] > _LEVELS[level] else level
            message = bounded(f"{message}; refused {reason}")
        self._send(level, message, self._node.get_clock().now().to_msg())

    def _send(self, level: str, message: str, stamp: Any) -> None:
        status = DiagnosticStatus(
            level=_LEVELS[level],
            name=self._name,
            message=message,
            hardware_id="beams",
            values=[KeyValue(key=key, value=_format_value(value)) for key, value in self._values.items()],
        )
        array = DiagnosticArray(status=[status])
        array.header.stamp = stamp
        self._publisher.publish(array)

    def _watch_clock(self) -> None:
        """Under use_sim_time: say so while the node's clock has not started (no /clock yet)."""
        if self._node.get_clock().now().nanoseconds != 0:
            return
        if self._clock_waits % self.WAITING_LOG_PERIOD == 0:
            self._node.get_logger().warning(self.WAITING_FOR_CLOCK)
        self._clock_waits += 1
        self._send("warn", self.WAITING_FOR_CLOCK, Time())


def _format_value(value: Any) -> str:
    return f"{value:.6g}" if isinstance(value, float) else bounded(str(value))
