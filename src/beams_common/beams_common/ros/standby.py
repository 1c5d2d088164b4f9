"""Hot standby: one ACTIVE process per node role, a second one waiting to take it over at once.

A role is a node's identity on one host: the ROS_DOMAIN_ID and the node's fully qualified name as its
--ros-args remaps set it (`-r __ns:=/robot1`, `-r __node:=x`, `--remap`), read from the command line
before rclpy is initialised (`node_identity`). The active process holds the role (`RoleLock`); a process
started with `--standby` (`split_standby_flag`) imports its modules, then waits (`wait_for_role`) without
any DDS participant until the holder dies, and only then becomes the node (beams_common.ros.node_support).

The lock is a Linux abstract unix socket bound to "\\0beams-role:<domain>:<fully qualified name>":
- the kernel frees the name the instant its process dies, SIGKILL and the OOM killer included, and
  nothing is left behind to clean (a stale file, a stale pid);
- it needs no writable directory (a read-only root, no $XDG_RUNTIME_DIR under a service manager);
- it is per network namespace, as the nodes' hosts are: two hosts emulated by network namespaces on one
  machine (test/dds/test_system_hosts.py) hold a role each, where a flock file in a shared /tmp would let
  one host's node block the other's.
Its cost: any process of the network namespace may bind the name, whoever the user (the role is a
coordination between cooperating processes, not a security boundary).

The holder listens on its socket and never accepts; a standby connects and waits for that connection to
break, which the kernel does when the holder's socket closes: the takeover starts as soon as the holder
is gone. Meanwhile the standby blocks in select on that connection and on a signal wakeup pipe
(`signal_wakeup`): no timeout, no CPU, and a stop signal still seen at once.
"""

import contextlib
import errno
import hashlib
import os
import select
import signal
import socket
import struct
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass

STANDBY_FLAG = "--standby"
ROLE_PREFIX = "beams-role"
# A Linux socket address holds 108 bytes; an abstract name starts with one zero byte.
MAX_ABSTRACT_NAME_BYTES = 107
# connections a holder keeps pending without accepting them: its standbys and the holder_pid queries
LISTEN_BACKLOG = 16
# A standby that cannot watch the holder (the holder between bind and listen, its backlog full)
# tries again after this long (s).
RETRY_S = 0.02
CONNECT_TIMEOUT_S = 1.0  # a connect blocks only while the holder's backlog is full
ROS_ARGS_START = "--ros-args"
ROS_ARGS_END = "--"
REMAP_FLAGS = ("-r", "--remap")
# --ros-args flags followed by a value (rcl's arguments.h), skipped so a value is never read as a remap
VALUE_FLAGS = (
    "-p",
    "--param",
    "--params-file",
    "-e",
    "--enclave",
    "--log-level",
    "--log-config-file",
    "--log-file-name",
)
NAMESPACE_REMAP = "__ns"
NAME_REMAPS = ("__node", "__name")  # rcl accepts both; __name is the older spelling
_UCRED = struct.Struct("3i")  # struct ucred: pid, uid, gid (SO_PEERCRED)


@dataclass(frozen=True)
class NodeIdentity:
    """A node's namespace (absolute) and name, as its remaps make them."""

    namespace: str
    name: str

    @property
    def fully_qualified_name(self) -> str:
        return f"{self.namespace.rstrip('/')}/{self.name}"

    @property
    def logger_name(self) -> str:
        """The node's logger name as rclpy makes it (`robot1.ekf_node`)."""
        return self.fully_qualified_name.strip("/").replace("/", ".")


def _ros_argument_sections(args: Sequence[str]) -> list[tuple[bool, str]]:
    """Each argument with whether it lies in a --ros-args section (rcl: from --ros-args to `--` or the
    end; several sections may follow each other). The markers themselves count as ROS arguments."""
    marked = []
    inside = False
    for argument in args:
        if argument == ROS_ARGS_START:
            inside = True
            marked.append((True, argument))
        elif inside and argument == ROS_ARGS_END:
            inside = False
            marked.append((True, argument))
        else:
            marked.append((inside, argument))
    return marked


def split_standby_flag(args: Sequence[str]) -> tuple[list[str], bool]:
    """The arguments without STANDBY_FLAG (rclpy must not see it) and whether it was given; only outside
    the --ros-args sections, where a program's own arguments are."""
    kept = [
        argument for inside, argument in _ros_argument_sections(args) if inside or argument != STANDBY_FLAG
    ]
    return kept, len(kept) != len(args)


def node_identity(args: Sequence[str], default_name: str, default_namespace: str = "/") -> NodeIdentity:
    """The node's identity after the command line's remaps of `__ns` and `__node` (each the last one
    given; a remap targeted at another node, `other_node:__ns:=/x`, is not this node's)."""
    namespace, name = default_namespace, default_name
    marked = _ros_argument_sections(args)
    index = 0
    while index < len(marked):
        inside, argument = marked[index]
        index += 1
        if not inside or index >= len(marked):
            continue
        if argument in VALUE_FLAGS:
            index += 1
        elif argument in REMAP_FLAGS:
            rule = marked[index][1]
            index += 1
            source, _, replacement = rule.partition(":=")
            target, _, key = source.rpartition(":")
            if target and target != default_name:
                continue
            if key == NAMESPACE_REMAP:
                namespace = replacement
            elif key in NAME_REMAPS:
                name = replacement
    namespace = "/" + namespace.strip("/")
    return NodeIdentity(namespace, name)


