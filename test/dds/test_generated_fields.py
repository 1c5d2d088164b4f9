"""Every field, parameter and service request field of each node, from the definitions (field_walk.py).

Each node is built in this process on a simulated clock (use_sim_time, the time set by the test); its
subscription, service, parameter and timer callbacks are called with real message objects, and what its
publishers are handed is kept. The cases: every leaf field of every message type the node subscribes to
(rosidl's SLOT_TYPES: header.stamp, header.frame_id, each covariance entry, each bearing's fields, the
sequences' lengths), every request field of its services, every parameter of its table at runtime (the
start-up refusals: test_parameter_refusals.py), each first as an explicit example with a bad value of its
kind, then hypothesis's own draws (derandomized: CI is reproducible). After each case, on every output:
finite, in a REP-105 frame, on the table, covariances symmetric, semi-definite and not absurd
(field_walk.output_problems); never `success: true` for what was not done (the node's state compared
before and after); never `tracking` on a stream the node refused, nor while the truth is outside the
protection level; no callback let an exception out, and on good input afterwards the true pose.
"""

import math
import pathlib
import sys
from functools import partial
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(pathlib.Path(__file__).parent))
import field_walk as fw

TRUE_POSE = (1.2, 0.8, 0.4)
VARIANCE_RAD2 = 3e-7
T0_S = 1000.0
REVOLUTION_S = 0.1
ODOMETRY_PER_REVOLUTION = 2
POSE_BOUND_M = 0.005
# revolutions of a case, and of good input afterwards
CASE, AFTER = 2, 3
# hypothesis's own draws per node, after the explicit walk of every field
GENERATED = 15
# NaN here says "no protection level" (docs/protection_level.md), "not computed" (leave-one-out)
ALLOWED_NAN = ("protection_level_m", "protection_level_rad", "leave_one_out_position_rms")


def _settings(count: int = GENERATED):
    return settings(
        max_examples=count,
        derandomize=True,
        database=None,
        deadline=None,
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=list(HealthCheck),
        report_multiple_bugs=False,
    )


def walked(test, cases):
    """`test` with one explicit example per case: every field walked, whatever hypothesis draws."""
    for case in cases:
        test = example(case)(test)
    return test


@pytest.fixture
def sim_time(ros_env):
    rclpy = pytest.importorskip("rclpy", reason="rclpy missing: run the tests through `make test`")
    # no checkpoint: ekf_node would write one at every tick
    rclpy.init(args=["fields", "--ros-args", "-p", "use_sim_time:=true", "-p", "checkpoint_file:=''"])
    nodes = []
    yield nodes.append
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()


class Harness:
    """A node built in this process on a simulated clock: its callbacks called with real messages, what
    its publishers are handed kept in `outputs` as (topic, message)."""

    def __init__(self, node: Any) -> None:
        self.node = node
        self.outputs: list[tuple[str, Any]] = []
        self.capture()
        self.set_time(T0_S)

    def capture(self) -> None:
        for publisher in self.node.publishers:
            publisher.publish = partial(self._keep, publisher.topic_name)
            # a reader on every output: what a node builds only while something subscribes is checked too
            publisher.get_subscription_count = lambda: 1

    def _keep(self, topic: str, message: Any) -> None:
        self.outputs.append((topic, message))

    def set_time(self, now_s: float) -> None:
        from rclpy.time import Time

        self.now_s = now_s
        self.node.get_clock().set_ros_time_override(Time(nanoseconds=round(now_s * 1e9)))

    def deliver(self, topic: str, message: Any) -> None:
        next(s for s in self.node.subscriptions if s.topic_name.endswith(topic)).callback(message)

    def call(self, name: str, request: Any) -> Any:
        service = next(s for s in self.node.services if s.srv_name.split("/")[-1] == name)
        return service.callback(request, service.srv_type.Response())

    def tick(self) -> None:
        """Every timer fires once (the node's periodic work: its status, /diagnostics, publications)."""
        for timer in list(self.node.timers):
            timer.callback()

    def set_parameter(self, name: str, value: Any) -> Any:
        """`ros2 param set`: through the node's parameter service; its result."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
        (result,) = self.call("set_parameters", request).results
        return result

    def take(self) -> list[tuple[str, Any]]:
        outputs, self.outputs = self.outputs, []
        return outputs

    def exceptions(self) -> str:
        diagnostics = self.node.diagnostics
        if diagnostics.get("callback_exceptions"):
            return diagnostics.get("last_callback_exception", "?")
        return ""

    def conclude(self, case: Any, problems: list[str]) -> None:
        """One case's end: a failed callback is a problem too; the count starts again for the next case."""
        if self.exceptions():
            problems.append(f"a callback failed: {self.exceptions()}")
        self.node.diagnostics.set("callback_exceptions", 0)
        assert not problems, f"{case}: {problems[:5]}"


