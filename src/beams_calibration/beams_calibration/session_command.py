"""`calibration_session`: a guided chapter-7 capture at a running calibration_node, then the calibration.

    calibration_session [--positions 12] [--orientations 4] [--area x_min,x_max,y_min,y_max]
                        [--revolutions N] [--yes] [--dry-run] [--no-calibrate] [--simulate]

Asks the node for its beacon map, spreads table 7.2's positions over the table (or --area), and for each
pose not yet in the dataset says where to place the robot, waits for Enter, captures (capture_reference)
with a progress bar, shows whether the capture took (beacons seen, robot still) and offers to retry or
skip; then lists the dataset and calibrates (calibrate) with a before/after table and the files written.
Stopped half-way, it resumes: the poses already in the dataset are skipped. Without a terminal it reads
its answers line by line from stdin; --yes answers Enter to every prompt.

--simulate is a rehearsal without a robot: the command publishes each pose it asks for as the simulated
robot's ground truth (beams/sim/ground_truth) for a driver_node started with `source: sim` and
`sim_static_pose: [0.0]`, and no sim_world_node. Exit status: 0 calibrated, 1 stopped before the
calibration, 2 a setup error or the calibration refused.
"""

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rcl_interfaces.srv import GetParameters
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.utilities import remove_ros_args

from beams_calibration.session import (
    DEFAULT_MAX_ATTEMPTS,
    EXIT_STOPPED,
    NOMINAL_TURRET_RATE_HZ,
    CalibrationReport,
    CaptureAnswer,
    CaptureProgress,
    Console,
    PlannedPose,
    TableArea,
    critical_positions,
    exit_status,
    plan_problems,
    reference_plan,
    run_session,
)
from beams_common.config.command_line import command
from beams_common.geometry.beacon_map import BeaconMap
from beams_common.interfaces import topics
from beams_common.ros.messages import seconds_to_stamp, set_pose2d
from beams_msgs.srv import Calibrate, CaptureReference, ListConfigurations

# The node's own bound on a capture is revolutions x 0.2 s + 5 s (calibration_node); ours is looser.
CAPTURE_TIMEOUT_S_PER_REVOLUTION = 0.2
CAPTURE_TIMEOUT_MARGIN_S = 15.0
# Algorithm 7.1 with the leave-one-position-out folds takes minutes on 48 configurations at most.
CALIBRATE_TIMEOUT_S = 1800.0
# Rehearsal: ground truth published at this rate, and revolutions left to pass after a placement.
SIMULATED_TRUTH_RATE_HZ = 20.0
SIMULATED_SETTLE_S = 0.5
NODE_PARAMETERS = ("beacon_ids", "beacon_x", "beacon_y", "min_configurations", "default_revolutions")


class SetupError(ValueError):
    """The session cannot start (no node, a bad plan); says why."""


def _area(text: str) -> TableArea:
    try:
        return TableArea.parse(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="calibration_session",
        description=__doc__.split("\n\n")[0],
        epilog="Run it in the calibration node's namespace: --ros-args -r __ns:=/robot1",
    )
    parser.add_argument("--positions", type=int, default=12, help="reference positions of table 7.2 (1-12)")
    parser.add_argument("--orientations", type=int, default=4, help="headings per position (4: eq. 7.3)")
    parser.add_argument(
        "--area",
        type=_area,
        help="x_min,x_max,y_min,y_max (m) to spread the positions over (default: the beacons' bounding box)",
    )
    parser.add_argument(
        "--revolutions",
        type=int,
        default=0,
        help="revolutions per capture (0: the node's default_revolutions)",
    )
    parser.add_argument("--node", default="calibration_node", help="the calibration node's name")
    parser.add_argument("--yes", action="store_true", help="answer Enter to every prompt (no input read)")
    parser.add_argument(
        "--max-attempts",
        type=int,
        default=DEFAULT_MAX_ATTEMPTS,
        help="with --yes, captures tried per pose before skipping it",
    )
    parser.add_argument(
        "--force", action="store_true", help="record poses outside the beacons' table or off their bearings"
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="calibrate without writing the calibration file"
    )
    parser.add_argument("--no-calibrate", action="store_true", help="capture only")
    parser.add_argument(
        "--simulate",
        action="store_true",
        help="rehearsal: publish each pose as the simulated robot's ground truth (beams/sim/ground_truth)",
    )
    parser.add_argument("--wait", type=float, default=10.0, help="seconds to wait for the node's services")
    return parser


