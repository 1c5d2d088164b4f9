"""The small ROS helpers every BeAMS node uses: start-up, diagnostics, calibration reload, clean shutdown.

Parameters are declared from their specs by beams_common.ros.parameters.
"""

import os
import pathlib
import signal
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from std_srvs.srv import Trigger

from beams_common.calibration.calibration_file import SensorCalibration, load_calibration
from beams_common.config.geometry_parameters import BeaconGeometry, geometry_of
from beams_common.intake.validation import bounded, revolution_size_problem
from beams_common.interfaces import topics
from beams_common.ros.node_logging import ThrottledLog
from beams_common.ros.parameters import ParameterValidationError
from beams_common.ros.standby import (
    STANDBY_FLAG,
    RoleLock,
    domain_id_of,
    node_identity,
    role_name,
    signal_wakeup,
    split_standby_flag,
    wait_for_role,
)
from beams_common.status.health import Status, Verdict

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
# Longest wait in the executor before a stop signal is seen (s)
STOP_POLL_PERIOD_S = 0.1
_LEVELS = {"ok": DiagnosticStatus.OK, "warn": DiagnosticStatus.WARN, "error": DiagnosticStatus.ERROR}


def run_node(
    node_class: Callable[[], Node] | Sequence[Callable[[], Node]],
    args: list[str] | None = None,
    *,
    events_executor: bool = True,
) -> int:
    """Create the node (or each of several, in this order: nodes of one process on one executor, as a C++
    component container runs components), spin until SIGINT or SIGTERM, destroy them in the reverse order
    and return the process exit status.

    The streaming nodes spin in rclpy's EventsExecutor (its event queue is in C++): on the 2-core
    benchmark machine it took a third off each node's CPU and the latency p99 from a revolution to the
    EKF's output from 4.2-6.2 ms to 2.5-3.8 ms (bench/bench_system.py). A node with coroutine (async)
    callbacks passes events_executor=False: Jazzy's EventsExecutor does not run them. The environment
    variable BEAMS_EXECUTOR=single_threaded puts every node back on rclpy's SingleThreadedExecutor.

    Hot standby (beams_common.ros.standby): the process first takes its node's role; started with
    `--standby` before --ros-args, it waits for the role before it makes any rclpy context (a stop signal
    while it waits ends it with 0); started without, it runs beside a holder with one WARN line.

    Every stop signal, however many and whenever they come, ends in the same quiet shutdown (see
    _catch_stop_signals): returns 0 (no traceback), and EXIT_INVALID_PARAMETERS when the node refused
    its parameters at start-up (any of the nodes).
    """
    stop_signals = _catch_stop_signals()
    arguments, standby = split_standby_flag(sys.argv if args is None else args)
    role = _take_role(arguments, standby, stop_signals)
    if role is None:  # a standby stopped while it waited
        _ignore_stop_signals()
        return 0
    # No rclpy signal handlers: they shut the context down under callbacks still running (a timer's
    # publish then fails) and chain to KeyboardInterrupt; the spin loop stops on stop_signals instead.
    try:
        rclpy.init(args=arguments, signal_handler_options=SignalHandlerOptions.NO)
    except _rclpy.RCLError as error:  # a malformed --ros-args (an unquoted list, a bad remap)
        reason = str(error).splitlines()[0]
        print(f"invalid command-line arguments (--ros-args): {reason}", file=sys.stderr)
        _ignore_stop_signals()
        return EXIT_INVALID_PARAMETERS
    nodes: list[Node] = []
    try:
        for make in node_class if isinstance(node_class, Sequence) else [node_class]:
            nodes.append(make())
        _spin(nodes, _executor(events_executor), stop_signals)
    except ParameterValidationError as error:
        rclpy.logging.get_logger("beams").fatal(f"invalid parameters: {error}")
        return EXIT_INVALID_PARAMETERS
    except ExternalShutdownException:
        pass
    finally:
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown()
        # only now, the participant gone: a standby taking over is never in the graph beside this one
        role.release()
        _ignore_stop_signals()
    return 0


