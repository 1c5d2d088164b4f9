"""Messages the replay writes (poses, estimates) and bags written from the offline simulator, for the
tests and the benches."""

from __future__ import annotations

import math
import pathlib
from collections.abc import Iterable
from typing import Any

import numpy as np

from beams_common.geometry.pose2d import Pose2D
from beams_common.interfaces import topics
from beams_common.interfaces.bearing_messages import BearingFields, bearing_array_message
from beams_common.ros.messages import ros_covariance
from beams_ekf.localiser import Estimate
from beams_tools.bag_events import (
    BEARINGS_TOPIC,
    BEARINGS_TYPE,
    NODES_QOS,
    NS_PER_S,
    ODOMETRY_TOPIC,
    ODOMETRY_TYPE,
    POSE_COV_TYPE,
    POSE_TYPE,
    TRUTH_TOPIC,
)
from beams_tools.bag_io import BagRecorder, fully_qualified
from beams_triangulation.gating import PoseEstimate


# -- output messages ------------------------------------------------------------------------------------
class MessageBuilder:
    """rosbags message objects: the replay's outputs, and inputs made from the offline simulator."""

    def __init__(self, typestore: Any) -> None:
        self.types = typestore.types

    def header(self, stamp: int, frame_id: str) -> Any:
        time_type = self.types["builtin_interfaces/msg/Time"]
        return self.types["std_msgs/msg/Header"](
            stamp=time_type(sec=stamp // NS_PER_S, nanosec=stamp % NS_PER_S), frame_id=frame_id
        )

    def pose_with_covariance(self, pose: Pose2D, covariance_6x6: np.ndarray) -> Any:
        t = self.types
        geometry = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](
                x=0.0, y=0.0, z=math.sin(0.5 * pose[2]), w=math.cos(0.5 * pose[2])
            ),
        )
        return t["geometry_msgs/msg/PoseWithCovariance"](
            pose=geometry, covariance=covariance_6x6.ravel().astype(float)
        )

    def odometry(
        self, stamp: int, frame_id: str, pose: Pose2D, speed_mps: float, yaw_rate_radps: float
    ) -> Any:
        """nav_msgs/Odometry (to base_link) with a planar pose and twist, covariances zero."""
        t = self.types
        linear = t["geometry_msgs/msg/Vector3"](x=float(speed_mps), y=0.0, z=0.0)
        angular = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=float(yaw_rate_radps))
        twist = t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=linear, angular=angular), covariance=np.zeros(36)
        )
        return t[ODOMETRY_TYPE](
            header=self.header(stamp, frame_id),
            child_frame_id="base_link",
            pose=self.pose_with_covariance(pose, np.zeros((6, 6))),
            twist=twist,
        )

    def bearing_array(
        self,
        start: int,
        period_s: float,
        bearings: Iterable[tuple[int, int, float, float] | tuple[int, int, float, float, float]],
        revolution: int,
        frame_id: str = "beams_sensor",
        calibrated: bool = True,
    ) -> Any:
        """beams_msgs/BeaconBearingArray from (stamp ns, beacon id, bearing rad, variance rad^2) tuples,
        optionally followed by the angular window (rad; 0 without it); `calibrated`: the driver's flag
        (true: no power bias to model, as for the simulator's default unbiased receiver)."""
        fields = [
            BearingFields(
                stamp, beacon, angle, variance, angular_window_rad=window[0] if window else 0.0, codes_seen=1
            )
            for stamp, beacon, angle, variance, *window in bearings
        ]
        return bearing_array_message(
            self.types,
            start,
            fields,
            period_s=period_s,
            revolution=revolution,
            frame_id=frame_id,
            calibrated=calibrated,
        )

    def triangulated_pose(self, estimate: PoseEstimate, stamp: int, frame_id: str) -> Any:
        full = np.asarray(ros_covariance(estimate.covariance))
        return self.types[POSE_TYPE](
            header=self.header(stamp, frame_id),
            pose=self.pose_with_covariance((estimate.x, estimate.y, estimate.heading), full),
            inverse_abs_d=float(estimate.inverse_abs_d),
            beacon_ids=np.array(estimate.beacon_ids, dtype=np.uint16),
            accepted=bool(estimate.accepted),
            reason=estimate.reason,
        )

    def ekf_odometry(self, estimate: Estimate, stamp: int, odometry: Any, frame_id: str) -> Any:
        full = np.asarray(ros_covariance(estimate.covariance))
        return self.types[ODOMETRY_TYPE](
            header=self.header(stamp, frame_id),
            child_frame_id=odometry.child_frame_id or "base_link",
            pose=self.pose_with_covariance(estimate.pose, full),
            twist=odometry.twist,
        )

    def stamped(self, header: Any, pose: Any) -> Any:
        return self.types[POSE_COV_TYPE](header=header, pose=pose)