class RosCalibrationServices:
    """The session's `CalibrationServices` over a running calibration_node's services."""

    def __init__(self, node: Node, args: argparse.Namespace) -> None:
        self.node = node
        self.args = args
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)
        # the node's private services (beams_common.interfaces.topics): /<namespace>/<node>/capture_reference
        service = f"{args.node}/{{}}".format
        self.capture_client = node.create_client(CaptureReference, service(topics.CAPTURE_REFERENCE[2:]))
        self.list_client = node.create_client(ListConfigurations, service(topics.LIST_CONFIGURATIONS[2:]))
        self.calibrate_client = node.create_client(Calibrate, service(topics.CALIBRATE[2:]))
        self.parameter_client = node.create_client(GetParameters, f"{args.node}/get_parameters")
        target = node.resolve_service_name(args.node)
        self.diagnostic_name = f"{target}: calibration"
        self.revolutions_received: int | None = None
        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diagnostics, 10)
        self.revolutions = args.revolutions
        self._truth: tuple[float, float, float] | None = None
        self._placed_s = 0.0
        if args.simulate:
            self._truth_publisher = node.create_publisher(Odometry, topics.GROUND_TRUTH, 10)
            node.create_timer(1.0 / SIMULATED_TRUTH_RATE_HZ, self._publish_truth)

    # ---- start-up ----

    def connect(self) -> dict[str, Any]:
        """Wait for the node's services; its parameters the session needs."""
        for client in (self.capture_client, self.list_client, self.calibrate_client, self.parameter_client):
            if not client.wait_for_service(timeout_sec=self.args.wait):
                raise SetupError(
                    f"{client.srv_name} not available within {self.args.wait} s: is calibration_node "
                    "running (in this namespace, with this ROS_DOMAIN_ID)?"
                )
        reply = self._call(self.parameter_client, GetParameters.Request(names=list(NODE_PARAMETERS)), 10.0)
        values = dict(zip(NODE_PARAMETERS, map(parameter_value_to_python, reply.values), strict=True))
        if self.revolutions <= 0:
            self.revolutions = int(values["default_revolutions"])
        return values

    # ---- CalibrationServices ----

    def place(self, planned: PlannedPose) -> None:
        if self.args.simulate:
            self._truth = planned.pose
            self._placed_s = time.monotonic()
            self._spin_for(0.0)

    def capture(self, planned: PlannedPose, console: Console) -> CaptureAnswer:
        if self.args.simulate:  # the simulated robot's revolutions from before its placement pass first
            self._spin_for(self._placed_s + SIMULATED_SETTLE_S - time.monotonic())
        progress = CaptureProgress(self.revolutions, time.monotonic(), self.revolutions_received)
        request = CaptureReference.Request(
            x=planned.x_m,
            y=planned.y_m,
            theta=planned.theta_rad,
            revolutions=self.revolutions,
            force=self.args.force,
        )

        def tick() -> None:
            progress.latest_count = self.revolutions_received
            now = time.monotonic()
            console.progress(progress.line(now), progress.fraction(now))

        timeout_s = self.revolutions * CAPTURE_TIMEOUT_S_PER_REVOLUTION + CAPTURE_TIMEOUT_MARGIN_S
        reply = self._call(self.capture_client, request, timeout_s, tick)
        console.end_progress()
        if reply is None:
            return CaptureAnswer(False, f"no answer from capture_reference within {timeout_s:.0f} s", 0)
        return CaptureAnswer(reply.success, reply.message, reply.configurations)

    def list_configurations(self) -> tuple[list[str], str]:
        reply = self._call(self.list_client, ListConfigurations.Request(), 10.0)
        if reply is None:
            return ["error: list_configurations did not answer within 10 s"], "?"
        return list(reply.summaries), reply.dataset_file

    def calibrate(self, console: Console) -> CalibrationReport:
        started = time.monotonic()
        console.say("calibrating (Algorithm 7.1, then the leave-one-position-out fits) ...")

        def tick() -> None:
            console.progress(f"calibrating ... {time.monotonic() - started:.0f} s", 0.0)

        request = Calibrate.Request(dry_run=self.args.dry_run, force=False)
        reply = self._call(self.calibrate_client, request, CALIBRATE_TIMEOUT_S, tick)
        console.end_progress()
        if reply is None:
            return CalibrationReport(False, f"calibrate did not answer within {CALIBRATE_TIMEOUT_S:.0f} s")
        return CalibrationReport(
            success=reply.success,
            message=reply.message,
            position_rms_before_m=reply.position_rms_before,
            position_rms_after_m=reply.position_rms_after,
            orientation_rms_before_rad=reply.orientation_rms_before,
            orientation_rms_after_rad=reply.orientation_rms_after,
            leave_one_out_position_m=reply.leave_one_out_position_rms,
            leave_one_out_orientation_rad=reply.leave_one_out_orientation_rms,
            warnings=tuple(reply.warnings),
            files_written=tuple(reply.files_written),
            calibration_file=reply.calibration_file,
        )

    # ---- ROS plumbing ----

    def _call(
        self, client: Any, request: Any, timeout_s: float, tick: Callable[[], None] | None = None
    ) -> Any:
        """Call a service, spinning (bounded) until it answers; None on a time-out."""
        future = client.call_async(request)
        deadline = time.monotonic() + timeout_s
        while not future.done() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.1)
            if tick is not None:
                tick()
        return future.result() if future.done() else None

    def _spin_for(self, duration_s: float) -> None:
        deadline = time.monotonic() + max(duration_s, 0.0)
        while True:
            self.executor.spin_once(timeout_sec=0.05)
            if time.monotonic() >= deadline:
                return

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name != self.diagnostic_name:
                continue
            for item in status.values:
                if item.key == "revolutions_received":
                    self.revolutions_received = int(item.value)

    def _publish_truth(self) -> None:
        if self._truth is None:
            return
        msg = Odometry()
        msg.header.stamp = seconds_to_stamp(self.node.get_clock().now().nanoseconds * 1e-9)
        msg.header.frame_id = "map"
        msg.child_frame_id = "base_link"
        set_pose2d(msg.pose.pose, self._truth)
        self._truth_publisher.publish(msg)


