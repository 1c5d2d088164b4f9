"""driver_node: BeAMS bearings once per turret revolution from an edge source (`source`, edge_source.py),
through the decoder, the variance model and the calibration's corrections (thesis ch. 7). A lifecycle node
(docs/nodes.md); a failed transition leaves it in its previous state with the reason logged."""

import sys
import traceback
from collections.abc import Callable

from lifecycle_msgs.srv import ChangeState
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.subscription import Subscription
from rclpy.timer import Timer

from beams_common.calibration.bearing_correction import BearingCorrection
from beams_common.calibration.calibration_file import SensorCalibration, load_calibration
from beams_common.config.parameters import ParameterTable
from beams_common.geometry.angles import wrap_to_pi
from beams_common.interfaces import topics
from beams_common.interfaces.bearing_messages import BearingFields, nanoseconds
from beams_common.ros.callback_guard import GuardedCallbacks
from beams_common.ros.input_watch import WatchedInputs
from beams_common.ros.messages import OdometrySample, bearing_array
from beams_common.ros.node_support import BEARINGS_QOS, Diagnostics, run_node, serve_calibration_reload
from beams_common.ros.parameters import (
    ApplyChange,
    ParameterValidationError,
    apply_runtime_changes,
    declare_table,
)
from beams_common.ros.rate_status import RateStatus
from beams_common.status.health import RATE_WINDOW_S, RateMonitor
from beams_driver.decoder import BearingDecoder, DecodedRevolution
from beams_driver.edge_source import EdgeSource, PoseCallback, source_kind
from beams_driver.edges import TURRET_PERIOD_S, RevolutionEdges
from beams_driver.parameters import (
    DRIVER_PARAMETERS,
    LIFECYCLE_PARAMETERS,
    SENSOR_PARAMETERS,
    VARIANCE_PARAMETERS,
    codes_of,
    corrected_variance_of,
    variance_model_of,
)
from beams_msgs.msg import BeaconBearingArray

# Sources that deliver revolutions as they arrive: the host buffers this many pose messages per topic.
POSE_QUEUE_DEPTH = 50
SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE
ERROR = TransitionCallbackReturn.ERROR
RCLError = _rclpy.RCLError
# the WARN of a driver publishing bearings no calibration corrected (the message's `calibrated` false)
UNCALIBRATED = (
    "uncalibrated: no calibration_file, the bearings carry the power bias (within 0.23 deg, thesis 5.7)"
)
# the published revolutions' rate is OK within +-50 % of the turret's (5-15 Hz): none for 2 s is ERROR,
# double (two sources) WARN; a wide band, as a real turret's speed and a loaded machine's polling vary
REVOLUTION_RATE_TOLERANCE = 0.5


class RosSourceHost:
    """What an edge source may ask of driver_node (edge_source.SourceHost), with ROS; `release` drops its
    subscriptions; `wake` makes `poll` an executor task (Jazzy's EventsExecutor runs no guard condition)."""

    def __init__(self, node: Node, poll: Callable[[], None]) -> None:
        self._node, self._poll = node, poll
        self._subscriptions: list[Subscription] = []

    def subscribe_poses(self, topic: str, callback: PoseCallback) -> None:
        def on_sample(sample: OdometrySample) -> None:
            callback(sample.stamp_s, sample.pose, sample.twist)

        self._subscriptions.append(
            self._node.create_odometry_subscription(topic, on_sample, POSE_QUEUE_DEPTH)
        )

    def release(self) -> None:
        for subscription in self._subscriptions:
            self._node.destroy_subscription(subscription)
        self._subscriptions.clear()

    def resolve_topic(self, topic: str) -> str:
        return self._node.resolve_topic_name(topic)

    def log_info(self, message: str) -> None:
        self._node.get_logger().info(message)

    def log_warning(self, message: str) -> None:
        self._node.get_logger().warning(message)

    def now_s(self) -> float:
        return self._node.get_clock().now().nanoseconds * 1e-9

    def wake(self) -> None:
        if (executor := self._node.executor) is not None:  # None before it spins: the poll timer takes them
            executor.create_task(self._poll)


class TransitionRefusedError(Exception):
    """A transition the node refuses, with the reason (a parameter, a source that cannot start)."""


