"""Nothing escapes a callback: one guard at the boundary of every ROS callback of a node.

`GuardedCallbacks` is a mixin for rclpy's Node and LifecycleNode (first among the bases:
`class EkfNode(GuardedCallbacks, Node)`). Every callback given to `create_subscription`,
`create_service`, `create_timer`, `add_on_set_parameters_callback`, `add_pre_set_parameters_callback`
and `add_post_set_parameters_callback` is wrapped so that an unexpected exception

- is logged with its traceback the first time at its site, then as one line at most every
  REPEAT_LOG_PERIOD_S with the count;
- is counted (`callback_exceptions` on /diagnostics) and turns /diagnostics ERROR with the reason for
  `Diagnostics.CALLBACK_FAULT_HOLD_S` (`Diagnostics.callback_failed`);
- calls the node's `recover_from_callback_exception(site)`, where it resets the state the exception may
  have left half-updated (ekf_node: the filter re-initialises from the next fix);

and the node keeps serving: a service caller gets the response type with `success = False` and a
`message` (when the type has those fields), a parameter change is refused with the reason, a
subscription or timer callback simply returns. Exceptions while the context shuts down pass through
(run_node's clean stop handles them). Coroutine callbacks (calibration_node's services) are guarded the
same way, awaited inside the guard.
"""

import functools
import inspect
import traceback
from collections.abc import Callable
from typing import Any

import rclpy
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from beams_common.intake.validation import bounded
from beams_common.ros.node_logging import log_at
from beams_common.status.log_throttle import KeyThrottle

REPEAT_LOG_PERIOD_S = 10.0
# rclpy's default keeps 10 requests: the 11th of a burst (20 operators' calls at once) was lost unanswered
SERVICES_QOS = QoSProfile(
    depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE
)