def domain_id_of(environ: Mapping[str, str]) -> str:
    """ROS_DOMAIN_ID as rmw reads it (unset or empty: domain 0); as text, so that a value rmw refuses
    still names a role and the node's own start-up says what is wrong with it."""
    value = environ.get("ROS_DOMAIN_ID", "").strip() or "0"
    return str(int(value)) if value.isdigit() else value  # 07 is domain 7


def role_name(identity: NodeIdentity, domain_id: str) -> str:
    """The role's abstract socket name (without its leading zero byte); a name too long for a socket
    address is replaced by its digest (the same role gets the same digest)."""
    name = f"{ROLE_PREFIX}:{domain_id}:{identity.fully_qualified_name}"
    if len(name.encode()) > MAX_ABSTRACT_NAME_BYTES:
        digest = hashlib.sha256(identity.fully_qualified_name.encode()).hexdigest()
        name = f"{ROLE_PREFIX}:{domain_id}:sha256:{digest}"
    return name


def role_holder_pid(command: Sequence[str], executable: str, environ: Mapping[str, str]) -> int | None:
    """The process id holding the role a node's command line names (its --ros-args remaps, `executable`
    the default node name, the environment's ROS_DOMAIN_ID); None when no process holds it: which
    process of a hot standby pair is the active one."""
    return RoleLock(role_name(node_identity(command, executable), domain_id_of(environ))).holder_pid()


class RoleLock:
    """One process's hold on a role: `try_acquire`, then held until `release` or the process's death."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._address = b"\0" + name.encode()
        self._socket: socket.socket | None = None

    @property
    def held(self) -> bool:
        return self._socket is not None

    def try_acquire(self) -> bool:
        """Take the role if no process holds it; True when this one holds it now."""
        if self._socket is not None:
            return True
        # Python's sockets are close-on-exec: a program this process starts cannot keep the role alive
        candidate = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            candidate.bind(self._address)
        except OSError as error:
            candidate.close()
            if error.errno == errno.EADDRINUSE:
                return False
            raise
        candidate.listen(LISTEN_BACKLOG)
        self._socket = candidate
        return True

    def release(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def holder_pid(self) -> int | None:
        """The process id of the role's holder (the kernel's record of who listens), None when free."""
        probe = self._connect(timeout_s=CONNECT_TIMEOUT_S)
        if probe is None:
            return None
        with probe:
            pid, _uid, _gid = _UCRED.unpack(
                probe.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _UCRED.size)
            )
        return pid

    def _connect(self, timeout_s: float) -> socket.socket | None:
        """A connection to the holder's socket, None when nobody listens (free, or not listening yet) or
        its backlog stays full for timeout_s."""
        connection = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        connection.settimeout(timeout_s)
        try:
            connection.connect(self._address)
        except (ConnectionRefusedError, FileNotFoundError, TimeoutError, BlockingIOError):
            connection.close()
            return None
        return connection

    def wait_for_holder_to_end(
        self, stopped: Callable[[], bool], wakeup_fd: int | None, poll_s: float | None
    ) -> None:
        """Return when the current holder's socket closed (its process died or released the role), when
        there is no holder to watch, or when stopped() is true: checked each time `wakeup_fd` becomes
        readable (`signal_wakeup`) and every poll_s (None: never by time)."""
        watch = self._connect(timeout_s=CONNECT_TIMEOUT_S)
        if watch is None:
            time.sleep(RETRY_S)  # not listening yet, or its backlog full: no busy loop
            return
        waited = [watch] if wakeup_fd is None else [watch, wakeup_fd]
        with watch:
            while not stopped():
                readable, _, _ = select.select(waited, [], [], poll_s)
                # the holder never accepts nor writes: readable means the connection broke (EOF or reset)
                if watch in readable:
                    return
                if wakeup_fd in readable:
                    _drain(wakeup_fd)


def _drain(fd: int) -> None:
    """Read what a non-blocking descriptor holds (the signal numbers set_wakeup_fd wrote)."""
    with contextlib.suppress(BlockingIOError):
        while os.read(fd, 512):
            pass


@contextlib.contextmanager
def signal_wakeup() -> Iterator[int]:
    """A descriptor that becomes readable when a signal with a Python handler arrives
    (signal.set_wakeup_fd; the main thread only): a wait blocks on it and on its event, with no timeout
    and no CPU, and still sees a stop signal at once. A pipe, not a socket: no endpoint of any kind."""
    reader, writer = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
    previous = signal.set_wakeup_fd(writer, warn_on_full_buffer=False)
    try:
        yield reader
    finally:
        signal.set_wakeup_fd(previous)
        os.close(reader)
        os.close(writer)


def wait_for_role(
    lock: RoleLock,
    stopped: Callable[[], bool],
    on_waiting: Callable[[int | None], None] = lambda _pid: None,
    wakeup_fd: int | None = None,
    poll_s: float | None = None,
) -> bool:
    """Take the role as soon as it is free: True once held, False when stopped() became true first
    (looked at whenever `wakeup_fd` is readable and every poll_s; with neither, only when a holder
    ends). `on_waiting(holder pid)` is called once, when the role is found held."""
    said = False
    while not stopped():
        if lock.try_acquire():
            return True
        if not said:
            on_waiting(lock.holder_pid())
            said = True
        lock.wait_for_holder_to_end(stopped, wakeup_fd, poll_s)
    return False
