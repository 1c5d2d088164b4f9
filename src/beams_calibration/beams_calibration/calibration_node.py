"""calibration_node: chapter 7's calibration of BeAMS as ROS services, from capture (raw bearings: a driver
without a calibration file) to calibration file; its services are in docs/nodes.md. They are coroutines, so
the node keeps receiving bearings while one waits or calibrates; a second one meanwhile is refused as busy.
"""

import math
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future
from std_srvs.srv import Trigger

from beams_calibration.calibrate import (
    CalibrationRefusedError,
    CalibrationResult,
    CoverageRequirements,
    calibrate,
)
from beams_calibration.dataset import (
    Configuration,
    DatasetError,
    append_configuration,
    average_capture,
    capture_bearing_problem,
    capture_pose_problem,
    load_dataset,
    save_dataset,
)
from beams_calibration.outputs import rms_regression, write_outputs
from beams_calibration.parameters import CALIBRATION_PARAMETERS
from beams_common.calibration.calibration_file import SensorCalibration
from beams_common.config.geometry_parameters import beacon_map_of
from beams_common.geometry.beacon_map import BeaconMap
from beams_common.intake.validation import bounded
from beams_common.interfaces import topics
from beams_common.ros.callback_guard import GuardedCallbacks
from beams_common.ros.input_watch import WatchedInputs
from beams_common.ros.node_support import BEARINGS_QOS, Diagnostics, run_node
from beams_common.ros.parameters import ParameterValidationError, apply_runtime_changes, declare_table
from beams_msgs.msg import BeaconBearingArray
from beams_msgs.srv import Calibrate, CaptureReference, ListConfigurations

# Upper bound on a turret period (s) when bounding a capture's duration (the sensor turns at ~10 Hz).
SLOWEST_REVOLUTION_S = 0.2
CAPTURE_MARGIN_S = 5.0
MAX_REVOLUTIONS = 10000
BUSY = "busy: a capture, calibration or clear is in progress; try again"


@dataclass
class _Capture:
    """A capture in progress: the revolutions received so far and the future the service awaits."""

    target: int
    done: Future
    revolutions: list[dict[int, tuple[float, float]]] = field(default_factory=list)