def _take_role(arguments: list[str], standby: bool, stop_signals: list[int]) -> RoleLock | None:
    """The node's role (beams_common.ros.standby), taken when free; a standby waits for it and gets None
    when a stop signal came first. Says in one line why a process waits, takes over or runs beside
    another instance."""
    # the executable's name (`ekf_node`, or `ekf_node.py` run as a script) is the node's
    identity = node_identity(arguments, pathlib.Path(arguments[0] if arguments else "").stem)
    domain_id = domain_id_of(os.environ)
    lock = RoleLock(role_name(identity, domain_id))
    role = f"{identity.fully_qualified_name} (ROS_DOMAIN_ID {domain_id})"
    # before rclpy.init: rcutils logs to the console in the node's format, under the node's logger name
    logger = rclpy.logging.get_logger(identity.logger_name)
    if not standby:
        if not lock.try_acquire():
            logger.warning(
                f"the role of {role} is held by process {lock.holder_pid()}: running anyway as a second "
                f"instance (start it with {STANDBY_FLAG} to wait for the role instead)"
            )
        return lock
    waiting_since_s = time.monotonic()

    def waiting(holder_pid: int | None) -> None:
        logger.info(
            f"standby: waiting for the role of {role}, held by process {holder_pid}, with no DDS "
            "participant; taking over when that process ends"
        )

    with signal_wakeup() as wakeup_fd:
        taken = wait_for_role(lock, lambda: bool(stop_signals), waiting, wakeup_fd=wakeup_fd)
    if not taken:
        return None
    logger.info(f"standby: took the role of {role} after {time.monotonic() - waiting_since_s:.2f} s")
    return lock


def _catch_stop_signals() -> list[int]:
    """Make SIGINT and SIGTERM requests to stop, which never raise; returns the list of those received.

    Under `ros2 launch`, Ctrl-C reaches a node twice (from the terminal's process group and from
    launch, which then escalates to SIGTERM): with Python's default handler the second one raised
    KeyboardInterrupt inside destroy_node. Here a repeated signal only adds to the list.
    """
    received: list[int] = []

    def note(signal_number: int, _frame: object) -> None:
        received.append(signal_number)

    for signal_number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signal_number, note)
    return received


def _ignore_stop_signals() -> None:
    """Ignore SIGINT and SIGTERM for the rest of the process's life (its exit).

    Python's finalisation resets every signal with a Python handler to its default action, and the DDS
    teardown that follows takes a while: a second Ctrl-C then killed the node (exit -2 under launch).
    Python leaves an ignored signal ignored; SIGKILL still ends a node that hangs.
    """
    for signal_number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signal_number, signal.SIG_IGN)


def _executor(events_executor: bool) -> Executor:
    """The executor run_node spins a node in (see run_node)."""
    choice = os.environ.get(EXECUTOR_VARIABLE, "")
    if choice not in ("", *EXECUTOR_CHOICES):
        raise ParameterValidationError(f"{EXECUTOR_VARIABLE}={choice!r}: expected one of {EXECUTOR_CHOICES}")
    if events_executor and choice != "single_threaded":
        return EventsExecutor()
    return SingleThreadedExecutor()


def _spin(nodes: Sequence[Node], executor: Executor, stop_signals: list[int]) -> None:
    """Spin until a stop signal or shutdown, surviving rclpy's rare failure to convert a taken message
    (a lost message)."""
    for node in nodes:
        executor.add_node(node)
    lost_messages = 0
    while rclpy.ok() and not stop_signals:
        try:
            # Python runs the signal handler between callbacks or when spin_once returns: this period
            # bounds the time from a signal to the shutdown of an idle node. (Jazzy's EventsExecutor.spin()
            # answered no service request at all here, busy on a core, and ignored SIGINT.)
            executor.spin_once(timeout_sec=STOP_POLL_PERIOD_S)
        except (_rclpy.RCLError, RuntimeError) as error:
            # A context shut down under the executor (rclpy.shutdown elsewhere) may make it fail to
            # build its wait set: that is a shutdown, not a fault.
            if not rclpy.ok():
                return
            # Under load rclpy occasionally fails to convert a message it has taken (the frame is
            # `_take_subscription`); the message is lost, the node must not die for it.
            if traceback.extract_tb(error.__traceback__)[-1].name != "_take_subscription":
                raise
            lost_messages += 1
            nodes[0].get_logger().warning(
                f"rclpy could not convert a received message ({lost_messages} lost): {error}"
            )


def startup_geometry(values: dict[str, Any]) -> BeaconGeometry:
    """The beacon geometry of validated parameters at start-up; a calibration file that cannot be read
    stops the node (ParameterValidationError: one line, exit 2)."""
    try:
        return geometry_of(values)
    except (OSError, ValueError) as error:
        raise ParameterValidationError(f"calibration_file: {error}") from None


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

    node.create_service(Trigger, topics.RELOAD_CALIBRATION, reload)