def output_problems(harness: Harness, outputs: list[tuple[str, Any]]) -> list[str]:
    """The output invariants on every message, in REP-105's frames or the node's frame parameters when
    they are frame names; a pose published as rejected (and the markers after it) keeps its numbers:
    finite, in its frame, but anywhere."""
    frames = fw.FRAMES | {
        value
        for name, value in harness.node.parameters.items()
        if name.endswith(("_frame", "frame_id")) and fw.FRAME_NAME.fullmatch(str(value))
    }
    problems, accepted = [], True
    for topic, message in outputs:
        accepted = getattr(message, "accepted", accepted if hasattr(message, "markers") else True)
        found = fw.output_problems(message, harness.now_s, ALLOWED_NAN, geometry=accepted, frames=frames)
        problems += [f"{topic}: {problem}" for problem in found]
    return problems


def statuses(outputs: list[tuple[str, Any]]) -> list[Any]:
    from beams_msgs.msg import LocalisationStatus

    return [m for _, m in outputs if isinstance(m, LocalisationStatus)]


def parameter_case(spec, value):
    """ParameterSpec objects are not hashable by hypothesis's reporting: cases carry the name."""
    return ("parameter", spec.name, value, None)


def parameter_cases(table) -> st.SearchStrategy:
    return st.sampled_from(table.specs).flatmap(
        lambda spec: fw.parameter_values(spec).map(partial(parameter_case, spec))
    )


def message_cases(name: str, cls: type, skip: tuple[str, ...] = ()) -> st.SearchStrategy:
    return fw.field_cases(cls, skip).map(lambda case: (name, *case))


def explicit(name: str, cls: type, skip: tuple[str, ...] = ()) -> list[tuple]:
    return [(name, *case) for case in fw.walk(cls, skip)]


def explicit_parameters(table) -> list[tuple]:
    return [parameter_case(spec, fw.bad_value(spec)) for spec in table.specs]


# --- the robot standing still at TRUE_POSE ------------------------------------------------------------


def stamp(now_s: float):
    from beams_common.ros.messages import seconds_to_stamp

    return seconds_to_stamp(now_s)


def odometry(now_s: float):
    from nav_msgs.msg import Odometry

    msg = Odometry()
    msg.header.stamp = stamp(now_s)
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    msg.pose.pose.orientation.w = 1.0
    return msg


def true_bearings() -> list[tuple[int, float]]:
    from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
    from beams_triangulation.total import expected_bearings

    angles = expected_bearings(EUROBOT_BEACON_MAP.xy, TRUE_POSE)
    return [(int(i), float(a)) for i, a in zip(EUROBOT_BEACON_MAP.ids, angles, strict=True)]


def revolution(number: int, now_s: float):
    from beams_common.interfaces.bearing_messages import BearingFields, nanoseconds
    from beams_common.ros.messages import bearing_array

    fields = [
        BearingFields(
            nanoseconds(now_s - 0.08 + 0.03 * k), beacon_id, bearing, VARIANCE_RAD2, 0.1, 0.0, 0.1, 3
        )
        for k, (beacon_id, bearing) in enumerate(true_bearings())
    ]
    return bearing_array(nanoseconds(now_s - 0.1), fields, period_s=0.1, revolution=number, frame_id="beams")