def _transition(
    step: Callable[["DriverNode"], None], base: Callable[[LifecycleNode, LifecycleState], object]
) -> Callable[["DriverNode", LifecycleState], object]:
    """A lifecycle callback from a step, then rclpy's `base`: TransitionRefusedError is a FAILURE with its
    reason logged and kept (autostart exits with it), any other exception an ERROR with its traceback."""
    name = step.__name__.strip("_")

    def callback(self: "DriverNode", state: LifecycleState) -> object:
        try:
            step(self)
        except TransitionRefusedError as failure:
            self.failure = str(failure)
            if not self.autostart:  # autostart: run_node prints the reason once, as a start-up error
                self.get_logger().error(f"{name} failed: {failure}")
            self.diagnostics.set_level("error", f"{name} failed: {failure}")
            return FAILURE
        except Exception as error:
            self.unexpected = error
            self.get_logger().error(f"{name}: {traceback.format_exc()}")
            return ERROR
        return base(self, state)

    return callback


def _refuse_unavailable_transitions(node: LifecycleNode) -> None:
    """A change_state request for a transition the current state does not offer is answered
    `success: false` (the rclcpp behaviour): Jazzy's rclpy raises out of the service callback and the
    node dies (ros2/rclpy#1209, fixed upstream by ros2/rclpy#1319)."""
    service = node._service_change_state  # rclpy keeps the lifecycle's ChangeState server there
    change_state = service.callback

    def guarded(request: ChangeState.Request, response: ChangeState.Response) -> ChangeState.Response:
        try:
            return change_state(request, response)
        except RCLError as error:
            node.get_logger().warning(
                f"transition {request.transition.label or request.transition.id} refused: {error}"
            )
            response.success = False
            return response

    service.callback = guarded