class CalibrationNode(WatchedInputs, GuardedCallbacks, Node):
    def __init__(self) -> None:
        super().__init__("calibration_node")
        self.parameters = declare_table(self, CALIBRATION_PARAMETERS)
        self.dataset_file = Path(self.parameters["dataset_file"])
        self.prior_map = beacon_map_of(self.parameters)
        self._apply_parameters(self.parameters, set(self.parameters))
        # the table validates everything these settings need: nothing to prepare, applied in post-set
        apply_runtime_changes(
            self, CALIBRATION_PARAMETERS, self.parameters, lambda v, c: partial(self._apply_parameters, v, c)
        )
        self._check_dataset_file()
        self.diagnostics = Diagnostics(self, "calibration")
        self._capture: _Capture | None = None
        self._busy = False
        self._steady_clock = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_subscription(BeaconBearingArray, topics.BEARINGS, self._on_bearings, BEARINGS_QOS)
        services = ReentrantCallbackGroup()
        self.create_service(
            CaptureReference, topics.CAPTURE_REFERENCE, self._on_capture, callback_group=services
        )
        self.create_service(Calibrate, topics.CALIBRATE, self._on_calibrate, callback_group=services)
        self.create_service(
            ListConfigurations, topics.LIST_CONFIGURATIONS, self._on_list, callback_group=services
        )
        self.create_service(Trigger, topics.CLEAR_DATASET, self._on_clear, callback_group=services)
        self.get_logger().info(
            f"dataset {self.dataset_file} ({self._count()} configurations), "
            f"calibration file {self.output_file}; listening to {self.resolve_topic_name('beams/bearings')} "
            "(run the driver without calibration_file while capturing)"
        )

    # ---- parameters ----

    def _apply_parameters(self, values: dict, _changed: set[str]) -> None:
        """The capture and fit settings (each service call reads them), at start-up and at runtime."""
        self.output_file = Path(values["calibration_file_out"])
        self.plots_directory = values["plots_directory"]
        self.default_revolutions = values["default_revolutions"]
        self.min_seen_fraction = values["min_seen_fraction"]
        self.max_spread_rad = math.radians(values["max_spread_deg"])
        self.eta = values["eta_m_per_rad"]
        self.threshold = values["threshold"]
        self.max_iterations = values["max_iterations"]
        self.leave_one_out = values["leave_one_out"]
        self.requirements = CoverageRequirements(min_configurations=values["min_configurations"])

    def _check_dataset_file(self) -> None:
        """An existing but unreadable dataset is a start-up error, not something to overwrite later."""
        if not self.dataset_file.exists():
            return
        try:
            dataset = load_dataset(self.dataset_file)
        except (OSError, DatasetError) as error:
            raise ParameterValidationError(f"dataset_file: {error}") from None
        if dataset.beacon_map.ids != self.prior_map.ids:
            self.get_logger().warning(
                f"the dataset's beacons {list(dataset.beacon_map.ids)} differ from beacon_ids "
                f"{list(self.prior_map.ids)}: the dataset's a-priori map is used"
            )

    def _count(self) -> int:
        try:
            return len(load_dataset(self.dataset_file).configurations) if self.dataset_file.exists() else 0
        except (OSError, DatasetError):
            return 0

    # ---- bearings ----

    def _on_bearings(self, msg: BeaconBearingArray) -> None:
        self.diagnostics.increment("revolutions_received")
        capture = self._capture
        if capture is None or capture.done.done():
            return
        if self.diagnostics.oversized_revolution(msg):
            return
        revolution = {
            int(b.beacon_id): (float(b.bearing), float(b.angular_window))
            for b in msg.bearings
            if math.isfinite(b.bearing) and math.isfinite(b.angular_window)
        }
        if len(revolution) < len(msg.bearings):  # a capture averages what is left: say what was not
            self.diagnostics.refuse(
                "bearings_refused_non_finite",
                f"revolution {msg.revolution}: {len(msg.bearings) - len(revolution)} bearing(s) with a "
                "non-finite bearing or window (or a beacon repeated) left out of the capture",
            )
        capture.revolutions.append(revolution)
        if len(capture.revolutions) >= capture.target:
            capture.done.set_result(True)

    # ---- services ----

    async def _on_capture(self, request: CaptureReference.Request, response: CaptureReference.Response):
        pose = (request.x, request.y, request.theta)
        if self._busy:
            return self._capture_reply(response, BUSY)
        implausible = capture_pose_problem(*pose, self._dataset_map_or_prior())
        if implausible and not (request.force and all(math.isfinite(v) for v in pose)):
            return self._capture_reply(
                response, f"refused: {implausible}" + ("" if request.force else " (force: true records it)")
            )
        revolutions = int(request.revolutions) or int(self.default_revolutions)
        if revolutions > MAX_REVOLUTIONS:
            return self._capture_reply(response, f"refused: at most {MAX_REVOLUTIONS} revolutions")
        self._busy = True
        try:
            samples = await self._collect(revolutions)
            if len(samples) < revolutions:
                return self._capture_reply(
                    response,
                    f"refused: {len(samples)} of {revolutions} revolutions received in time: "
                    f"is the driver publishing {self.resolve_topic_name('beams/bearings')}?",
                )
            dataset_map = self._dataset_map()
            observations = average_capture(
                samples,
                dataset_map.ids,
                min_seen_fraction=self.min_seen_fraction,
                max_spread_rad=self.max_spread_rad,
            )
            mismatch = capture_bearing_problem(pose, observations, dataset_map)
            if mismatch and not request.force:
                raise DatasetError(f"{mismatch} (force: true records it)")
            configuration = Configuration(
                *map(float, pose), observations, revolutions, SensorCalibration.now_utc()
            )
            dataset = append_configuration(self.dataset_file, dataset_map, configuration)
        except (OSError, DatasetError) as error:
            self.diagnostics.set("last_capture", f"refused: {error}")
            return self._capture_reply(response, f"refused: {error}")
        finally:
            self._busy = False
        response.success = True
        response.configurations = len(dataset.configurations)
        message = f"configuration {response.configurations} recorded: {configuration.summary()}"
        response.message = message
        self.diagnostics.set("configurations", response.configurations)
        self.diagnostics.set("last_capture", "recorded")
        self.get_logger().info(message)
        return response

    def _capture_reply(self, response: CaptureReference.Response, message: str) -> CaptureReference.Response:
        response.configurations = self._count()
        return self._refuse(response, message, "captures_refused")

    def _dataset_map_or_prior(self) -> BeaconMap:
        """The dataset's beacon map, or the a-priori one when the dataset is missing or unreadable."""
        try:
            return self._dataset_map()
        except (OSError, DatasetError):
            return self.prior_map

    async def _collect(self, revolutions: int) -> list[dict[int, tuple[float, float]]]:
        """Wait for the next `revolutions` revolutions, bounded in (steady) time."""
        capture = _Capture(target=revolutions, done=Future(executor=self.executor))
        timeout_s = revolutions * SLOWEST_REVOLUTION_S + CAPTURE_MARGIN_S

        def expire() -> None:
            if not capture.done.done():
                capture.done.set_result(False)

        # A steady-clock timer: an operator's time-out, valid with use_sim_time and no /clock.
        timer = self.create_timer(timeout_s, expire, clock=self._steady_clock)
        self._capture = capture
        try:
            await capture.done
        finally:
            self._capture = None
            self.destroy_timer(timer)
        return capture.revolutions

    def _dataset_map(self) -> BeaconMap:
        return load_dataset(self.dataset_file).beacon_map if self.dataset_file.exists() else self.prior_map

    def _refuse(self, response: Any, message: str, counter: str = "") -> Any:
        response.success = False
        response.message = bounded(message)
        if counter:
            self.diagnostics.refuse(counter, response.message)
        return response

    async def _on_calibrate(self, request: Calibrate.Request, response: Calibrate.Response):
        if self._busy:
            return self._refuse(response, BUSY)
        self._busy = True
        try:
            dataset = load_dataset(self.dataset_file)
            result = await self._in_worker(
                lambda: calibrate(
                    dataset,
                    eta_m_per_rad=self.eta,
                    threshold=self.threshold,
                    max_iterations=self.max_iterations,
                    leave_one_out=self.leave_one_out,
                    requirements=self.requirements,
                    progress=lambda line: self.get_logger().info(f"calibrate: {line}"),
                )
            )
            worse = rms_regression(result, self.eta)
            if worse and not request.force:
                raise CalibrationRefusedError(f"{worse} (force: true writes it); nothing written")
            output = None if request.dry_run else self.output_file
            plots = Path(self.plots_directory) if self.plots_directory else None
            # every file written beside its target first: a failure leaves them all as they were
            files = await self._in_worker(lambda: write_outputs(result, output, plots))
            written = "" if output is None else str(output)
        except (OSError, DatasetError, CalibrationRefusedError) as error:
            return self._refuse(response, f"not calibrated, no file changed: {error}", "calibrations_refused")
        finally:
            self._busy = False
        response.success = True
        response.position_rms_before = result.before.position_rms_m
        response.position_rms_after = result.after.position_rms_m
        response.orientation_rms_before = result.before.orientation_rms_rad
        response.orientation_rms_after = result.after.orientation_rms_rad
        response.calibration_file = written
        generalisation = result.leave_one_out
        response.leave_one_out_position_rms = generalisation.position_rms_m if generalisation else math.nan
        response.leave_one_out_orientation_rms = (
            generalisation.orientation_rms_rad if generalisation else math.nan
        )
        response.warnings = [bounded(w) for w in result.warnings]
        response.files_written = [str(path) for path in files]
        response.message = _summary(result, written)
        self.diagnostics.set_level("warn" if result.warnings else "ok", response.message)
        self.get_logger().info(response.message)
        return response

    async def _in_worker(self, work: Callable[[], Any]) -> Any:
        """Run blocking work in a thread and await it: the executor keeps serving meanwhile."""
        future = Future(executor=self.executor)

        def run() -> None:
            try:
                future.set_result(work())
            except Exception as error:  # handed to the awaiting service, which reports it
                future.set_exception(error)

        threading.Thread(target=run, name="calibration", daemon=True).start()
        return await future

    def _on_list(self, _request: ListConfigurations.Request, response: ListConfigurations.Response):
        response.dataset_file = str(self.dataset_file)
        try:
            configurations = (
                load_dataset(self.dataset_file).configurations if self.dataset_file.exists() else ()
            )
        except (OSError, DatasetError) as error:
            response.summaries = [f"error: {error}"]
            return response
        response.configurations = len(configurations)
        response.summaries = [f"{k + 1}: {c.summary()}" for k, c in enumerate(configurations)]
        return response

    def _on_clear(self, _request: Trigger.Request, response: Trigger.Response):
        if self._busy:
            return self._refuse(response, BUSY)
        if not self.dataset_file.exists():
            response.success = True
            response.message = f"nothing to clear: {self.dataset_file} does not exist (no .bak made)"
            self.get_logger().info(response.message)
            return response
        try:
            dataset = load_dataset(self.dataset_file)
            save_dataset(dataset.cleared(), self.dataset_file)  # keeps the previous file as .bak
        except (OSError, DatasetError) as error:
            return self._refuse(response, f"not cleared, the dataset is unchanged: {error}", "clears_refused")
        response.success = True
        response.message = (
            f"cleared {len(dataset.configurations)} configurations; the previous dataset is kept as "
            f"{self.dataset_file}.bak"
        )
        self.diagnostics.set("configurations", 0)
        self.get_logger().info(response.message)
        return response


def _summary(result: CalibrationResult, written: str) -> str:
    text = (
        f"position RMS {result.before.position_rms_m * 1e3:.2f} -> "
        f"{result.after.position_rms_m * 1e3:.2f} mm, "
        f"orientation RMS {math.degrees(result.before.orientation_rms_rad):.3f} -> "
        f"{math.degrees(result.after.orientation_rms_rad):.3f} deg"
    )
    if result.leave_one_out is not None:
        text += f", leave-one-position-out {result.leave_one_out.position_rms_m * 1e3:.2f} mm"
    text += f"; written to {written}" if written else "; dry run, nothing written"
    if result.warnings:
        text += "; WARNINGS: " + "; ".join(result.warnings)
    return text


def main(args: list[str] | None = None) -> None:
    # async services (a capture awaits revolutions): rclpy's Python executor runs them
    sys.exit(run_node(CalibrationNode, args, events_executor=False))
