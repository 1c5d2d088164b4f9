"""The fault campaign's probe: its rclpy node records the simulator's truth (from the raw topic: only the
real simulator publishes there), the EKF's estimates and its status (beams/ekf/status), publishes the bad
messages and makes the service calls, parameter changes and lifecycle transitions, each answer awaited at most
CALL_TIMEOUT_S while it keeps recording."""

import collections
import math
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from nav_msgs.msg import Odometry
from rcl_interfaces.srv import GetParameters, SetParameters

from beams_common.interfaces import topics
from beams_common.interfaces.bearing_messages import BearingFields, nanoseconds
from beams_common.ros.messages import bearing_array, pose2d_of, seconds_to_stamp, stamp_to_seconds
from beams_msgs.msg import BeaconBearingArray, LocalisationStatus
from beams_tools.campaign_metrics import CallRecord
from beams_tools.campaign_processes import NODES

CALL_TIMEOUT_S = 5.0
# the serial feed extrapolates the truth at most this far (s) past its newest sample
MAX_EXTRAPOLATION_S = 0.2
# a second ekf_node's child frame: the same launch twice but for this, so the probe tells the two
# estimate streams apart (the real one's is judged; the user of beams/ekf/odometry receives both)
DUPLICATE_EKF_FRAME = "base_link_duplicate_ekf"
# a pose the ekf's operator services receive: the truth, with a covariance (m^2, rad^2) on the diagonal
OPERATOR_COVARIANCE = {"set_pose_huge_covariance": 1e12, "initialpose_huge_covariance": 1e300}


