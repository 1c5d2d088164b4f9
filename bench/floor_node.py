"""What rclpy costs a robot node before any of its own work (`bench_system.py --floor`): a stand-in with
triangulation_node's or ekf_node's subscriptions (odometry raw, as the nodes read it), publications, timers
and executor, each callback doing nothing but what its publications need (a message built once, its stamp
set). The real node's CPU above the stand-in's is the node's own work.

Usage: python bench/floor_node.py triangulation|ekf PUBLISH_RATE_HZ --ros-args -r __node:=NAME
(PUBLISH_RATE_HZ: ekf_node's publish_rate_hz; bench_system passes its default, the stand-in stays light)
"""

import sys

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from tf2_msgs.msg import TFMessage

from beams_common.interfaces import topics
from beams_common.ros.input_watch import GRAPH_CHECK_PERIOD_S
from beams_common.ros.node_support import BEARINGS_QOS, TF_QOS, run_node
from beams_common.ros.status_topic import STATUS_QOS
from beams_msgs.msg import BeaconBearingArray, LocalisationStatus, TriangulatedPose


def stand_in(role: str, publish_rate_hz: float) -> Node:
    """The stand-in node of `role`, its publications and subscriptions made."""
    node = rclpy.create_node(f"{role}_node")
    diagnostics = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
    diagnostic = DiagnosticArray(status=[DiagnosticStatus(name=node.get_fully_qualified_name())])
    status_topic = topics.EKF_STATUS if role == "ekf" else topics.TRIANGULATION_STATUS
    status = node.create_publisher(LocalisationStatus, status_topic, STATUS_QOS)

    def every_second() -> None:
        diagnostic.header.stamp = node.get_clock().now().to_msg()
        diagnostics.publish(diagnostic)
        status.publish(LocalisationStatus())

    node.create_timer(1.0, every_second)
    node.create_timer(GRAPH_CHECK_PERIOD_S, lambda: node.count_publishers(topics.ODOMETRY))
    node.create_subscription(Odometry, topics.ODOMETRY, lambda _: None, qos_profile_sensor_data, raw=True)
    if role == "triangulation":
        pose = node.create_publisher(TriangulatedPose, topics.POSE, 10)
        pose_cov = node.create_publisher(PoseWithCovarianceStamped, topics.POSE_COV, 10)
        total, total_cov = TriangulatedPose(accepted=True), PoseWithCovarianceStamped()

        def on_bearings(msg: BeaconBearingArray) -> None:
            # stamped within its bearings, as ToTal's pose is (the bench matches a pose to its revolution so)
            total.header = total_cov.header = msg.bearings[-1].header if msg.bearings else msg.header
            pose.publish(total)
            pose_cov.publish(total_cov)

        node.create_subscription(BeaconBearingArray, topics.BEARINGS, on_bearings, BEARINGS_QOS)
    else:
        odometry_out = node.create_publisher(Odometry, topics.EKF_ODOMETRY, 10)
        pose_out = node.create_publisher(PoseWithCovarianceStamped, topics.EKF_POSE, 10)
        tf_out = node.create_publisher(TFMessage, topics.TF, TF_QOS)
        odometry, pose = Odometry(), PoseWithCovarianceStamped()
        tf = TFMessage(transforms=[TransformStamped()])

        def publish(with_tf: bool) -> None:  # a revolution refines an instant /tf already has
            odometry.header.stamp = pose.header.stamp = node.get_clock().now().to_msg()
            odometry_out.publish(odometry)
            pose_out.publish(pose)
            if with_tf:
                tf.transforms[0].header.stamp = odometry.header.stamp
                tf_out.publish(tf)

        timer = node.create_timer(1.0 / publish_rate_hz, lambda: publish(True))

        def on_bearings(_) -> None:  # as ekf_node: the timer's next estimate a period after this one
            publish(False)
            timer.reset()

        node.create_subscription(BeaconBearingArray, topics.BEARINGS, on_bearings, BEARINGS_QOS)
        node.create_subscription(TriangulatedPose, topics.POSE, lambda _: None, 10)
        node.create_subscription(PoseWithCovarianceStamped, topics.INITIAL_POSE, lambda _: None, 10)
    return node


if __name__ == "__main__":  # spun as the nodes are (run_node: their executor, their stop signals)
    sys.exit(run_node(lambda: stand_in(sys.argv[1], float(sys.argv[2])), [sys.argv[0], *sys.argv[3:]]))