def planar_pose(msg, now_s: float, variance: float = 1e-4):
    msg.header.stamp = stamp(now_s)
    msg.header.frame_id = "map"
    msg.pose.pose.position.x, msg.pose.pose.position.y = TRUE_POSE[:2]
    msg.pose.pose.orientation.z = math.sin(TRUE_POSE[2] / 2)
    msg.pose.pose.orientation.w = math.cos(TRUE_POSE[2] / 2)
    for index in (0, 7, 35):
        msg.pose.covariance[index] = variance
    return msg


def total_pose(now_s: float):
    from beams_msgs.msg import TriangulatedPose

    msg = planar_pose(TriangulatedPose(accepted=True, beacon_ids=[1, 2, 3], inverse_abs_d=0.5), now_s - 0.05)
    msg.reason = "accepted"
    return msg


def operator_pose(now_s: float):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    return planar_pose(PoseWithCovarianceStamped(), now_s, 0.01)


def error_m(pose) -> float:
    return math.hypot(pose.position.x - TRUE_POSE[0], pose.position.y - TRUE_POSE[1])


class StillRobot:
    """The inputs of a robot standing at TRUE_POSE, one revolution at a time, any of them replaced by
    the case's (`bad`: topic -> the message maker)."""

    def __init__(self, harness: Harness, topics: tuple[str, ...]) -> None:
        self.harness, self.topics = harness, topics
        self.number = 0

    def revolutions(self, count: int, bad: dict | None = None, topics: tuple[str, ...] | None = None) -> None:
        bad, topics = bad or {}, self.topics if topics is None else topics
        harness = self.harness
        for _ in range(count):
            for _ in range(ODOMETRY_PER_REVOLUTION):
                harness.set_time(harness.now_s + REVOLUTION_S / ODOMETRY_PER_REVOLUTION)
                if "odom" in topics:
                    harness.deliver("odom", bad.get("odom", odometry)(harness.now_s))
            self.number += 1
            makers = {"beams/bearings": partial(revolution, self.number), "beams/pose": total_pose}
            for topic in ("beams/bearings", "beams/pose"):
                if topic in topics:
                    harness.deliver(topic, bad.get(topic, makers[topic])(harness.now_s))
            harness.tick()


def mutate(make, leaf, value, element):
    return lambda now_s: fw.mutated(make(now_s), leaf, value, element)


# --- ekf_node -----------------------------------------------------------------------------------------