def _plan(args: argparse.Namespace, values: dict[str, Any]) -> tuple[PlannedPose, ...]:
    beacons = BeaconMap.from_lists(values["beacon_ids"], values["beacon_x"], values["beacon_y"])
    try:
        area = args.area or TableArea.of_beacons(beacons)
        excluded = critical_positions(area, beacons)
        plan = reference_plan(area, args.positions, args.orientations, excluded)
    except ValueError as error:
        raise SetupError(str(error)) from None
    if excluded:
        print(
            f"left out of the plan: P{', P'.join(map(str, excluded))} of table 7.2, too near the beacons' "
            "critical circumference (section 6.3) on this table",
            flush=True,
        )
    problems = plan_problems(plan, beacons, 0 if args.no_calibrate else int(values["min_configurations"]))
    if args.force:
        problems = [p for p in problems if "would refuse" not in p]
    if problems:
        raise SetupError("; ".join(problems))
    return plan


@command("calibration_session")
def main(argv: Sequence[str] | None = None) -> int:
    """The `calibration_session` console script; returns the exit status."""
    argv = ["calibration_session", *(sys.argv[1:] if argv is None else argv)]
    args = _parser().parse_args(remove_ros_args(argv)[1:])
    console = Console(
        sys.stdin, sys.stdout, assume_yes=args.yes, tty=sys.stdin.isatty() and sys.stdout.isatty()
    )
    rclpy.init(args=argv)
    node = rclpy.create_node("calibration_session")
    try:
        services = RosCalibrationServices(node, args)
        plan = _plan(args, services.connect())
        duration_s = services.revolutions / NOMINAL_TURRET_RATE_HZ
        console.say(
            f"plan: {len(plan)} poses ({args.positions} positions x {args.orientations} orientations), "
            f"{services.revolutions} revolutions each (~{duration_s:.0f} s)"
            + (" [rehearsal: the simulated robot is moved to each pose]" if args.simulate else "")
        )
        outcome = run_session(
            plan, services, console, max_attempts=args.max_attempts, calibrate=not args.no_calibrate
        )
        return exit_status(outcome)
    except (KeyboardInterrupt, ExternalShutdownException):
        console.say("\nstopped; run the same command again to resume (the captured poses are skipped)")
        return EXIT_STOPPED
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
