"""The role lock of the hot standby (beams_common.ros.standby): held and free, freed by the kernel when its
holder is killed, one role per domain and fully qualified name, the identity read from --ros-args."""

import os
import pathlib
import signal
import subprocess
import sys
import threading
import time
import uuid

import pytest

import beams_common
from beams_common.ros.standby import (
    MAX_ABSTRACT_NAME_BYTES,
    NodeIdentity,
    RoleLock,
    domain_id_of,
    node_identity,
    role_name,
    signal_wakeup,
    split_standby_flag,
    wait_for_role,
)

SUBPROCESS_TIMEOUT_S = 20.0
# the kernel frees the name as the holder's process is reaped: a waiting standby sees it at once
TAKEOVER_BOUND_S = 0.5


def unique_role(label: str = "ekf_node") -> str:
    """A role no other test or session holds (the abstract namespace is the whole machine's)."""
    return role_name(NodeIdentity(f"/test_{uuid.uuid4().hex[:12]}", label), "0")


def start_holder(name: str) -> subprocess.Popen:
    """A process that takes the role, says 'held' and sleeps."""
    source_root = pathlib.Path(beams_common.__file__).resolve().parents[1]
    program = (
        "import sys, time\n"
        "from beams_common.ros.standby import RoleLock\n"
        f"lock = RoleLock({name!r})\n"
        "print('held' if lock.try_acquire() else 'refused', flush=True)\n"
        "time.sleep(60)\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(source_root), os.environ.get("PYTHONPATH", "")])}
    holder = subprocess.Popen([sys.executable, "-c", program], stdout=subprocess.PIPE, text=True, env=env)
    assert holder.stdout.readline().strip() == "held"
    return holder


def test_a_role_is_held_by_one_lock_until_released():
    name = unique_role()
    first, second = RoleLock(name), RoleLock(name)
    assert first.try_acquire() and first.held
    assert not second.try_acquire() and not second.held
    assert second.holder_pid() == os.getpid()
    first.release()
    assert second.holder_pid() is None
    assert second.try_acquire()
    second.release()


def test_the_role_is_freed_when_its_holder_is_killed_and_a_waiting_standby_takes_it_at_once():
    name = unique_role()
    holder = start_holder(name)
    standby = RoleLock(name)
    try:
        assert not standby.try_acquire()
        assert standby.holder_pid() == holder.pid
        seen_holders: list[int | None] = []
        outcome: dict[str, float | bool] = {}
        stop = threading.Event()

        def wait() -> None:
            outcome["taken"] = wait_for_role(standby, stop.is_set, seen_holders.append, poll_s=0.1)
            outcome["at_s"] = time.monotonic()

        waiter = threading.Thread(target=wait)
        waiter.start()
        time.sleep(0.3)  # waiting on the holder
        assert waiter.is_alive() and seen_holders == [holder.pid]
        killed_at_s = time.monotonic()
        holder.send_signal(signal.SIGKILL)
        waiter.join(timeout=SUBPROCESS_TIMEOUT_S)
        stop.set()
        assert outcome["taken"] is True and standby.held
        assert outcome["at_s"] - killed_at_s < TAKEOVER_BOUND_S
        assert holder.wait(timeout=SUBPROCESS_TIMEOUT_S) == -signal.SIGKILL
    finally:
        holder.kill()
        holder.wait(timeout=SUBPROCESS_TIMEOUT_S)
        standby.release()


def test_a_waiting_standby_blocks_without_cpu_and_wakes_on_its_wakeup_descriptor():
    name = unique_role()
    holder = RoleLock(name)
    assert holder.try_acquire()
    stop = threading.Event()
    outcome: list[bool] = []
    reader, writer = os.pipe2(os.O_NONBLOCK)
    waiter = threading.Thread(
        target=lambda: outcome.append(wait_for_role(RoleLock(name), stop.is_set, wakeup_fd=reader))
    )
    try:
        waiter.start()
        time.sleep(0.1)  # connected and waiting
        cpu_before_s = time.process_time()
        time.sleep(1.0)  # this thread sleeps: the process's CPU meanwhile is the waiter's
        waiting_cpu_s = time.process_time() - cpu_before_s
        stop.set()
        os.write(writer, b"x")  # what a signal does through signal_wakeup
        waiter.join(timeout=SUBPROCESS_TIMEOUT_S)
    finally:
        holder.release()
        os.close(reader)
        os.close(writer)
    assert outcome == [False]
    # blocked in select with no timeout: no wake-up at all (a 0.1-s poll cost 1 ms a second)
    assert waiting_cpu_s < 0.002


def test_a_stop_signal_ends_the_wait_at_once_through_signal_wakeup():
    name = unique_role()
    holder = RoleLock(name)
    assert holder.try_acquire()
    received: list[int] = []
    previous = signal.signal(signal.SIGUSR1, lambda number, _frame: received.append(number))
    sender = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGUSR1))
    try:
        started_s = time.monotonic()
        sender.start()
        with signal_wakeup() as wakeup_fd:
            taken = wait_for_role(RoleLock(name), lambda: bool(received), wakeup_fd=wakeup_fd)
        waited_s = time.monotonic() - started_s
    finally:
        sender.cancel()
        signal.signal(signal.SIGUSR1, previous)
        holder.release()
    assert not taken and received == [signal.SIGUSR1]
    assert 0.3 <= waited_s < 0.3 + TAKEOVER_BOUND_S


