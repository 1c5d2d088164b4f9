"""fault_relay_node: sits between the robot's publishers and its filters and makes their data wrong on
request, well-formed all the same (the fault campaign; its remappings and parameters: docs/fault_campaign.md).
The ground truth passes unchanged (the simulated sensor reads it)."""

import collections
import math
import sys

from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from beams_common.interfaces import topics
from beams_common.ros.messages import seconds_to_stamp, stamp_to_seconds
from beams_common.ros.node_support import BEARINGS_QOS, run_node
from beams_msgs.msg import BeaconBearing, BeaconBearingArray

RAW_SUFFIX = "_raw"
FAULT_PARAMETERS = ("odometry_offset_x_m", "odometry_delay_s", "bearing_stamp_offset_s")
QUEUE_DEPTH = 10
RELEASE_PERIOD_S = 0.005


class FaultRelayNode(Node):
    """Republishes odometry, bearings and the ground truth with the requested faults."""

    def __init__(self) -> None:
        super().__init__("fault_relay_node")
        self.faults = {name: 0.0 for name in FAULT_PARAMETERS}
        for name in FAULT_PARAMETERS:
            self.declare_parameter(name, 0.0)
        # another team's beacon (an id not on the map) seen once per revolution; 0: none
        self.unknown_beacon_id = self.declare_parameter("unknown_beacon_id", 0).value
        self.add_on_set_parameters_callback(self._on_parameters)
        self._held: collections.deque[tuple[float, Odometry]] = collections.deque()
        self.odometry_publisher = self.create_publisher(Odometry, topics.ODOMETRY, QUEUE_DEPTH)
        self.bearings_publisher = self.create_publisher(BeaconBearingArray, topics.BEARINGS, BEARINGS_QOS)
        self.truth_publisher = self.create_publisher(Odometry, topics.GROUND_TRUTH, QUEUE_DEPTH)
        self.create_subscription(
            Odometry, topics.ODOMETRY + RAW_SUFFIX, self._on_odometry, qos_profile_sensor_data
        )
        self.create_subscription(
            BeaconBearingArray, topics.BEARINGS + RAW_SUFFIX, self._on_bearings, BEARINGS_QOS
        )
        self.create_subscription(
            Odometry, topics.GROUND_TRUTH + RAW_SUFFIX, self.truth_publisher.publish, QUEUE_DEPTH
        )
        self.create_timer(RELEASE_PERIOD_S, self._release)
        self.get_logger().info("fault_relay_node ready")

    def _on_parameters(self, parameters) -> SetParametersResult:
        faults = [p for p in parameters if p.name in self.faults]
        wrong = [p.name for p in faults if not isinstance(p.value, float) or not math.isfinite(p.value)]
        if wrong:
            return SetParametersResult(successful=False, reason=f"{wrong}: a finite float, please")
        for parameter in (p for p in parameters if p.name == "unknown_beacon_id"):
            if not isinstance(parameter.value, int) or not 0 <= parameter.value <= 65535:
                return SetParametersResult(
                    successful=False, reason="unknown_beacon_id: an id 0-65535 (uint16), please"
                )
            self.unknown_beacon_id = parameter.value
        for parameter in faults:
            self.faults[parameter.name] = parameter.value
            self.get_logger().info(f"{parameter.name} = {parameter.value}")
        return SetParametersResult(successful=True)

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_odometry(self, msg: Odometry) -> None:
        msg.pose.pose.position.x += self.faults["odometry_offset_x_m"]
        self._held.append((self._now_s() + self.faults["odometry_delay_s"], msg))
        self._release()

    def _release(self) -> None:
        now_s = self._now_s()
        while self._held and self._held[0][0] <= now_s:
            self.odometry_publisher.publish(self._held.popleft()[1])

    def _on_bearings(self, msg: BeaconBearingArray) -> None:
        offset_s = self.faults["bearing_stamp_offset_s"]
        if offset_s:
            msg.header.stamp = seconds_to_stamp(stamp_to_seconds(msg.header.stamp) + offset_s)
            for bearing in msg.bearings:
                bearing.header.stamp = seconds_to_stamp(stamp_to_seconds(bearing.header.stamp) + offset_s)
        if self.unknown_beacon_id and msg.bearings:
            stranger = BeaconBearing(
                beacon_id=self.unknown_beacon_id, bearing=0.5, variance=msg.bearings[0].variance
            )
            stranger.header.stamp = msg.bearings[-1].header.stamp
            msg.bearings.append(stranger)
        self.bearings_publisher.publish(msg)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(FaultRelayNode, args))


if __name__ == "__main__":
    main()
