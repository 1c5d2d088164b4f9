"""virtual_turret: the shipped turret firmware in simavr, in real time, on a pseudo-terminal.

    ros2 run beams_sim virtual_turret [--link PATH] [--seed N] [--harness PATH] [--firmware PATH]
        [--ros-args -p trajectory_seed:=3 ...]

It prints the pty's path (and links it at --link); `driver_node source:=serial device:=<that path>` then
reads the firmware's frames as from the board. The receiver's and the zero reference's pins follow the
robot of sim_world_node's match: the node declares sim_world_node's parameters (the same values give the
same trajectory), placed on the match's clock by ground-truth poses (match_time_of), and the
edge-level simulator's revolutions are written to the harness a second ahead of the emulation. Exit 2
when the harness or the image is missing (`make hil`) or the ground truth is another trajectory, 0 on
Ctrl-C or SIGTERM. docs/firmware.md.
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
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from beams_common import topics
from beams_common.beacon_map import EUROBOT_BEACON_MAP
from beams_common.ros.messages import pose2d_of, stamp_to_seconds
from beams_common.ros.parameters import declare_table
from beams_sim.parameters import SIM_WORLD_PARAMETERS, trajectory_of
from beams_sim.virtual_turret import (
    CPU_HZ,
    PERIOD_S,
    START_CYCLE,
    MatchClock,
    TurretPins,
    default_firmware,
    default_harness,
    harness_command,
    missing,
)

LEAD_S = 1.0  # the schedule is written this far ahead of the emulation
START_DELAY_S = 0.5  # from the harness's start to its cycle 0 (the first chunk is written meanwhile)
TRUTH_OFF_PATH_M = 0.01  # a ground-truth pose this far from the trajectory is another match's


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="virtual_turret", description=__doc__.split("\n")[0])
    parser.add_argument("--link", type=pathlib.Path, help="a symbolic link to the pty, made and removed")
    parser.add_argument("--seed", type=int, default=1, help="seed of the simulated sensor's noise")
    parser.add_argument("--harness", type=pathlib.Path, default=default_harness(), help="turret_hil")
    parser.add_argument("--firmware", type=pathlib.Path, default=default_firmware(), help="turret.elf")
    return parser.parse_args(argv)


def run(node: Node, options: argparse.Namespace, master: int) -> int:
    """Emulate until the harness ends (its status), an interrupt, or a ground truth off the trajectory
    (SystemExit 2)."""
    trajectory = trajectory_of(declare_table(node, SIM_WORLD_PARAMETERS))
    clock = MatchClock(trajectory)
    node.create_subscription(
        Odometry,
        topics.GROUND_TRUTH,
        lambda m: clock.on_truth(stamp_to_seconds(m.header.stamp), pose2d_of(m.pose.pose)),
        10,
    )
    node.get_logger().info(f"waiting for {node.resolve_topic_name(topics.GROUND_TRUTH)} (sim_world_node)")
    while clock.origin_s is None:
        rclpy.spin_once(node, timeout_sec=0.1)
    start_at_s = time.time() + START_DELAY_S
    zero_s = start_at_s + START_CYCLE / CPU_HZ  # the system time of turret time 0
    pins = TurretPins(
        lambda t: trajectory.pose_at(zero_s + t - clock.origin_s), EUROBOT_BEACON_MAP, options.seed
    )
    command = harness_command(
        options.harness, options.firmware, "-", 0, out_fd=master, realtime=True, start_at_s=start_at_s
    )
    harness = subprocess.Popen(command, stdin=subprocess.PIPE, pass_fds=(master,))
    node.get_logger().info(
        f"the firmware runs, match time {start_at_s - clock.origin_s:.3f} s at its cycle 0"
    )
    try:
        while harness.poll() is None:
            with contextlib.suppress(BrokenPipeError):
                harness.stdin.write(pins.until(time.time() - zero_s + LEAD_S))
                harness.stdin.flush()
            rclpy.spin_once(node, timeout_sec=PERIOD_S)
            if clock.off_m > TRUTH_OFF_PATH_M:
                node.get_logger().error(
                    f"the ground truth is {clock.off_m:.3f} m off this trajectory: give virtual_turret "
                    "sim_world_node's parameters (trajectory, trajectory_seed, ...), and restart it with "
                    "the match"
                )
                sys.exit(2)
    finally:
        with contextlib.suppress(BrokenPipeError):
            harness.stdin.close()  # its end of the schedule: the harness stops
        try:
            harness.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            harness.kill()
            harness.wait()
    # a Ctrl-C in the terminal reaches the harness too
    return 0 if harness.returncode == -signal.SIGINT else harness.returncode


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv if argv is None else argv
    options = parse(remove_ros_args(argv)[1:])
    why = missing(options.harness, options.firmware)
    if why:
        print(f"virtual_turret: {why}", file=sys.stderr)
        sys.exit(2)
    master, slave = os.openpty()
    tty.setraw(slave)  # the frames are binary; the slave stays open so the line never hangs up
    os.set_blocking(master, False)  # a line nobody reads loses the bytes, as a UART's does
    if options.link:
        options.link.unlink(missing_ok=True)
        options.link.symlink_to(os.ttyname(slave))
    linked = f" (linked at {options.link})" if options.link else ""
    print(f"virtual_turret: the turret's serial line is {os.ttyname(slave)}{linked}", flush=True)

    def interrupt(_signal: int, _frame: object) -> None:
        raise KeyboardInterrupt

    for stop in (signal.SIGINT, signal.SIGTERM):  # SIGINT too: a shell's background job ignores it
        signal.signal(stop, interrupt)
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
    if status:
        print(f"virtual_turret: the harness exited {status}", file=sys.stderr)
    sys.exit(status)


if __name__ == "__main__":
    main()