def test_roles_of_other_namespaces_names_and_domains_are_independent():
    namespace = f"/test_{uuid.uuid4().hex[:12]}"
    roles = [
        role_name(NodeIdentity(namespace + "/robot1", "ekf_node"), "7"),
        role_name(NodeIdentity(namespace + "/robot2", "ekf_node"), "7"),
        role_name(NodeIdentity(namespace + "/robot1", "ekf_node"), "8"),
        role_name(NodeIdentity(namespace + "/robot1", "x"), "7"),
    ]
    locks = [RoleLock(name) for name in roles]
    try:
        assert len(set(roles)) == 4
        assert all(lock.try_acquire() for lock in locks)
    finally:
        for lock in locks:
            lock.release()


def test_a_name_too_long_for_a_socket_address_is_replaced_by_its_digest():
    long_namespace = "/" + "n" * 200
    name = role_name(NodeIdentity(long_namespace, "ekf_node"), "3")
    assert len(name.encode()) <= MAX_ABSTRACT_NAME_BYTES and name.startswith("beams-role:3:sha256:")
    assert name == role_name(NodeIdentity(long_namespace, "ekf_node"), "3")
    assert name != role_name(NodeIdentity(long_namespace, "ekf_node_2"), "3")
    lock = RoleLock(name)
    assert lock.try_acquire()
    lock.release()


@pytest.mark.parametrize(
    ("args", "identity"),
    [
        (["ekf_node"], ("/", "ekf_node")),
        (["ekf_node", "--ros-args", "-r", "__ns:=/robot1"], ("/robot1", "ekf_node")),
        (["ekf_node", "--ros-args", "--remap", "__ns:=robot1/"], ("/robot1", "ekf_node")),
        (["ekf_node", "--ros-args", "-r", "__node:=x", "-r", "__ns:=/a/b"], ("/a/b", "x")),
        (["ekf_node", "--ros-args", "-r", "__name:=y"], ("/", "y")),
        # the last remap of a key wins, as rcl applies them
        (["ekf_node", "--ros-args", "-r", "__ns:=/a", "--ros-args", "-r", "__ns:=/b"], ("/b", "ekf_node")),
        # a remap targeted at this node applies, one targeted at another does not
        (
            ["ekf_node", "--ros-args", "-r", "ekf_node:__ns:=/mine", "-r", "other:__node:=z"],
            ("/mine", "ekf_node"),
        ),
        # after `--` the arguments are the program's again; a parameter value is never a remap
        (["ekf_node", "--ros-args", "-r", "__ns:=/in", "--", "-r", "__ns:=/out"], ("/in", "ekf_node")),
        (["ekf_node", "--ros-args", "-p", "-r", "--params-file", "__ns:=/p"], ("/", "ekf_node")),
        (["ekf_node", "-r", "__ns:=/not_ros"], ("/", "ekf_node")),
    ],
)
def test_the_identity_comes_from_the_remaps(args, identity):
    assert node_identity(args, "ekf_node") == NodeIdentity(*identity)


def test_the_fully_qualified_name_and_logger_name():
    assert NodeIdentity("/", "ekf_node").fully_qualified_name == "/ekf_node"
    assert NodeIdentity("/robot1/a", "ekf_node").fully_qualified_name == "/robot1/a/ekf_node"
    assert NodeIdentity("/robot1/a", "ekf_node").logger_name == "robot1.a.ekf_node"
    assert NodeIdentity("/", "ekf_node").logger_name == "ekf_node"


def test_the_standby_flag_is_stripped_only_from_the_programs_own_arguments():
    assert split_standby_flag(["ekf_node", "--standby", "--ros-args", "-r", "__ns:=/a"]) == (
        ["ekf_node", "--ros-args", "-r", "__ns:=/a"],
        True,
    )
    assert split_standby_flag(["ekf_node", "--ros-args", "-p", "x:=1"]) == (
        ["ekf_node", "--ros-args", "-p", "x:=1"],
        False,
    )
    # inside --ros-args it is not the program's (rcl refuses it there, with its reason)
    inside = ["ekf_node", "--ros-args", "--standby"]
    assert split_standby_flag(inside) == (inside, False)
    assert split_standby_flag(["ekf_node", "--ros-args", "--", "--standby"]) == (
        ["ekf_node", "--ros-args", "--"],
        True,
    )


@pytest.mark.parametrize(
    ("environ", "domain"),
    [
        ({}, "0"),
        ({"ROS_DOMAIN_ID": ""}, "0"),
        ({"ROS_DOMAIN_ID": "07"}, "7"),
        ({"ROS_DOMAIN_ID": " 42 "}, "42"),
    ],
)
def test_the_domain_id_as_rmw_reads_it(environ, domain):
    assert domain_id_of(environ) == domain
