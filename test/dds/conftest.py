"""Fixtures shared by the DDS tests of this folder (the graph and node fixtures: test/conftest.py)."""

import contextlib
import math
import os
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import AbstractContextManager

import pytest

from beams_sim.sensor_sim import SensorSimConfig


@contextlib.contextmanager
def _streaming_pty(chunks: Iterable[bytes]) -> Iterator[str]:
    """A pty whose device writes one chunk per turret period from a thread until the test ends; yields
    the device's path (the driver's `device` parameter)."""
    master, slave = os.openpty()
    os.set_blocking(master, False)  # nobody reading must not hang the writer
    stop = threading.Event()
    period_s = SensorSimConfig().period_s

    def run() -> None:
        for chunk in chunks:
            if stop.is_set():
                return
            with contextlib.suppress(BlockingIOError):
                os.write(master, chunk)
            stop.wait(period_s)

    writer = threading.Thread(target=run, daemon=True)
    writer.start()
    try:
        yield os.ttyname(slave)
    finally:
        stop.set()
        writer.join(timeout=10)
        os.close(master)
        os.close(slave)


@pytest.fixture
def streaming_pty() -> Callable[[Iterable[bytes]], AbstractContextManager[str]]:
    """`with streaming_pty(chunks) as device:` a simulated serial sensor writing one chunk per turret
    period (the serial driver tests' device)."""
    return _streaming_pty


def _total_pose_message(stamp_s: float, pose: tuple[float, float, float], frame_id: str = "map"):
    """An accepted ToTal pose (beams_msgs/TriangulatedPose on beams/pose) of `pose` (x, y, yaw), stamped
    stamp_s, with a covariance of 1 cm and 1 deg standard deviations."""
    from beams_common.ros.messages import seconds_to_stamp
    from beams_msgs.msg import TriangulatedPose

    msg = TriangulatedPose(accepted=True, beacon_ids=[1, 2, 3])
    msg.header.stamp = seconds_to_stamp(stamp_s)
    msg.header.frame_id = frame_id
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(pose[0]), float(pose[1])
    msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(pose[2] / 2), math.cos(pose[2] / 2)
    covariance = [0.0] * 36
    covariance[0] = covariance[7] = 1e-4
    covariance[35] = 3e-4
    msg.pose.covariance = covariance
    return msg


@pytest.fixture
def total_pose_message() -> Callable[..., object]:
    """`total_pose_message(stamp_s, (x, y, yaw), frame_id="map")`: an accepted ToTal pose message."""
    return _total_pose_message
