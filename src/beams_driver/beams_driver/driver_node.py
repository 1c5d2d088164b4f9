"""driver_node: BeAMS bearings, once per turret revolution, from an edge source (simulated, serial, ...).

Publishes `beams/bearings` (beams_msgs/BeaconBearingArray, reliable) and `/diagnostics`. The edge source
is chosen by the `source` parameter (edge_source.py): the simulated sensor (the default) follows the
robot's true pose on `beams/sim/ground_truth` (or a static pose) edge by edge; the serial source reads the
sensor microcontroller's edge captures. Every source goes through the same decoder and variance model;
the calibration file's bearing corrections (power bias, rotation bias; thesis ch. 7) are applied to the
published bearings.
"""

import sys

from nav_msgs.msg import Odometry
from rclpy.node import Node

from beams_common import topics
from beams_common.angles import wrap_to_pi
from beams_common.bearing_correction import BearingCorrection
from beams_common.calibration_file import SensorCalibration, load_calibration
from beams_common.parameters import ParameterTable
from beams_common.ros.messages import pose2d_of, seconds_to_stamp, stamp_to_seconds
from beams_common.ros.node_support import BEARINGS_QOS, Diagnostics, run_node, serve_calibration_reload
from beams_common.ros.parameters import ParameterValidationError, apply_runtime_changes, declare_table
from beams_driver.decoder import BearingDecoder, DecodedRevolution
from beams_driver.edge_source import EdgeSource, PoseCallback, source_kind
from beams_driver.parameters import DRIVER_PARAMETERS, codes_of, variance_model_of
from beams_msgs.msg import BeaconBearing, BeaconBearingArray

# Sources that deliver revolutions as they arrive: the host buffers this many pose messages per topic.
POSE_QUEUE_DEPTH = 50


class RosSourceHost:
    """What an edge source may ask of driver_node (edge_source.SourceHost), done with ROS."""

    def __init__(self, node: Node) -> None:
        self._node = node

    def subscribe_poses(self, topic: str, callback: PoseCallback) -> None:
        def on_message(msg: Odometry) -> None:
            twist = (msg.twist.twist.linear.x, msg.twist.twist.angular.z)
            callback(stamp_to_seconds(msg.header.stamp), pose2d_of(msg.pose.pose), twist)

        self._node.create_subscription(Odometry, topic, on_message, POSE_QUEUE_DEPTH)

    def resolve_topic(self, topic: str) -> str:
        return self._node.resolve_topic_name(topic)

    def log_info(self, message: str) -> None:
        self._node.get_logger().info(message)

    def log_warning(self, message: str) -> None:
        self._node.get_logger().warning(message)

    def now_s(self) -> float:
        return self._node.get_clock().now().nanoseconds * 1e-9