def test_ekf_node_every_input_field_parameter_and_service(sim_time):
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from std_srvs.srv import Trigger

    from beams_ekf.ekf_node import EkfNode
    from beams_ekf.parameters import EKF_PARAMETERS
    from beams_msgs.msg import BeaconBearingArray, LocalisationStatus, TriangulatedPose
    from beams_msgs.srv import SetPose

    node = EkfNode()
    sim_time(node)
    harness = Harness(node)
    robot = StillRobot(harness, ("odom", "beams/bearings", "beams/pose"))
    makers = {
        "odom": (Odometry, odometry),
        "beams/bearings": (BeaconBearingArray, lambda now_s: revolution(robot.number + 1, now_s)),
        "beams/pose": (TriangulatedPose, total_pose),
        "/initialpose": (PoseWithCovarianceStamped, operator_pose),
        "set_pose": (SetPose.Request, lambda now_s: SetPose.Request(pose=operator_pose(now_s))),
    }
    cases = st.one_of(
        *(message_cases(name, cls) for name, (cls, _) in makers.items()), parameter_cases(EKF_PARAMETERS)
    )
    explicit_cases = [c for name, (cls, _) in makers.items() for c in explicit(name, cls)]
    explicit_cases += explicit_parameters(EKF_PARAMETERS)

    def check(case) -> None:
        target, what, value, element = case
        reset = harness.call("reset", Trigger.Request())
        assert reset.success
        # initialised from ToTal, not yet confirmed by the bearings
        robot.revolutions(2, topics=("odom", "beams/pose"))
        harness.take()
        accepted_before = node.localiser.stats.counts["bearings_accepted"]
        problems, original = [], None
        if target == "parameter":
            original = change_parameter(harness, what, value, problems)
            robot.revolutions(CASE)
        elif target in ("/initialpose", "set_pose"):
            make = makers[target][1]
            message = fw.mutated(make(harness.now_s), what, value, element)
            before = node.localiser.estimate()
            if target == "set_pose":
                answer = harness.call("set_pose", message)
                pose = message.pose
            else:
                harness.deliver("/initialpose", message)
                answer, pose = None, message
            after = node.localiser.estimate()
            taken = after is not None and (
                before is None or after.stamp_s != before.stamp_s or after.pose != before.pose
            )
            if answer is not None and answer.success:
                x, y = pose.pose.pose.position.x, pose.pose.pose.position.y
                if after is None or not np.allclose(after.pose[:2], (x, y), atol=1e-6):
                    problems.append(f"success, but the estimate is {after and after.pose}, not ({x}, {y})")
            if answer is not None and not answer.success and taken:
                problems.append(f"refused ({answer.message}), yet the estimate changed to {after.pose}")
            robot.revolutions(CASE)
        else:
            make = makers[target][1]
            robot.revolutions(CASE, {target: mutate(make, what, value, element)})
        outputs = harness.take()
        problems += output_problems(harness, outputs)
        tracking = [s for s in statuses(outputs) if s.status == LocalisationStatus.TRACKING]
        if target == "beams/bearings" and node.localiser.stats.counts["bearings_accepted"] == accepted_before:
            problems += [f"tracking on refused bearings: {s.message}" for s in tracking[:1]]
        for status in tracking:
            estimate = _estimate_at(outputs, status.estimate_stamp)
            if estimate is not None and error_m(estimate.pose.pose) > max(
                status.horizontal_protection_level_m, POSE_BOUND_M
            ):
                problems.append(
                    f"tracking {error_m(estimate.pose.pose):.3f} m off the truth, protection level "
                    f"{status.horizontal_protection_level_m:.3f} m"
                )
                break
        if original is not None:
            assert harness.set_parameter(what, original).successful
        robot.revolutions(AFTER)
        outputs = harness.take()
        estimates = [m for topic, m in outputs if topic.endswith("ekf/odometry")]
        problems += output_problems(harness, outputs)
        if not estimates or error_m(estimates[-1].pose.pose) > POSE_BOUND_M:
            problems.append(f"no true pose afterwards: {estimates[-1].pose.pose if estimates else 'nothing'}")
        harness.conclude(case, problems)

    _settings()(given(cases)(walked(check, explicit_cases)))()


def change_parameter(harness: Harness, name: str, value: Any, problems: list[str]) -> Any:
    """Set a parameter as `ros2 param set` does; a success must have set it, and the node's own copy
    (`parameters`), a refusal left both as they were. Returns the value to set back (None: refused)."""
    node = harness.node
    original, before = node.get_parameter(name).value, node.parameters.get(name)
    result = harness.set_parameter(name, value)
    now = node.get_parameter(name).value
    if result.successful and (_differs(now, value) or _differs(node.parameters.get(name), value)):
        problems.append(f"success, but {name} is {now!r} ({node.parameters.get(name)!r}), not {value!r}")
    if not result.successful and (_differs(now, original) or _differs(node.parameters.get(name), before)):
        problems.append(f"refused ({result.reason}), yet {name} changed to {now!r}")
    return original if result.successful else None