class Diagnostics:
    """Counters and a status published on /diagnostics once a second (diagnostic_msgs).

    The status is at least as bad as the last refusal (`refuse`) and every condition in force
    (`set_condition`, `callback_failed`); a localisation node's verdict (`set_verdict`) is judged under
    those conditions (`Verdict.under`), for /diagnostics and its status topic alike. Every text is bounded
    in length (`validation.bounded`).
    """

    WAITING_FOR_CLOCK = "waiting for /clock (use_sim_time is true): no time, nothing processed"
    WAITING_LOG_PERIOD = 5
    # how long /diagnostics stays ERROR after a callback let an exception out (s, steady clock)
    CALLBACK_FAULT_HOLD_S = 10.0

    def __init__(self, node: Node, name: str, period_s: float = 1.0) -> None:
        self._node = node
        self._name = f"{node.get_fully_qualified_name()}: {name}"
        self._values: dict[str, Any] = {}
        self._level = "ok"
        self._message = "running"
        self._refusal: tuple[str, str] | None = None  # (level, reason) not yet published
        # name -> (level, reason, steady time it ends or None: until cleared)
        self._conditions: dict[str, tuple[str, str, float | None]] = {}
        self._published_errors: set[str] = set()  # the ERROR conditions of the last publication
        self._last_sent: tuple[str, str] | None = None  # its (level, message)
        self._verdict: Verdict | None = None  # a localisation node's status (set_verdict)
        self.on_publish: Callable[[], None] | None = None  # told after each publication (StatusTopic)
        self.before_publish: Callable[[], None] | None = None  # asked before each timed publication
        # sets the values read only for /diagnostics (counters, rates) as each report is sent: a node's
        # per-message path then does not copy them at every estimate
        self.refresh_values: Callable[[], None] | None = None
        self._log = ThrottledLog(node.get_logger())
        self._publisher = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self._timer = node.create_timer(period_s, self._publish_periodically)
        self._clock_waits = 0
        if node.get_parameter("use_sim_time").value:
            # the node's timers run on /clock: without it they never fire, so watch on the steady clock
            self._clock_watch = node.create_timer(
                period_s, self._watch_clock, clock=Clock(clock_type=ClockType.STEADY_TIME)
            )

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

    def refuse(self, key: str, reason: str, level: str = "warn", *, counted: int | None = None) -> None:
        """Count a refused input under `key`, keep its reason in `last_refusal`, make the next status at
        least `level` with it, and log it (at most once a second). `counted`: the refusals of this key
        another object already counts (the Localiser, shared with the offline replay), shown as they
        are: one writer of the count."""
        if level not in ("warn", "error"):
            raise ValueError(f"a refusal is 'warn' or 'error', got {level!r}")
        reason = bounded(reason)
        if counted is None:
            self.increment(key)
        else:
            self.set(key, counted)
        self._values["last_refusal"] = f"{key}: {reason}"
        if self._refusal is None or _LEVELS[level] >= _LEVELS[self._refusal[0]]:
            self._refusal = (level, f"{key}: {reason}")
        # one rclpy call site per severity (node_logging.log_at): rclpy raises when a site changes it
        self._log.log(level, key, f"refused ({key}, {self._values[key]} so far): {reason}")

    def set_condition(self, name: str, level: str, reason: str, hold_s: float | None = None) -> None:
        """Hold the status at least at `level` with `reason` until `clear_condition(name)` or, with
        `hold_s`, that many seconds (steady clock) from now."""
        if level not in _LEVELS:
            raise ValueError(f"diagnostic level must be one of {sorted(_LEVELS)}, got {level!r}")
        until_s = None if hold_s is None else time.monotonic() + hold_s
        known = self._conditions.get(name)
        self._conditions[name] = (level, bounded(reason), until_s)
        if level == "error" and (known is None or known[0] != level):
            self.publish()  # an ERROR is said at once, not at the next tick (up to period_s later)

    def clear_condition(self, name: str) -> None:
        if name in self._conditions:
            self._conditions.pop(name)
            self.publish_if_conditions_changed()

    def publish_if_conditions_changed(self) -> None:
        """Publish at once when the ERROR conditions in force differ from the last publication's (one
        cleared, or its hold ended), as an ERROR is said at once (set_condition), not up to period_s later,
        after the last publication repeated (`_close_span`)."""
        if self._errors() != self._published_errors:
            self._close_span()
            self.publish()

    def _close_span(self) -> None:
        """The last publication repeated, stamped now: it closes its span, so a reader that gives each
        estimate the first report at or after it never credits the estimates made before a change with
        the report after it."""
        if self._last_sent is not None:
            self._send(*self._last_sent, self._node.get_clock().now().to_msg())

    def active_conditions(self) -> dict[str, tuple[str, str]]:
        """The conditions in force now: name -> (level, reason); expired ones are dropped."""
        now_s = time.monotonic()
        self._conditions = {n: c for n, c in self._conditions.items() if c[2] is None or now_s < c[2]}
        return {name: (level, reason) for name, (level, reason, _) in self._conditions.items()}

    def _errors(self) -> "set[str]":  # the builtin: `set` is a method here
        return {name for name, (level, _) in self.active_conditions().items() if level == "error"}

    def callback_failed(self, site: str, summary: str) -> None:
        """A callback let an exception out (the guard caught it): counted in `callback_exceptions`, kept
        in `last_callback_exception`, and the status ERROR for CALLBACK_FAULT_HOLD_S."""
        self.increment("callback_exceptions")
        reason = f"{site}: {summary}"
        self._values["last_callback_exception"] = bounded(reason)
        self.set_condition(
            "callback_exception", "error", f"a callback failed ({reason})", hold_s=self.CALLBACK_FAULT_HOLD_S
        )

    def oversized_revolution(self, message: Any) -> bool:
        """True, the message refused and counted, when a beams/bearings message holds more bearings than a
        revolution can (`validation.MAX_BEARINGS_PER_REVOLUTION`): checked before any per-bearing work."""
        problem = revolution_size_problem(len(message.bearings))
        if problem:
            self.refuse("revolutions_too_many_bearings", f"revolution {message.revolution}: {problem}")
        return bool(problem)

    def _publish_periodically(self) -> None:
        """The timer's publication, `before_publish` first (its failure is the guarded timer's)."""
        if self.before_publish is not None:
            self.before_publish()
        self.publish()

    def publish(self) -> None:
        verdict = self.verdict()
        if verdict is not None:  # a localisation node: its status under the conditions, as its topic says
            self._values["status"] = str(verdict.status)
            level, message = verdict.level, verdict.message
        else:
            conditions = self._ordered_conditions()  # the worst first
            own = (self._level, self._message)
            # the node's own state (a source's health: the cause) leads the conditions it is no better than
            # (the rates and timeouts that follow from it); an OK state comes after any condition
            leads = self._level != "ok" and (
                not conditions or _LEVELS[conditions[0][0]] <= _LEVELS[self._level]
            )
            said = [own, *conditions] if leads else [*conditions, own]
            level = max((c_level for c_level, _ in said), key=_LEVELS.__getitem__)
            message = bounded("; ".join(reason for _, reason in said))
        if self._refusal is not None:
            refusal_level, reason = self._refusal
            self._refusal = None
            level = max(level, refusal_level, key=_LEVELS.__getitem__)
            message = bounded(f"{message}; refused {reason}")
        self._published_errors = self._errors()
        self._send(level, message, self._node.get_clock().now().to_msg())
        self._last_sent = (level, message)
        if self.on_publish is not None:
            self.on_publish()

    def set_verdict(self, verdict: Verdict) -> Verdict:
        """The node's status (beams_common.status.health), said under the conditions in force (`verdict`,
        returned): one other than the last said at once, not at the next tick (tracking after
        `_close_span`); else an ERROR condition's end at once."""
        self._verdict, under = verdict, verdict.under(self._ordered_conditions())
        if self._values.get("status") == under.status:
            self.publish_if_conditions_changed()
        else:
            if under.status is Status.TRACKING:
                self._close_span()
            self.publish()
        return under

    def verdict(self) -> Verdict | None:
        """The node's verdict (set_verdict) under the conditions in force (`Verdict.under`), None without."""
        return None if self._verdict is None else self._verdict.under(self._ordered_conditions())

    def _ordered_conditions(self) -> list[tuple[str, str]]:
        """(level, reason) of the conditions in force: the worst first, and among equals the ones held until
        cleared (the graph's, which name the publishers): the text is bounded, the end may be cut."""
        conditions = self.active_conditions()
        held = {name: until_s is not None for name, (_, _, until_s) in self._conditions.items()}
        ordered = sorted(conditions, key=lambda name: (-ord(_LEVELS[conditions[name][0]]), held[name]))
        return [conditions[name] for name in ordered]

    def _send(self, level: str, message: str, stamp: Any) -> None:
        if self.refresh_values is not None:
            self.refresh_values()
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


class StampedInputs:
    """Mixin of ekf_node and triangulation_node: their receiving clock, and each input's stamp judged
    against it with the node's `stamp_check`, `diagnostics` and `health`."""

    def _now_s(self) -> float:
        """The node's receiving clock (ROS time: /clock under use_sim_time), s."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _implausible_stamp(self, kind: str, what: str, stamp_s: float, now_s: float) -> bool:
        """True, the input refused with the reason, when its stamp is beyond the tolerance against the
        receiving clock (`plausibility.StampCheck`); the status (`health.fault`) degraded once the refusals
        are confirmed (two in a row: not one hiccup)."""
        problem, confirmed = self.stamp_check.check(kind, what, stamp_s, now_s)
        if problem:
            self.diagnostics.refuse(f"{kind}_stamp_refused", problem)
        if confirmed:
            self.health.fault(f"{kind}_stamp", now_s, problem)
        return bool(problem)
