"""virtual_turret: sim_world_node's match, and the turret firmware in simavr on a pty following its robot,
for `driver_node source:=serial device:=<the pty or --link>` (docs/firmware.md)."""

import argparse
import contextlib
import os
import pathlib
import signal
import subprocess
import sys
import time
import tty
from collections.abc import Sequence

import rclpy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from beams_common.config.command_line import command
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.ros.node_support import EXIT_INVALID_PARAMETERS
from beams_common.ros.parameters import ParameterValidationError
from beams_sim import virtual_turret as turret
from beams_sim.sim_world_node import SimWorldNode

LEAD_S = 1.0  # the schedule is written this far ahead of the emulation
START_DELAY_S = 0.5  # from the harness's start to its cycle 0 (the first chunk is written meanwhile)


def run(world: SimWorldNode, options: argparse.Namespace, master: int) -> int:
    """Emulate until the harness ends (its status) or an interrupt."""
    while world.start_s is None:  # the match starts at the node's first tick
        rclpy.spin_once(world, timeout_sec=0.1)
    start_at_s = time.time() + START_DELAY_S
    zero_s = start_at_s + turret.START_CYCLE / turret.CPU_HZ  # the system time of turret time 0
    pins = turret.TurretPins(
        lambda t: world.trajectory.pose_at(zero_s + t - world.start_s), EUROBOT_BEACON_MAP, options.seed
    )
    flags = ("--out-fd", master, "--realtime", "--start-at", f"{start_at_s:.6f}")
    command = turret.harness_command("-", 0, *flags, firmware=options.firmware)
    harness = subprocess.Popen(command, stdin=subprocess.PIPE, pass_fds=(master,))
    world.get_logger().info(f"cycle 0 at {start_at_s:.6f} s, match time {start_at_s - world.start_s:.6f} s")
    try:
        while harness.poll() is None:
            with contextlib.suppress(BrokenPipeError):
                harness.stdin.write(pins.until(time.time() - zero_s + LEAD_S))
                harness.stdin.flush()
            rclpy.spin_once(world, timeout_sec=turret.PERIOD_S)
    finally:
        with contextlib.suppress(BrokenPipeError):
            harness.stdin.close()  # the schedule's end: the harness stops
        harness.wait()
    return 0 if harness.returncode == -signal.SIGINT else harness.returncode  # a terminal's Ctrl-C


@command("virtual_turret")
def main(argv: Sequence[str] | None = None) -> int:
    argv = ["virtual_turret", *(sys.argv[1:] if argv is None else argv)]
    parser = argparse.ArgumentParser(prog="virtual_turret", description=__doc__.split("\n")[0])
    parser.add_argument("--link", type=pathlib.Path, help="a symbolic link to the pty, made and removed")
    parser.add_argument("--seed", type=int, default=1, help="seed of the simulated sensor's noise")
    parser.add_argument("--firmware", type=pathlib.Path, default=turret.FIRMWARE, help="turret.elf")
    options = parser.parse_args(remove_ros_args(argv)[1:])
    why = turret.missing(options.firmware)
    if options.link and options.link.exists() and not options.link.is_symlink():
        why = f"{options.link} exists and is not a link"  # a real device's path, say
    if why:
        raise ValueError(why)
    master, slave = os.openpty()
    try:
        tty.setraw(slave)  # binary frames; the slave stays open so that the line never hangs up
        os.set_blocking(master, False)  # a line nobody reads loses the bytes, as a UART's does
        if options.link:
            options.link.unlink(missing_ok=True)
            options.link.symlink_to(os.ttyname(slave))
        return _serve(argv, options, master, slave)
    finally:
        os.close(master)
        os.close(slave)
        if options.link and options.link.is_symlink():
            options.link.unlink(missing_ok=True)


def _serve(argv: list[str], options: argparse.Namespace, master: int, slave: int) -> int:
    """The world node and the emulated turret on the pty, until the harness ends or an interrupt."""
    print(f"virtual_turret: the turret's serial line is {os.ttyname(slave)} {options.link or ''}", flush=True)
    for stop in (signal.SIGINT, signal.SIGTERM):  # SIGINT too: a shell's background job ignores it
        signal.signal(stop, signal.default_int_handler)  # KeyboardInterrupt
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    world, status = None, 0
    try:
        world = SimWorldNode()
        status = run(world, options, master)
    except ParameterValidationError as error:
        print(f"virtual_turret: invalid parameters: {error}", file=sys.stderr)
        status = EXIT_INVALID_PARAMETERS
    except KeyboardInterrupt:
        pass
    finally:
        if world is not None:
            world.destroy_node()
        rclpy.try_shutdown()
    return status