def _differs(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return False
    return list(a) != list(b) if isinstance(a, list | tuple) else a != b


def _estimate_at(outputs, stamp_msg):
    for topic, message in reversed(outputs):
        if topic.endswith("ekf/odometry") and message.header.stamp == stamp_msg:
            return message
    return None


# --- triangulation_node -------------------------------------------------------------------------------


def test_triangulation_node_every_input_field_and_parameter(sim_time):
    from nav_msgs.msg import Odometry

    from beams_msgs.msg import BeaconBearingArray, LocalisationStatus
    from beams_triangulation.parameters import TRIANGULATION_PARAMETERS
    from beams_triangulation.triangulation_health import TriangulationHealth
    from beams_triangulation.triangulation_node import TriangulationNode

    node = TriangulationNode()
    sim_time(node)
    harness = Harness(node)
    robot = StillRobot(harness, ("odom", "beams/bearings"))
    makers = {
        "odom": (Odometry, odometry),
        "beams/bearings": (BeaconBearingArray, lambda now_s: revolution(robot.number + 1, now_s)),
    }
    cases = st.one_of(
        *(message_cases(name, cls) for name, (cls, _) in makers.items()),
        parameter_cases(TRIANGULATION_PARAMETERS),
    )
    explicit_cases = [c for name, (cls, _) in makers.items() for c in explicit(name, cls)]
    explicit_cases += explicit_parameters(TRIANGULATION_PARAMETERS)

    def check(case) -> None:
        target, what, value, element = case
        # a fresh start: no pose, no revolution yet
        node.recover_from_callback_exception("test")
        node.health = TriangulationHealth(node.parameters, harness.now_s, use_odometry=node.use_odometry)
        node._accepted_stamp = None
        robot.revolutions(1, topics=("odom",))
        harness.take()
        problems, original = [], None
        if target == "parameter":
            original = change_parameter(harness, what, value, problems)
            robot.revolutions(CASE)
        else:
            make = makers[target][1]
            robot.revolutions(CASE, {target: mutate(make, what, value, element)})
        outputs = harness.take()
        problems += output_problems(harness, outputs)
        accepted = [m for topic, m in outputs if topic.endswith("beams/pose") and m.accepted]
        tracking = [s for s in statuses(outputs) if s.status == LocalisationStatus.TRACKING]
        if not accepted:
            problems += [f"tracking without an accepted pose: {s.message}" for s in tracking[:1]]
        if original is not None:
            assert harness.set_parameter(what, original).successful
        robot.revolutions(AFTER)
        outputs = harness.take()
        problems += output_problems(harness, outputs)
        accepted = [m for topic, m in outputs if topic.endswith("beams/pose") and m.accepted]
        if not accepted or error_m(accepted[-1].pose.pose) > POSE_BOUND_M:
            problems.append(f"no true pose afterwards: {accepted[-1].pose.pose if accepted else 'nothing'}")
        harness.conclude(case, problems)

    _settings()(given(cases)(walked(check, explicit_cases)))()


# --- calibration_node ---------------------------------------------------------------------------------

# revolutions fed to a capture that still waits, at most (default_revolutions is 100)
MAX_FED = 120


def capture_revolution(now_s: float):
    return revolution(1, now_s)


def drive(harness: Harness, coroutine, feed) -> Any:
    """Run a service coroutine to its answer, calling `feed()` (one revolution) while it waits; a capture
    still waiting after MAX_FED revolutions times out as its timer would end it."""
    for _ in range(MAX_FED + 2):
        try:
            coroutine.send(None)
        except StopIteration as done:
            return done.value
        capture = harness.node._capture
        if capture is None or len(capture.revolutions) >= MAX_FED:
            if capture is not None and not capture.done.done():
                capture.done.set_result(False)
            continue
        feed()
    raise AssertionError("the service never answered")


def test_calibration_node_every_request_field_bearing_field_and_parameter(sim_time, tmp_path, monkeypatch):
    import rclpy.parameter

    from beams_calibration.calibration_node import CalibrationNode
    from beams_calibration.dataset import load_dataset
    from beams_calibration.parameters import CALIBRATION_PARAMETERS
    from beams_msgs.msg import BeaconBearingArray
    from beams_msgs.srv import Calibrate, CaptureReference, ListConfigurations

    dataset, output = tmp_path / "dataset.yaml", tmp_path / "calibration.yaml"
    monkeypatch.chdir(tmp_path)
    node = CalibrationNode()
    sim_time(node)
    node.set_parameters(
        [
            rclpy.parameter.Parameter("calibration_file_out", value=str(output)),
            rclpy.parameter.Parameter("leave_one_out", value=False),
        ]
    )
    node.dataset_file = dataset
    harness = Harness(node)
    good_capture = CaptureReference.Request(x=TRUE_POSE[0], y=TRUE_POSE[1], theta=TRUE_POSE[2], revolutions=5)
    requests = {
        "capture_reference": (
            CaptureReference.Request,
            lambda: CaptureReference.Request(**_fields(good_capture)),
        ),
        "calibrate": (Calibrate.Request, Calibrate.Request),
    }
    cases = st.one_of(
        *(message_cases(name, cls) for name, (cls, _) in requests.items()),
        message_cases("beams/bearings", BeaconBearingArray),
        st.sampled_from([("clear_dataset", None, None, None), ("list_configurations", None, None, None)]),
        parameter_cases(CALIBRATION_PARAMETERS),
    )
    explicit_cases = [c for name, (cls, _) in requests.items() for c in explicit(name, cls)]
    explicit_cases += explicit("beams/bearings", BeaconBearingArray)
    explicit_cases += [("clear_dataset", None, None, None), ("list_configurations", None, None, None)]
    explicit_cases += explicit_parameters(CALIBRATION_PARAMETERS)

    def feed(make=capture_revolution) -> None:
        harness.set_time(harness.now_s + REVOLUTION_S)
        harness.deliver("beams/bearings", make(harness.now_s))

    def capture(request, make=capture_revolution) -> tuple[Any, list[str]]:
        """A capture; its answer and why it broke the rule: success exactly when one configuration, the
        request's pose with finite bearings near the true ones, was appended, else the dataset unchanged."""
        before = dataset.read_bytes() if dataset.exists() else None
        count = len(load_dataset(dataset).configurations) if before is not None else 0
        answer = drive(harness, harness.call("capture_reference", request), partial(feed, make))
        after = dataset.read_bytes() if dataset.exists() else None
        if not answer.success:
            return answer, [] if after == before else [f"refused ({answer.message}), yet the dataset changed"]
        configurations = load_dataset(dataset).configurations
        problems = (
            [] if len(configurations) == count + 1 else [f"success, {len(configurations)} configurations"]
        )
        last = configurations[-1]
        if not np.allclose((last.x_m, last.y_m, last.theta_rad), (request.x, request.y, request.theta)):
            problems.append(
                f"success, but the configuration's pose is {(last.x_m, last.y_m, last.theta_rad)}"
            )
        truth = dict(true_bearings())
        for observation in last.observations:
            off = abs(math.remainder(observation.bearing_rad - truth[observation.beacon_id], math.tau))
            if not (math.isfinite(off) and off < 0.01 and math.isfinite(observation.window_rad)):
                problems.append(f"success, but beacon {observation.beacon_id}'s bearing is {off} rad off")
        return answer, problems

    def check(case) -> None:
        target, what, value, element = case
        for path in (dataset, output):
            path.unlink(missing_ok=True)
        harness.take()
        problems, original = [], None
        if target == "parameter":
            original = change_parameter(harness, what, value, problems)
        elif target == "capture_reference":
            _, problems = capture(fw.mutated(requests[target][1](), what, value, element))
        elif target == "beams/bearings":
            make = mutate(capture_revolution, what, value, element)
            _, problems = capture(CaptureReference.Request(**_fields(good_capture)), make)
        elif target == "calibrate":
            answer = drive(
                harness, harness.call("calibrate", fw.mutated(Calibrate.Request(), what, value)), feed
            )
            if answer.success or output.exists():
                problems.append(f"calibrated from no dataset: {answer.message}")
        elif target == "clear_dataset":
            capture(CaptureReference.Request(**_fields(good_capture)))
            answer = harness.call("clear_dataset", _trigger())
            if answer.success and load_dataset(dataset).configurations:
                problems.append(f"success, but the dataset still has configurations: {answer.message}")
        else:
            capture(CaptureReference.Request(**_fields(good_capture)))
            answer = harness.call("list_configurations", ListConfigurations.Request())
            if answer.configurations != 1 or len(answer.summaries) != 1:
                problems.append(f"one configuration listed as {answer.configurations}: {answer.summaries}")
        problems += output_problems(harness, harness.take())
        if original is not None:
            assert harness.set_parameter(what, original).successful
        for path in (dataset, output):
            path.unlink(missing_ok=True)
        answer, afterwards = capture(CaptureReference.Request(**_fields(good_capture)))
        if not answer.success:
            afterwards.append(f"no good capture afterwards: {answer.message}")
        problems += afterwards
        harness.conclude(case, problems)

    _settings()(given(cases)(walked(check, explicit_cases)))()


def _fields(message: Any) -> dict[str, Any]:
    return {name: getattr(message, name) for name in message.get_fields_and_field_types()}


def _trigger():
    from std_srvs.srv import Trigger

    return Trigger.Request()


# --- driver_node --------------------------------------------------------------------------------------


def ground_truth(now_s: float):
    from nav_msgs.msg import Odometry

    msg = planar_pose(Odometry(), now_s, 0.0)
    msg.child_frame_id = "base_link"
    return msg


def test_driver_node_every_input_field_service_field_and_parameter(sim_time):
    from lifecycle_msgs.msg import State, Transition
    from lifecycle_msgs.srv import ChangeState
    from nav_msgs.msg import Odometry

    from beams_common.intake.validation import MIN_BEARING_VARIANCE_RAD2
    from beams_driver.driver_node import DriverNode
    from beams_driver.parameters import DRIVER_PARAMETERS

    node = DriverNode()
    sim_time(node)
    harness = Harness(node)
    truth = dict(true_bearings())
    deactivate = (Transition.TRANSITION_DEACTIVATE, "deactivate")

    def state() -> int:
        return node._state_machine.current_state[0]

    def activate() -> None:
        """Back to active, from wherever a case left it (finalized: a new node; the fixture destroys both)."""
        nonlocal node
        if state() == State.PRIMARY_STATE_FINALIZED:
            node = harness.node = DriverNode()
            sim_time(node)
        if state() == State.PRIMARY_STATE_UNCONFIGURED:
            node.trigger_configure()
        if state() == State.PRIMARY_STATE_INACTIVE:
            node.trigger_activate()
        harness.capture()
        harness.set_time(harness.now_s)

    def run(revolutions: int, make=ground_truth) -> None:
        for _ in range(revolutions):
            for _ in range(ODOMETRY_PER_REVOLUTION):
                harness.set_time(harness.now_s + REVOLUTION_S / ODOMETRY_PER_REVOLUTION)
                harness.deliver("beams/sim/ground_truth", make(harness.now_s))
            harness.tick()

    def bearing_problems(outputs) -> list[str]:
        problems = []
        for message in (m for topic, m in outputs if topic.endswith("beams/bearings")):
            for b in message.bearings:
                if b.beacon_id not in truth or not (
                    math.isfinite(b.bearing)
                    and abs(b.bearing) <= math.pi
                    and b.variance >= MIN_BEARING_VARIANCE_RAD2
                ):
                    problems.append(f"bearing {b.beacon_id}: {b.bearing} rad, variance {b.variance}")
        return problems

    cases = st.one_of(
        message_cases("beams/sim/ground_truth", Odometry),
        message_cases("change_state", ChangeState.Request),
        parameter_cases(DRIVER_PARAMETERS),
    )
    explicit_cases = explicit("beams/sim/ground_truth", Odometry) + explicit(
        "change_state", ChangeState.Request
    )
    explicit_cases += explicit_parameters(DRIVER_PARAMETERS)

    def check(case) -> None:
        target, what, value, element = case
        activate()
        run(2)
        harness.take()
        problems, original = [], None
        if target == "parameter":
            original = change_parameter(harness, what, value, problems)
            run(CASE)
        elif target == "change_state":
            request = ChangeState.Request(transition=Transition(id=deactivate[0], label=deactivate[1]))
            before = state()
            answer = harness.call("change_state", fw.mutated(request, what, value, element))
            if answer.success != (state() != before):
                problems.append(f"success {answer.success}, state {before} -> {state()}")
            run(CASE)
        else:
            run(CASE, mutate(ground_truth, what, value, element))
        outputs = harness.take()
        problems += output_problems(harness, outputs) + bearing_problems(outputs)
        if original is not None:
            assert harness.set_parameter(what, original).successful
        activate()
        run(AFTER)
        outputs = harness.take()
        problems += output_problems(harness, outputs) + bearing_problems(outputs)
        bearings = [m for topic, m in outputs if topic.endswith("beams/bearings") and m.bearings]
        last = {b.beacon_id: b.bearing for b in bearings[-1].bearings} if bearings else {}
        if set(last) != set(truth) or any(
            abs(math.remainder(last[i] - truth[i], math.tau)) > 0.01 for i in last
        ):
            problems.append(f"no true bearings afterwards: {last}")
        harness.conclude(case, problems)

    _settings()(given(cases)(walked(check, explicit_cases)))()
