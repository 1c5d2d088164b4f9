"""The fault campaign's two hosts: network namespaces joined by one link (root and iproute2)."""

import ctypes
import os
import pathlib
import shutil
import subprocess

# The robot on two hosts: driver_node on the sensor's computer, everything else (the other nodes, the
# relay and the campaign's probe) on the main computer, each a network namespace, joined by one veth link
# in a private subnet that exists only inside them (test/dds/test_system_hosts.py builds the same for
# two robots and a base station). DDS discovers across it with ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET.
HOST_SUBNET = "10.214.0"
HOST_ADDRESS = {"main": 1, "sensor": 2}
HOST_LINK = "eth0"
MULTICAST_RANGE = "224.0.0.0/4"
IP_TIMEOUT_S = 10.0
CLONE_NEWNET = 0x40000000
# the processes on the sensor's host; the others run on the main computer's
SENSOR_HOST_PROCESSES = ("driver",)


def hosts_problem() -> str:
    """Why network namespaces cannot be made here ('' when they can): root and iproute2's `ip`."""
    if os.geteuid() != 0:
        return "network namespaces need root (CAP_NET_ADMIN, CAP_SYS_ADMIN)"
    if shutil.which("ip") is None:
        return "iproute2's `ip` is missing (scripts/bootstrap.sh installs it)"
    return ""


def _ip(*args: str) -> None:
    result = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=IP_TIMEOUT_S)
    if result.returncode != 0:
        raise RuntimeError(f"`ip {' '.join(args)}` failed: {result.stderr.strip()}")


def _setns(fd: int, path: str) -> None:
    """This thread (the main one: the probe's DDS participant and the processes it starts) into the
    network namespace of fd, opened at path, which it closes (Python 3.11 has no os.setns)."""
    try:
        if ctypes.CDLL(None, use_errno=True).setns(fd, CLONE_NEWNET) != 0:
            raise OSError(ctypes.get_errno(), f"setns({path})")
    finally:
        os.close(fd)


def _remove_stale_namespaces() -> None:
    """Delete the namespaces of an earlier campaign whose process is gone (killed before its clean-up)."""
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=IP_TIMEOUT_S)
    for line in listed.stdout.splitlines():
        name = line.split()[0] if line.strip() else ""
        pid = name.removeprefix("beams-campaign-").split("-")[0]
        if name.startswith("beams-campaign-") and pid.isdigit() and not pathlib.Path(f"/proc/{pid}").exists():
            subprocess.run(["ip", "netns", "delete", name], capture_output=True, timeout=IP_TIMEOUT_S)


class Hosts:
    """The two namespaces and their link; `enter` moves the campaign's main thread onto the main
    computer's host (and `leave` back), `set_link` cuts or restores the link."""

    def __init__(self, tag: str) -> None:
        self.namespaces = {host: f"beams-campaign-{tag}-{host}" for host in HOST_ADDRESS}
        self._home: int | None = None

    def build(self) -> None:
        _remove_stale_namespaces()
        main, sensor = self.namespaces["main"], self.namespaces["sensor"]
        for name in self.namespaces.values():
            _ip("netns", "add", name)
            _ip("-n", name, "link", "set", "lo", "multicast", "on", "up")
        _ip("-n", main, "link", "add", HOST_LINK, "type", "veth", "peer", "name", HOST_LINK, "netns", sensor)
        for host, name in self.namespaces.items():
            _ip("-n", name, "addr", "add", f"{HOST_SUBNET}.{HOST_ADDRESS[host]}/24", "dev", HOST_LINK)
            _ip("-n", name, "link", "set", HOST_LINK, "multicast", "on", "up")
            _ip("-n", name, "route", "add", MULTICAST_RANGE, "dev", HOST_LINK)

    def exec_prefix(self, process: str) -> list[str]:
        """`ip netns exec` onto the sensor's host for its processes (the others inherit the main host's
        namespace from the campaign's main thread)."""
        return ["ip", "netns", "exec", self.namespaces["sensor"]] if process in SENSOR_HOST_PROCESSES else []

    def enter(self) -> None:
        self._home = os.open("/proc/self/ns/net", os.O_RDONLY)
        path = f"/var/run/netns/{self.namespaces['main']}"
        _setns(os.open(path, os.O_RDONLY), path)

    def leave(self) -> None:
        if self._home is not None:
            home, self._home = self._home, None
            _setns(home, "/proc/self/ns/net")

    def set_link(self, up: bool) -> None:
        _ip("-n", self.namespaces["main"], "link", "set", HOST_LINK, "up" if up else "down")

    def remove(self) -> None:
        for name in self.namespaces.values():
            subprocess.run(["ip", "netns", "delete", name], capture_output=True, timeout=IP_TIMEOUT_S)