class GuardedCallbacks:
    """Mixin for rclpy.node.Node and rclpy.lifecycle.LifecycleNode: see the module docstring.

    rclpy's Node constructor already creates services (parameters, lifecycle) through these methods, so
    the guard's state is made on first use, not in __init__.
    """

    # -- the hook a node overrides ---------------------------------------------------------------------
    def recover_from_callback_exception(self, site: str) -> str:
        """Reset what an exception at `site` may have corrupted; returns what was reset ('' nothing)."""
        return ""

    # -- the wrapped creators ------------------------------------------------------------------------
    def create_subscription(self, msg_type, topic, callback, *args, **kwargs):
        site = f"subscription {self._resolved(self.resolve_topic_name, topic)}"
        guarded = self.guard_callback(site, callback, on_failure=lambda *_: None)
        return super().create_subscription(msg_type, topic, guarded, *args, **kwargs)

    def create_service(self, srv_type, srv_name, callback, *args, **kwargs):
        site = f"service {self._resolved(self.resolve_service_name, srv_name)}"
        guarded = self.guard_callback(
            site, callback, on_failure=lambda reason, *_: failed_response(srv_type, reason)
        )
        kwargs.setdefault("qos_profile", SERVICES_QOS)
        return super().create_service(srv_type, srv_name, guarded, *args, **kwargs)

    def create_timer(self, timer_period_sec, callback, *args, **kwargs):
        site = f"timer {getattr(callback, '__qualname__', callback)}"
        return super().create_timer(
            timer_period_sec, self.guard_callback(site, callback, on_failure=lambda *_: None), *args, **kwargs
        )

    def add_on_set_parameters_callback(self, callback):
        guarded = self.guard_callback(
            "parameter change",
            callback,
            on_failure=lambda reason, *_: SetParametersResult(
                successful=False, reason=f"refused: internal error: {reason}"
            ),
        )
        self._guarded_parameter_callbacks()[callback] = guarded
        return super().add_on_set_parameters_callback(guarded)

    def remove_on_set_parameters_callback(self, callback):
        guarded = self._guarded_parameter_callbacks().pop(callback, callback)
        return super().remove_on_set_parameters_callback(guarded)

    def add_pre_set_parameters_callback(self, callback):
        # an empty list makes rclpy refuse the change
        guarded = self.guard_callback("parameter pre-set", callback, on_failure=lambda *_: [])
        self._guarded_parameter_callbacks()[callback] = guarded
        return super().add_pre_set_parameters_callback(guarded)

    def remove_pre_set_parameters_callback(self, callback):
        guarded = self._guarded_parameter_callbacks().pop(callback, callback)
        return super().remove_pre_set_parameters_callback(guarded)

    def add_post_set_parameters_callback(self, callback):
        guarded = self.guard_callback("parameter post-set", callback, on_failure=lambda *_: None)
        self._guarded_parameter_callbacks()[callback] = guarded
        return super().add_post_set_parameters_callback(guarded)

    def remove_post_set_parameters_callback(self, callback):
        guarded = self._guarded_parameter_callbacks().pop(callback, callback)
        return super().remove_post_set_parameters_callback(guarded)

    # -- the guard -----------------------------------------------------------------------------------
    def guard_callback(self, site: str, callback: Callable, on_failure: Callable[..., Any]) -> Callable:
        """`callback` wrapped: an exception is handled (`_callback_failed`) and `on_failure(reason,
        *args)` answers in its place. The wrapper keeps the callback's signature (functools.wraps):
        rclpy inspects it (a subscription callback may take the message info)."""
        if inspect.iscoroutinefunction(callback):

            @functools.wraps(callback)
            async def guarded_coroutine(*args):
                try:
                    return await callback(*args)
                except Exception as error:
                    return on_failure(self._callback_failed(site, error), *args)

            return guarded_coroutine

        @functools.wraps(callback)
        def guarded(*args):
            try:
                return callback(*args)
            except Exception as error:
                return on_failure(self._callback_failed(site, error), *args)

        return guarded

    def _callback_failed(self, site: str, error: Exception) -> str:
        """Log, count, show and recover from an exception a callback let out; returns the reason."""
        if isinstance(error, ExternalShutdownException) or not rclpy.ok(context=self.context):
            raise error  # the context is going down: run_node's clean stop, not a fault
        reason = bounded(f"{type(error).__name__}: {error}")
        held_back = self._callback_log_throttle().admit(site)
        logger = self.get_logger()
        if held_back is not None:
            first = site not in self._callback_sites_logged()
            self._callback_sites_logged().add(site)
            detail = traceback.format_exc() if first else reason
            repeats = f" ({held_back} more since the last line)" if held_back else ""
            log_at(
                logger, "error", f"unexpected exception in {site}, the node keeps running{repeats}: {detail}"
            )
        diagnostics = getattr(self, "diagnostics", None)
        recovered = self._recover(site)
        summary = f"{reason}; {recovered}" if recovered else reason
        if diagnostics is not None:
            try:
                diagnostics.callback_failed(site, summary)
            except Exception:  # /diagnostics itself failing (it publishes an ERROR at once) stays here
                log_at(logger, "error", f"could not show the failure of {site}: {traceback.format_exc()}")
        return bounded(f"{site}: {summary}")

    def _recover(self, site: str) -> str:
        try:
            return self.recover_from_callback_exception(site)
        except Exception as error:  # a failing reset must not escape either
            log_at(self.get_logger(), "error", f"recovery after {site} failed: {traceback.format_exc()}")
            return f"recovery failed ({type(error).__name__}: {error})"

    @staticmethod
    def _resolved(resolve: Callable[[str], str], name: str) -> str:
        """The fully qualified name for the log and /diagnostics (the name as given if it cannot be)."""
        try:
            return resolve(name)
        except Exception:  # an invalid name: rclpy's creator refuses it right after with its reason
            return name

    # -- state made on first use (rclpy's constructor creates callbacks before ours runs) -------------
    def _callback_log_throttle(self) -> KeyThrottle:
        if "_guard_throttle" not in self.__dict__:
            self._guard_throttle = KeyThrottle(REPEAT_LOG_PERIOD_S)
        return self._guard_throttle

    def _callback_sites_logged(self) -> set[str]:
        if "_guard_sites_logged" not in self.__dict__:
            self._guard_sites_logged: set[str] = set()
        return self._guard_sites_logged

    def _guarded_parameter_callbacks(self) -> dict[Callable, Callable]:
        if "_guard_parameter_callbacks" not in self.__dict__:
            self._guard_parameter_callbacks: dict[Callable, Callable] = {}
        return self._guard_parameter_callbacks


def failed_response(srv_type: Any, reason: str) -> Any:
    """A fresh response of the service type saying it failed (success, message when it has them)."""
    response = srv_type.Response()
    fields = response.get_fields_and_field_types()
    if fields.get("success") == "boolean":
        response.success = False
    if fields.get("message") == "string":
        response.message = bounded(f"internal error, nothing done; the node keeps running: {reason}")
    return response