# -- bags from the offline simulator --------------------------------------------------------------------
# (when the live system would publish it (ns), topic, ROS type, rosbags message or raw CDR bytes)
BagMessage = tuple[int, str, str, Any]


def simulated_messages(match: Any, typestore: Any, epoch_ns: int = 0) -> list[BagMessage]:
    """The input topics of a `beams_sim.simulated_match.SimulatedMatch`, stamped epoch_ns + match time:
    truth and odometry at their stamps, each revolution when it ends (as driver_node publishes it).
    Topics are fully qualified ("/odom"), as `ros2 bag record` names them."""
    build = MessageBuilder(typestore)
    g, o = match.ground_truth, match.odometry
    messages: list[BagMessage] = []
    for k, t in enumerate(o.stamp_s):
        stamp = epoch_ns + round(t * 1e9)
        truth = (g.x_m[k], g.y_m[k], g.theta_rad[k])
        messages.append(
            (
                stamp,
                fully_qualified(TRUTH_TOPIC),
                ODOMETRY_TYPE,
                build.odometry(stamp, "map", truth, g.speed_mps[k], g.yaw_rate_radps[k]),
            )
        )
        messages.append(
            (
                stamp,
                fully_qualified(ODOMETRY_TOPIC),
                ODOMETRY_TYPE,
                build.odometry(stamp, topics.ODOMETRY, o.pose(k), o.speed_mps[k], o.yaw_rate_radps[k]),
            )
        )
    for r in match.revolutions:
        start = epoch_ns + round(r.start_time_s * 1e9)
        bearings = [
            (epoch_ns + round(b.stamp_s * 1e9), b.beacon_id, b.bearing, b.variance, b.angular_window)
            for b in r.bearings
        ]
        messages.append(
            (
                start + round(r.period_s * 1e9),
                fully_qualified(BEARINGS_TOPIC),
                BEARINGS_TYPE,
                build.bearing_array(start, r.period_s, bearings, r.revolution),
            )
        )
    return messages


def write_bag(
    path: pathlib.Path,
    messages: Iterable[BagMessage],
    typestore: Any,
    *,
    storage: str = "mcap",
    passes: int = 1,
    pass_period_ns: int = 0,
    jitter_s: float = 0.0,
    seed: int = 0,
) -> pathlib.Path:
    """A bag of the messages, recorded when published plus a random delivery delay in [0, jitter_s) (so
    that bag order is not stamp order); passes > 1 records them again pass_period_ns later each time
    with the same stamps (a bag played in a loop). Topic names are written as given; each topic
    carries the nodes' offered QoS profile (NODES_QOS)."""
    rng = np.random.default_rng(seed)
    records = []
    for n in range(passes):
        for published, topic, msgtype, message in messages:
            raw = message if isinstance(message, bytes) else typestore.serialize_cdr(message, msgtype)
            arrival = published + n * pass_period_ns + round(jitter_s * rng.random() * 1e9)
            records.append((arrival, topic, msgtype, raw))
    records.sort(key=lambda record: record[0])
    with BagRecorder(pathlib.Path(path), typestore, storage) as recorder:
        for arrival, topic, msgtype, raw in records:
            recorder.write(topic, msgtype, arrival, raw, [NODES_QOS])
    return pathlib.Path(path)
