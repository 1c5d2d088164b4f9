"""Fast DDS after a kill -9 (restart recovery): why the discovery profile puts user data on UDP.

A plain subscriber of a 50 Hz nav_msgs/Odometry publisher is killed with SIGKILL after its first message
and started again, RESTARTS times, timing creation to first message, with the project's profile
(src/beams_bringup/config/fastdds_fast_discovery.xml: UDP) and without its unicast locator (shared memory).
No BeAMS node takes part. In ROS_DOMAIN_ID 67 unless the environment sets one.
"""

import functools
import os
import pathlib
import re
import selectors
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np
from rows_table import Row, bench_main

ROOT = pathlib.Path(__file__).resolve().parents[1]
PROFILE = ROOT / "src" / "beams_bringup" / "config" / "fastdds_fast_discovery.xml"
# the profile's element that takes user data off shared memory
UDP_LOCATOR = re.compile(r"\s*<defaultUnicastLocatorList>.*?</defaultUnicastLocatorList>", re.DOTALL)
DEFAULT_DOMAIN_ID = "67"  # 61-69 are the developers' (test/conftest.py); the tests never use it
RESTARTS = 6
PUBLISHER_SETTLE_S = 1.5
PAUSE_AFTER_KILL_S = 0.3
FIRST_MESSAGE_TIMEOUT_S = 10.0

PUBLISHER = """
import time
import rclpy
from nav_msgs.msg import Odometry
from rclpy.qos import qos_profile_sensor_data
rclpy.init()
node = rclpy.create_node("restart_bench_publisher")
publisher = node.create_publisher(Odometry, "restart_bench", qos_profile_sensor_data)
while rclpy.ok():  # rclpy's SIGINT handler shuts the context down
    try:
        publisher.publish(Odometry())
    except Exception:  # the context shut down between the check and the publication
        break
    time.sleep(0.02)
"""

SUBSCRIBER = """
import time
import rclpy
from nav_msgs.msg import Odometry
from rclpy.qos import qos_profile_sensor_data
rclpy.init()
node = rclpy.create_node("restart_bench_subscriber")
created = time.monotonic()
first = []
node.create_subscription(Odometry, "restart_bench", lambda msg: first.append(time.monotonic()),
                         qos_profile_sensor_data)
while not first:
    rclpy.spin_once(node, timeout_sec=0.005)
print(f"{first[0] - created:.4f}", flush=True)
time.sleep(3600)  # until killed
"""


def shared_memory_profile(directory: pathlib.Path) -> pathlib.Path:
    """The project's profile without its UDP default unicast locator."""
    text = PROFILE.read_text()
    stripped, count = UDP_LOCATOR.subn("", text)
    if count != 1:
        raise RuntimeError(f"{PROFILE} has {count} <defaultUnicastLocatorList> elements, expected 1")
    path = directory / "shared_memory.xml"
    path.write_text(stripped)
    return path


def first_message_delay(subscriber: subprocess.Popen) -> float:
    """The subscriber's reported delay (s), or inf when nothing arrived in FIRST_MESSAGE_TIMEOUT_S."""
    with selectors.DefaultSelector() as selector:
        selector.register(subscriber.stdout, selectors.EVENT_READ)
        if not selector.select(FIRST_MESSAGE_TIMEOUT_S):
            return float("inf")
        line = subscriber.stdout.readline().strip()
    return float(line) if line else float("inf")


def kill(process: subprocess.Popen) -> None:
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=15)


def restart_delays(profile: pathlib.Path) -> list[float]:
    """Delays (s) to the first message of subscribers started right after the previous one's kill -9."""
    env = dict(
        os.environ,
        FASTRTPS_DEFAULT_PROFILES_FILE=str(profile),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID", DEFAULT_DOMAIN_ID),
    )
    spawn = functools.partial(subprocess.Popen, env=env, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    publisher = spawn([sys.executable, "-c", PUBLISHER], stdout=subprocess.DEVNULL)
    delays = []
    try:
        time.sleep(PUBLISHER_SETTLE_S)
        for restart in range(RESTARTS + 1):
            subscriber = spawn([sys.executable, "-c", SUBSCRIBER], stdout=subprocess.PIPE, text=True)
            delay = first_message_delay(subscriber)
            kill(subscriber)
            if restart:  # the first subscriber starts fresh: no killed process before it
                delays.append(delay)
            time.sleep(PAUSE_AFTER_KILL_S)
    finally:
        publisher.send_signal(signal.SIGINT)
        try:
            publisher.wait(timeout=15)
        except subprocess.TimeoutExpired:
            kill(publisher)
    return delays


def rows() -> list[Row]:
    with tempfile.TemporaryDirectory(prefix="beams-dds-restart-") as directory:
        profiles = {
            "shared memory": shared_memory_profile(pathlib.Path(directory)),
            "UDP (the project's profile)": PROFILE,
        }
        result = []
        for transport, profile in profiles.items():
            delays = restart_delays(profile)
            result += [
                (
                    f"plain subscriber restarted after kill -9, user data in {transport}: first message, "
                    f"{statistic} of {RESTARTS}",
                    value,
                    "s",
                    "recovery within 2 s",
                )
                for statistic, value in (("median", float(np.median(delays))), ("max", max(delays)))
            ]
    return result


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