class Probe:
    """The campaign's rclpy node: records, publishes the bad messages, calls the services."""

    def __init__(self, domain_id: int) -> None:
        # rclpy loads the middleware: imported as the probe starts, after a campaign on two hosts has
        # entered the main host's namespace
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile

        from beams_common.ros.node_support import BEARINGS_QOS
        from beams_common.ros.status_topic import STATUS_QOS

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node("fault_campaign_probe", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.truth: list[tuple[float, float, float]] = []
        self.truth_orientation = None  # the newest true orientation (a quaternion message)
        # the recent true poses (t, x, y, theta), for the serial feed's thread
        self._recent_poses: collections.deque[tuple[float, ...]] = collections.deque(maxlen=200)
        self._recent_lock = threading.Lock()
        self.ekf: list[tuple[float, ...]] = []
        self.duplicate_estimates = 0  # received from a second ekf_node (duplicate_publisher/ekf)
        self.status: list[tuple[float, float, float]] = []  # (stamp, tracking, estimate stamp)
        self.status_messages: list[tuple[float, int, str]] = []  # (stamp, status code, message)
        node = self.node
        node.create_subscription(Odometry, topics.GROUND_TRUTH + "_raw", self._on_truth, 100)
        node.create_subscription(Odometry, topics.EKF_ODOMETRY, self._on_ekf, 100)
        # every report kept: the topic's depth of 1 would keep only the newest of a burst
        status_qos = QoSProfile(
            depth=100, reliability=STATUS_QOS.reliability, durability=STATUS_QOS.durability
        )
        node.create_subscription(LocalisationStatus, topics.EKF_STATUS, self._on_status, status_qos)
        # bearings and odom have one publisher by design (a second is said at ERROR, input_watch): the
        # probe's exist only while a bad-message fault uses them (open_publisher, close_publisher)
        self._publisher_kinds = {
            "bearings": (BeaconBearingArray, topics.BEARINGS, BEARINGS_QOS),
            "odom": (Odometry, topics.ODOMETRY, 10),
        }
        self._publisher_users: dict[str, int] = {}
        self.publishers = {
            "initialpose": node.create_publisher(PoseWithCovarianceStamped, topics.INITIAL_POSE, 10),
        }
        self._clients: dict[str, Any] = {}
        self.pending: list[list[Any]] = []  # [record, client, request, deadline, sent, future, judge]
        self.calls: list[CallRecord] = []

    def now_s(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def open_publisher(self, name: str) -> None:
        """The probe's publisher on a single-publisher topic for a fault's window (counted: they overlap)."""
        if name not in self._publisher_kinds:
            return
        self._publisher_users[name] = self._publisher_users.get(name, 0) + 1
        if name not in self.publishers:
            self.publishers[name] = self.node.create_publisher(*self._publisher_kinds[name])

    def close_publisher(self, name: str) -> None:
        if name not in self._publisher_kinds or name not in self.publishers:
            return
        self._publisher_users[name] -= 1
        if self._publisher_users[name] == 0:
            self.node.destroy_publisher(self.publishers.pop(name))

    def spin(self, timeout_s: float) -> None:
        self.executor.spin_once(timeout_sec=timeout_s)

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    # recording
    def _on_truth(self, msg) -> None:
        x, y, heading = pose2d_of(msg.pose.pose)
        row = (stamp_to_seconds(msg.header.stamp), x, y)
        if all(math.isfinite(v) for v in row):
            self.truth.append(row)
            self.truth_orientation = msg.pose.pose.orientation
            with self._recent_lock:
                self._recent_poses.append((*row, heading))

    def _on_ekf(self, msg) -> None:
        if msg.child_frame_id == DUPLICATE_EKF_FRAME:
            self.duplicate_estimates += 1
            return

        c = msg.pose.covariance
        p = msg.pose.pose.position
        self.ekf.append((stamp_to_seconds(msg.header.stamp), p.x, p.y, c[0], c[1], c[7]))

    def _on_status(self, msg) -> None:
        # what a consumer of beams/ekf/status reads: the misleading test judges what users rely on
        stamp_s = stamp_to_seconds(msg.header.stamp)
        tracking = 1.0 if msg.status == LocalisationStatus.TRACKING else 0.0
        self.status.append((stamp_s, tracking, stamp_to_seconds(msg.estimate_stamp)))
        self.status_messages.append((stamp_s, msg.status, msg.message))

    def pose_at(self, host_s: float) -> tuple[float, float, float] | None:
        """The true pose at a host time: interpolated among the recent poses, extrapolated past the newest
        one with its velocity (the serial feed writes a revolution as it ends, a few ms ahead of the truth
        that reached the probe); None before any."""
        with self._recent_lock:
            recent = np.array(self._recent_poses, dtype=float).reshape(-1, 4)
        if len(recent) < 2:
            return None
        recent[:, 3] = np.unwrap(recent[:, 3])
        if host_s > recent[-1, 0]:
            rate = (recent[-1, 1:] - recent[-2, 1:]) / max(recent[-1, 0] - recent[-2, 0], 1e-6)
            x, y, theta = recent[-1, 1:] + rate * min(host_s - recent[-1, 0], MAX_EXTRAPOLATION_S)
        else:
            x, y, theta = (float(np.interp(host_s, recent[:, 0], recent[:, k])) for k in (1, 2, 3))
        return float(x), float(y), float(theta)

    def truth_pose(self, stamp_s: float, variance: float, offset_x_m: float = 0.0, frame: str = "map"):
        """An operator's pose at the newest truth, moved offset_x_m along x, with the true heading."""
        x, y = self.truth[-1][1:3] if self.truth else (1.5, 1.0)
        msg = operator_pose(stamp_s, (x + offset_x_m, y), variance, frame)
        if self.truth_orientation is not None:
            msg.pose.pose.orientation = self.truth_orientation
        return msg

    # service calls, answered or not within CALL_TIMEOUT_S while the probe keeps spinning
    def call(
        self,
        fault: str,
        srv_type: Any,
        service: str,
        request: Any,
        expected: bool | None = None,
        judge: Callable[[Any], tuple[bool, str]] | None = None,
    ) -> None:
        client = self._clients.get(service)
        if client is None:
            client = self._clients[service] = self.node.create_client(srv_type, service)
        record = CallRecord(fault, service, expected_success=expected)
        self.calls.append(record)
        judge = judge or (lambda response: (bool(response.success), str(getattr(response, "message", ""))))
        self.pending.append(
            [record, client, request, self.now_s() + CALL_TIMEOUT_S, self.now_s(), None, judge]
        )

    def poll_calls(self) -> None:
        now_s = self.now_s()
        still = []
        for entry in self.pending:
            record, client, request, deadline_s, sent_s, future, judge = entry
            if future is None and client.service_is_ready():
                entry[5] = future = client.call_async(request)
            if future is not None and future.done():
                record.answered = True
                record.latency_s = now_s - sent_s
                try:
                    record.success, record.detail = judge(future.result())
                except Exception as error:  # a malformed answer is an answer; say what it was
                    record.detail = f"answer not understood: {error!r}"
                continue
            if now_s > deadline_s:
                record.detail = "no answer" if future is not None else "service not available"
                continue
            still.append(entry)
        self.pending = still

    def set_parameter(self, fault: str, node: str, name: str, value: Any, expected: bool | None) -> None:
        from rclpy.parameter import Parameter

        request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])

        def judge(response) -> tuple[bool, str]:
            result = response.results[0]
            return bool(result.successful), f"{name}={value!r}: {result.reason}"

        self.call(fault, SetParameters, f"/{NODES[node].executable}/set_parameters", request, expected, judge)

    def get_parameter(self, fault: str, node: str, name: str) -> None:
        def judge(response) -> tuple[bool, str]:
            return len(response.values) == 1 and response.values[0].type != 0, f"get {name}"

        request = GetParameters.Request(names=[name])
        self.call(fault, GetParameters, f"/{NODES[node].executable}/get_parameters", request, True, judge)

    def change_state(self, fault: str, transition_id: int, expected: bool) -> None:
        request = ChangeState.Request(transition=Transition(id=transition_id))
        self.call(
            fault,
            ChangeState,
            f"/{NODES['driver'].executable}/change_state",
            request,
            expected,
            lambda response: (bool(response.success), f"transition {transition_id}"),
        )


