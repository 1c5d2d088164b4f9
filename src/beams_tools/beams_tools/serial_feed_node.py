"""`python -m beams_tools.serial_feed_node LINK`: the simulated serial sensor (`serial_feed`) alone in its
process, following the true pose of sim_world_node's robot (bench/bench_system.py's turret)."""

import contextlib
import pathlib
import sys
import threading

import rclpy
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException

from beams_common.interfaces import topics
from beams_common.ros.messages import pose2d_of, stamp_to_seconds
from beams_sim.occlusion import truth_buffer
from beams_tools.serial_feed import SerialFeed


def main(link: str) -> None:
    """The feed behind `link` until SIGINT."""
    truth, lock = truth_buffer(), threading.Lock()

    def on_truth(msg: Odometry) -> None:
        with lock:
            twist = (msg.twist.twist.linear.x, msg.twist.twist.angular.z)
            truth.add(stamp_to_seconds(msg.header.stamp), pose2d_of(msg.pose.pose), twist)

    def pose_at(host_s: float) -> tuple[float, float, float] | None:
        with lock:
            return truth.pose_at(host_s)

    rclpy.init()
    node = rclpy.create_node("serial_feed")
    node.create_subscription(Odometry, topics.GROUND_TRUTH, on_truth, 50)
    feed = SerialFeed(pathlib.Path(link), pose_at, seed=1)
    with contextlib.suppress(KeyboardInterrupt, ExternalShutdownException):
        rclpy.spin(node)
    feed.close()


if __name__ == "__main__":
    main(sys.argv[1])
