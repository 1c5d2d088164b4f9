"""virtual_turret: the turret firmware in simavr in real time on a pty (docs/firmware.md), for
`driver_node source:=serial device:=<its path or --link>`. Its pins follow sim_world_node's robot: the
trajectory from sim_world_node's parameters, the match clock from the ground truth, the simulator's
revolutions written LEAD_S ahead. Exit 1 without `make hil`'s harness and image, 2 once the ground truth
leaves the trajectory (the match started over), 0 on Ctrl-C or SIGTERM.
"""

import argparse
import contextlib
import os
import pathlib
import signal
import subprocess
import sys
import time
import tty

import rclpy
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.interfaces import topics
from beams_common.ros.messages import pose2d_of, stamp_to_seconds
from beams_sim import virtual_turret as turret
from beams_sim.parameters import SIM_WORLD_PARAMETERS
from beams_sim.world import trajectory_of

LEAD_S = 1.0  # the schedule is written this far ahead of the emulation
START_DELAY_S = 0.5  # from the harness's start to its cycle 0 (the first chunk is written meanwhile)
TRUTH_OFF_PATH_M = 0.01  # a ground-truth pose this far from the trajectory is another match's


def run(node: Node, options: argparse.Namespace, master: int) -> int:
    """Emulate until the harness ends (its status), an interrupt, or a ground truth off the trajectory (2)."""
    world = AsyncParameterClient(node, "sim_world_node")  # of this namespace
    node.get_logger().info("waiting for sim_world_node")
    world.wait_for_services()
    future = world.get_parameters(list(SIM_WORLD_PARAMETERS.names))
    rclpy.spin_until_future_complete(node, future)
    values = map(parameter_value_to_python, future.result().values)
    trajectory = trajectory_of(dict(zip(SIM_WORLD_PARAMETERS.names, values, strict=True)))
    clock = turret.MatchClock(trajectory)
    node.create_subscription(
        Odometry,
        topics.GROUND_TRUTH,
        lambda m: clock.on_truth(stamp_to_seconds(m.header.stamp), pose2d_of(m.pose.pose)),
        10,
    )
    while clock.origin_s is None:
        rclpy.spin_once(node, timeout_sec=0.1)
    start_at_s = time.time() + START_DELAY_S
    zero_s = start_at_s + turret.START_CYCLE / turret.CPU_HZ  # the system time of turret time 0
    pins = turret.TurretPins(
        lambda t: trajectory.pose_at(zero_s + t - clock.origin_s), EUROBOT_BEACON_MAP, options.seed
    )
    flags = ("--out-fd", master, "--realtime", "--start-at", f"{start_at_s:.6f}")
    command = turret.harness_command("-", 0, *flags, firmware=options.firmware)
    harness = subprocess.Popen(command, stdin=subprocess.PIPE, pass_fds=(master,))
    node.get_logger().info(f"cycle 0 at {start_at_s:.6f} s, match time {start_at_s - clock.origin_s:.6f} s")
    try:
        while harness.poll() is None and clock.off_m <= TRUTH_OFF_PATH_M:
            with contextlib.suppress(BrokenPipeError):
                harness.stdin.write(pins.until(time.time() - zero_s + LEAD_S))
                harness.stdin.flush()
            rclpy.spin_once(node, timeout_sec=turret.PERIOD_S)
    finally:
        with contextlib.suppress(BrokenPipeError):
            harness.stdin.close()  # the schedule's end: the harness stops
        harness.wait()
    if clock.off_m > TRUTH_OFF_PATH_M:
        node.get_logger().error(f"the ground truth is {clock.off_m:.3f} m off the trajectory: a new match?")
        return 2
    return 0 if harness.returncode == -signal.SIGINT else harness.returncode  # a terminal's Ctrl-C


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(prog="virtual_turret", description=__doc__.split("\n")[0])
    parser.add_argument("--link", type=pathlib.Path, help="a symbolic link to the pty, made and removed")
    parser.add_argument("--seed", type=int, default=1, help="seed of the simulated sensor's noise")
    parser.add_argument("--firmware", type=pathlib.Path, default=turret.FIRMWARE, help="turret.elf")
    options = parser.parse_args(remove_ros_args(argv)[1:])
    why = turret.missing(options.firmware)
    if options.link and options.link.exists() and not options.link.is_symlink():
        why = f"{options.link} exists and is not a link"  # a real device's path, say
    if why:
        sys.exit(f"virtual_turret: {why}")  # exit status 1
    master, slave = os.openpty()
    tty.setraw(slave)  # binary frames; the slave stays open so that the line never hangs up
    os.set_blocking(master, False)  # a line nobody reads loses the bytes, as a UART's does
    if options.link:
        options.link.unlink(missing_ok=True)
        options.link.symlink_to(os.ttyname(slave))
    print(f"virtual_turret: the turret's serial line is {os.ttyname(slave)} {options.link or ''}", flush=True)
    for stop in (signal.SIGINT, signal.SIGTERM):  # SIGINT too: a shell's background job ignores it
        signal.signal(stop, signal.default_int_handler)  # KeyboardInterrupt
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = Node("virtual_turret")
    status = 0
    try:
        status = run(node, options, master)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        os.close(master)
        os.close(slave)
        if options.link:
            options.link.unlink(missing_ok=True)
    sys.exit(status)