class DriverNode(Node):
    def __init__(self) -> None:
        super().__init__("driver_node")
        self.diagnostics = Diagnostics(self, "driver")
        self.parameters = declare_table(self, DRIVER_PARAMETERS)
        try:
            kind = source_kind(self.parameters["source"])
        except ValueError as error:
            raise ParameterValidationError(str(error)) from None
        source_parameters = declare_table(self, ParameterTable("driver_node", kind.parameters, kind.together))
        self.codes = codes_of(self.parameters)
        # the receiver the edges come through (the simulated one, or the thesis hardware's): the decoder's
        # window correction and the variance model know its minimum burst
        self.receiver = kind.receiver(source_parameters, self.codes)
        self.decoder = BearingDecoder(
            self.codes,
            variance_model_of(self.parameters, self.codes, self.receiver),
            min_codes_seen=self.parameters["min_complete_codes"],
            receiver=self.receiver.receiver,
        )
        self.frame_id = self.parameters["frame_id"]
        self.correction = self._correction_of(self.parameters["calibration_file"])
        serve_calibration_reload(self, self._apply_calibration)
        apply_runtime_changes(self, DRIVER_PARAMETERS, self.parameters, self._apply_parameters)
        self.publisher = self.create_publisher(BeaconBearingArray, topics.BEARINGS, BEARINGS_QOS)
        self.host = RosSourceHost(self)
        try:
            self.source: EdgeSource = kind.create(source_parameters, self.codes, self.host)
        except (ValueError, OSError) as error:
            raise ParameterValidationError(f"source {kind.name}: {error}") from None
        self.create_timer(kind.poll_period_s, self._poll)
        self.get_logger().info(
            f"{kind.name} source, codes {[str(c) for c in self.codes]}, variance mode "
            f"{self.decoder.variance_model.mode}, publishing {self.resolve_topic_name('beams/bearings')}"
        )

    def destroy_node(self) -> None:
        # the source is released on every stop, so a restarted driver (or a terminal program) can open
        # the serial port
        source = getattr(self, "source", None)
        if source is not None:
            source.close()
        super().destroy_node()

    # ---- parameters ----

    @staticmethod
    def _correction_of(path: str) -> BearingCorrection:
        """The calibration file's bearing corrections (none without a file); a file that cannot be read
        stops the node at start-up."""
        if not path:
            return BearingCorrection()
        try:
            return load_calibration(path).bearing_correction
        except (OSError, ValueError) as error:
            raise ParameterValidationError(f"calibration_file: {error}") from None

    def _apply_parameters(self, values: dict, changed: set[str]) -> None:
        """A runtime change (validated by the table): the variance model, the frame, the calibration."""
        if "calibration_file" in changed:
            path = values["calibration_file"]
            self.correction = load_calibration(path).bearing_correction if path else BearingCorrection()
        self.decoder.variance_model = variance_model_of(values, self.codes, self.receiver)
        self.decoder.min_codes_seen = values["min_complete_codes"]
        self.frame_id = values["frame_id"]

    def _apply_calibration(self, calibration: SensorCalibration) -> str:
        self.correction = calibration.bearing_correction
        return "power and rotation bias corrections replaced"

    # ---- the source ----

    def _poll(self) -> None:
        poll = self.source.poll(self.host.now_s())
        if poll.continuity_broken:
            self.decoder.reset()  # no window is joined across a gap in the stream
        for edges in poll.revolutions:
            self._publish(self.decoder.decode(edges))
        health = self.source.health()
        for key, value in health.values.items():
            self.diagnostics.set(key, value)
        if health.level != "ok" or health.message:
            self.diagnostics.set_level(health.level, health.message or health.level)

    # ---- publishing ----

    def _publish(self, decoded: DecodedRevolution) -> None:
        msg = BeaconBearingArray()
        msg.header.stamp = seconds_to_stamp(decoded.start_time_s)
        msg.header.frame_id = self.frame_id
        msg.revolution = decoded.revolution % 2**32
        msg.period = decoded.period_s
        msg.bearings = [self._bearing_message(b) for b in decoded.bearings]
        msg.rejected_windows = min(len(decoded.rejections), 2**16 - 1)
        self.publisher.publish(msg)
        self.diagnostics.increment("revolutions")
        self.diagnostics.increment("bearings", len(msg.bearings))
        for rejection in decoded.rejections:
            self.diagnostics.increment(f"rejected_{rejection.kind}")
        self.diagnostics.set_level("ok", f"{len(msg.bearings)} bearings in the last revolution")

    def _bearing_message(self, decoded) -> BeaconBearing:
        msg = BeaconBearing()
        msg.header.stamp = seconds_to_stamp(decoded.stamp_s)
        msg.header.frame_id = self.frame_id
        msg.beacon_id = decoded.beacon_id
        msg.bearing = float(wrap_to_pi(self.correction.correct(decoded.bearing, decoded.angular_window)))
        msg.variance = float(decoded.variance)
        msg.angular_window = float(decoded.angular_window)
        msg.rising_angle = float(decoded.rising_angle)
        msg.falling_angle = float(decoded.falling_angle)
        msg.codes_seen = decoded.codes_seen
        return msg


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(DriverNode, args))


if __name__ == "__main__":
    main()