class DriverNode(WatchedInputs, GuardedCallbacks, LifecycleNode):
    def __init__(self) -> None:
        super().__init__("driver_node")
        _refuse_unavailable_transitions(self)
        self.diagnostics = Diagnostics(self, "driver")
        turret_hz = 1.0 / TURRET_PERIOD_S
        self.revolution_rate = RateStatus(
            self.diagnostics,
            "revolution",
            RateMonitor(
                "revolutions",
                RATE_WINDOW_S,
                turret_hz * (1.0 - REVOLUTION_RATE_TOLERANCE),
                turret_hz * (1.0 + REVOLUTION_RATE_TOLERANCE),
            ),
        )
        self.host = RosSourceHost(self, self.guard_callback("source wake", self._poll, lambda *_: None))
        self.failure = ""  # the last failed transition's reason
        self.unexpected: Exception | None = None
        self.decoder: BearingDecoder | None = None
        self.publisher: LifecyclePublisher | None = None
        self.source: EdgeSource | None = None
        self._poll_timer: Timer | None = None
        self._stale_before_s: float | None = None
        self.diagnostics.before_publish = self._show_source_health
        self.correction = BearingCorrection()
        # a mistyped autostart stops the node at once (exit 2): whether to wait is unknown
        self.autostart: bool = declare_table(self, LIFECYCLE_PARAMETERS)["autostart"]
        self._parameter_problem = ""
        try:
            self._declare_parameters()
        except ParameterValidationError as error:
            if self.autostart:
                raise
            self._parameter_problem = str(error)  # configure refuses with it; the node stays unconfigured
        if self.autostart:
            self._start()
        else:
            self._show_state("unconfigured: waiting for a lifecycle manager (configure, then activate)")

    def _declare_parameters(self) -> None:
        """Declare the driver's and its source's parameters, validated (ParameterValidationError)."""
        self.parameters = {"autostart": self.autostart, **declare_table(self, SENSOR_PARAMETERS)}
        try:
            self.kind = source_kind(self.parameters["source"])
        except ValueError as error:
            raise ParameterValidationError(str(error)) from None
        self.source_parameters = declare_table(
            self, ParameterTable("driver_node", self.kind.parameters, self.kind.together)
        )
        self.frame_id = self.parameters["frame_id"]
        serve_calibration_reload(self, self._apply_calibration)
        apply_runtime_changes(self, DRIVER_PARAMETERS, self.parameters, self._prepare_parameters)

    def _start(self) -> None:
        """autostart: configure and activate now; a refusal stops the node (run_node: one line, exit 2)."""
        for trigger in (self.trigger_configure, self.trigger_activate):
            if trigger() == SUCCESS:
                continue
            self._release()
            if self.unexpected is not None:
                raise self.unexpected
            raise ParameterValidationError(self.failure)

    def recover_from_callback_exception(self, site: str) -> str:
        """A callback failed halfway (GuardedCallbacks): no decoding window joins across it."""
        if self.decoder is None:
            return ""
        self.decoder.reset()
        return "decoder reset"

    # ---- the lifecycle transitions ----

    def _configure(self) -> None:
        """Validate the parameters and build the decoder and the publisher; nothing is opened."""
        if self._parameter_problem:
            raise TransitionRefusedError(self._parameter_problem)
        try:
            self.codes = codes_of(self.parameters)
            # the receiver the edges come through (the simulated one, or the thesis hardware's): the
            # decoder's window correction and the variance model know its minimum burst
            self.receiver = self.kind.receiver(self.source_parameters, self.codes)
            self.correction = self._correction_of(self.parameters["calibration_file"])
        except (ValueError, ParameterValidationError) as error:
            raise TransitionRefusedError(str(error)) from None
        self.decoder = BearingDecoder(
            self.codes,
            variance_model_of(self.parameters, self.codes, self.receiver),
            min_codes_seen=self.parameters["min_complete_codes"],
            receiver=self.receiver,
        )
        self.frame_id = self.parameters["frame_id"]
        self.publisher = self.create_lifecycle_publisher(BeaconBearingArray, topics.BEARINGS, BEARINGS_QOS)
        self._show_state("inactive: configured, not publishing")

    def _activate(self) -> None:
        """Create the source (open the port, start the simulation) unless a deactivation kept it; poll."""
        if self.source is None:
            try:
                self.source = self.kind.create(self.source_parameters, self.codes, self.host)
            except (ValueError, OSError) as error:
                self.host.release()
                raise TransitionRefusedError(f"source {self.kind.name}: {error}") from None
            self._stale_before_s = None
        else:
            # what the kept source gathered while inactive is old: no window joins it, none is published
            self.decoder.reset()
            self._stale_before_s = self.host.now_s()
        self._poll_timer = self.create_timer(TURRET_PERIOD_S, self._poll)  # and when the source wakes it
        self.revolution_rate.start(self.host.now_s())
        self._show_state("active")
        self.get_logger().info(
            f"{self.kind.name} source, codes {[str(c) for c in self.codes]}, variance mode "
            f"{self.decoder.variance_model.mode}, publishing {self.resolve_topic_name(topics.BEARINGS)}"
        )

    def _deactivate(self) -> None:
        """Stop polling and publishing; the source stays open for the next activation."""
        self._stop_polling()
        self._show_state("inactive: deactivated, not publishing")

    def _cleanup(self) -> None:
        """Release the source (close the serial port) and the publisher: back to unconfigured."""
        self._release()
        self._show_state("unconfigured: cleaned up")

    def _shutdown(self) -> None:
        """From any state: release everything."""
        self._release()
        self._show_state("finalized: shut down, nothing held")

    def _error(self) -> None:
        """A transition raised: release everything; the node goes back to unconfigured."""
        self._release()
        self._show_state("unconfigured: a transition failed")

    on_configure = _transition(_configure, LifecycleNode.on_configure)
    on_activate = _transition(_activate, LifecycleNode.on_activate)
    on_deactivate = _transition(_deactivate, LifecycleNode.on_deactivate)
    on_cleanup = _transition(_cleanup, LifecycleNode.on_cleanup)
    on_shutdown = _transition(_shutdown, LifecycleNode.on_shutdown)
    on_error = _transition(_error, LifecycleNode.on_error)

    def _stop_polling(self) -> None:
        self.revolution_rate.stop()
        if self._poll_timer is not None:
            self.destroy_timer(self._poll_timer)
            self._poll_timer = None

    def _release(self) -> None:
        """Stop polling, close the source, drop the pose subscriptions and the publisher (idempotent)."""
        self._stop_polling()
        source, self.source = self.source, None
        if source is not None:
            source.close()
        self.host.release()
        if self.publisher is not None:
            self.destroy_lifecycle_publisher(self.publisher)
            self.publisher = None
        self.decoder = None

    def _show_state(self, message: str) -> None:
        self.diagnostics.set("lifecycle_state", message.split(":")[0])
        self.diagnostics.set_level("ok", message)

    def destroy_node(self) -> None:
        # the source is released on every stop, so a restarted driver (or a terminal program) can open
        # the serial port
        self._release()
        # rclpy's LifecycleNode leaves its state machine holding the node: the node would stay in the
        # graph (and in the process) until the process ends
        self._state_machine.destroy_when_not_in_use()
        super().destroy_node()

    # ---- parameters ----

    @staticmethod
    def _correction_of(path: str) -> BearingCorrection:
        """The calibration file's bearing corrections (none without a file); a file that cannot be read
        refuses the configuration (autostart: stops the node)."""
        if not path:
            return BearingCorrection()
        try:
            return load_calibration(path).bearing_correction
        except (OSError, ValueError) as error:
            raise ParameterValidationError(f"calibration_file: {error}") from None

    def _prepare_parameters(self, values: dict, changed: set[str]) -> ApplyChange:
        """A runtime change (validated by the table): the calibration read and the variance model built
        now (ValueError, OSError: refused); the returned step applies them with the frame. Unconfigured,
        the values are kept for the next configure."""
        correction = self.correction
        if "calibration_file" in changed:
            path = values["calibration_file"]
            correction = load_calibration(path).bearing_correction if path else BearingCorrection()
        # the exact model enumerates every code (~20 ms): only a change of its parameters rebuilds it
        rebuild = self.decoder is not None and bool(changed & VARIANCE_PARAMETERS)
        model = variance_model_of(values, self.codes, self.receiver) if rebuild else None

        def apply() -> None:
            self.correction = correction
            self.frame_id = values["frame_id"]
            if self.decoder is not None:
                if model is not None:
                    self.decoder.variance_model = model
                self.decoder.min_codes_seen = values["min_complete_codes"]

        return apply

    def _apply_calibration(self, calibration: SensorCalibration) -> str:
        self.correction = calibration.bearing_correction
        return "power and rotation bias corrections replaced"

    # ---- the source ----

    def _poll(self) -> None:
        if self._poll_timer is None:
            return  # inactive: a wake or a timer event queued before the deactivation
        now_s = self.host.now_s()
        poll = self.source.poll(now_s)
        if poll.continuity_broken:
            self.decoder.reset()  # no window is joined across a gap in the stream
        fresh = self._fresh(poll.revolutions, now_s)
        for edges in fresh:
            self._publish(self.decoder.decode(edges))
        self.revolution_rate.tick(now_s, len(fresh))
        self.revolution_rate.update(now_s)

    def _show_source_health(self) -> None:
        """The polled source's health, read once a second for /diagnostics (not at every poll)."""
        if self.source is None or self._poll_timer is None:
            return
        health = self.source.health()
        for key, value in health.values.items():
            self.diagnostics.set(key, value)
        if health.level != "ok" or health.message:
            self.diagnostics.set_level(health.level, health.message or health.level)

    def _fresh(self, revolutions: list[RevolutionEdges], now_s: float) -> list[RevolutionEdges]:
        """After a re-activation, the revolutions begun while the node was inactive are dropped: the
        first one begun since (or a clock gone back, a replayed bag) ends the filter."""
        if self._stale_before_s is None:
            return revolutions
        fresh = [edges for edges in revolutions if edges.start_time_s >= self._stale_before_s]
        if fresh or now_s < self._stale_before_s:
            self._stale_before_s = None
        return fresh

    # ---- publishing ----

    def _publish(self, decoded: DecodedRevolution) -> None:
        msg = bearing_array(
            nanoseconds(decoded.start_time_s),
            [self._bearing_fields(b) for b in decoded.bearings],
            period_s=decoded.period_s,
            revolution=decoded.revolution,
            rejected_windows=len(decoded.rejections),
            frame_id=self.frame_id,
            calibrated=not self.correction.is_identity,
        )
        self.publisher.publish(msg)
        self.diagnostics.increment("revolutions")
        self.diagnostics.increment("bearings", len(msg.bearings))
        # windows outside the calibrated ones: the power bias is held at its edge value, not extrapolated
        held = int(sum(self.correction.holds_power_bias(b.angular_window) for b in decoded.bearings))
        if held:
            self.diagnostics.increment("bearings_power_bias_held", held)
        for rejection in decoded.rejections:
            self.diagnostics.increment(f"rejected_{rejection.kind}")
        self.diagnostics.set("calibrated", msg.calibrated)
        status = f"{len(msg.bearings)} bearings in the last revolution"
        if msg.calibrated:
            self.diagnostics.set_level("ok", status)
        else:
            self.diagnostics.set_level("warn", f"{UNCALIBRATED}; {status}")

    def _bearing_fields(self, decoded) -> BearingFields:
        """A decoded bearing, corrected by the calibration (power and rotation bias), its variance with
        what the power-bias correction at the noisy decoded window adds."""
        variance = decoded.variance
        if not self.correction.is_identity and self.decoder is not None:
            published = corrected_variance_of(self.decoder.variance_model, self.correction)
            variance = published.variance(decoded.beacon_id, decoded.angular_window)
        return BearingFields(
            stamp_ns=nanoseconds(decoded.stamp_s),
            beacon_id=decoded.beacon_id,
            bearing_rad=float(wrap_to_pi(self.correction.correct(decoded.bearing, decoded.angular_window))),
            variance_rad2=variance,
            angular_window_rad=decoded.angular_window,
            rising_angle_rad=decoded.rising_angle,
            falling_angle_rad=decoded.falling_angle,
            codes_seen=decoded.codes_seen,
        )


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(DriverNode, args))


if __name__ == "__main__":
    main()