# the bad messages
def _revolution(stamp_s: float, bearings: list[tuple[int, float, float]]):
    """A revolution of (beacon, bearing, variance) stamped stamp_s, flagged uncalibrated."""
    stamp_ns = nanoseconds(stamp_s)
    fields = [BearingFields(stamp_ns, *bearing) for bearing in bearings]
    return bearing_array(stamp_ns, fields, period_s=0.1, calibrated=False)


def operator_pose(stamp_s: float, xy: tuple[float, float], variance: float, frame: str = "map"):
    msg = PoseWithCovarianceStamped()
    msg.header.stamp, msg.header.frame_id = seconds_to_stamp(stamp_s), frame
    msg.pose.pose.position.x, msg.pose.pose.position.y = xy
    msg.pose.pose.orientation.w = 1.0
    for k in (0, 7, 35):
        msg.pose.covariance[k] = variance
    return msg


def nan_pose(probe: Probe):
    return operator_pose(probe.now_s(), (math.nan, 1.0), 0.01)


def bad_message_topic(variant: str) -> str:
    """The probe's publisher a bad message goes through (bad_message's first element)."""
    if variant.startswith("initialpose"):
        return "initialpose"
    return "odom" if variant == "nan_odometry" else "bearings"


def bad_message(variant: str, probe: Probe) -> tuple[str, Any]:
    """(publisher, message) of one bad message, stamped now."""
    now_s = probe.now_s()
    if variant == "nan_bearings":
        return "bearings", _revolution(now_s, [(1, math.nan, 1e-6), (2, 0.5, math.nan), (3, 1.0, 1e-6)])
    if variant == "unknown_beacon":
        return "bearings", _revolution(now_s, [(1, 0.1, 1e-6), (2, 1.5, 1e-6), (9, 2.0, 1e-6)])
    if variant == "empty_revolution":
        return "bearings", _revolution(now_s, [])
    if variant == "oversized_revolution":
        return "bearings", _revolution(now_s, [(1, 0.01 * k, 1e-6) for k in range(65)])
    if variant == "nan_odometry":
        msg = Odometry(child_frame_id="base_link")
        msg.header.stamp, msg.header.frame_id = seconds_to_stamp(now_s), "odom"
        msg.pose.pose.position.x = msg.pose.pose.orientation.w = math.nan
        return "odom", msg
    if variant == "initialpose_huge_covariance":
        return "initialpose", probe.truth_pose(now_s, OPERATOR_COVARIANCE[variant])
    if variant == "initialpose_nan":
        return "initialpose", nan_pose(probe)
    raise ValueError(f"unknown bad message {variant!r}")
