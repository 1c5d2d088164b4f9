"""Fixtures for tests that run the installed executables and talk to them over DDS.

Every test gets a ROS_DOMAIN_ID of its own (claimed with a lock file, so parallel runs and other
sessions on the machine never share one), discovery stays on localhost, and every wait is bounded.
"""

import contextlib
import fcntl
import os
import pathlib
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
import yaml

ROOT = pathlib.Path(__file__).resolve().parents[1]
INSTALL_BASE = pathlib.Path(os.environ.get("BEAMS_INSTALL_BASE", ROOT / "install"))
# Domains 61-69 are left for developers' manual experiments.
TEST_DOMAIN_IDS = [*range(1, 61), *range(70, 101)]
SHUTDOWN_TIMEOUT_S = 15.0
# Read-only queries, which `RosGraph.call` sends again each QUERY_RESEND_S without an answer: on a loaded
# machine a call to a node just started now and then gets no answer at all (2 runs of the DDS tier in 10
# here, no process of another test in the domain, nothing in the node's log), as public reports of
# Fast DDS services under load describe; a second request is answered.
QUERY_SERVICES = {"GetParameters", "DescribeParameters", "ListParameters", "GetParameterTypes", "GetState"}
QUERY_RESEND_S = 2.0


def processes_in_domain(domain_id: int) -> list[str]:
    """The other processes on DDS started with this ROS_DOMAIN_ID in their environment ("pid: command
    line"); those without an rmw library loaded cannot talk (multiprocessing's resource tracker, which a
    test's pool starts and which lives as long as the test process)."""
    wanted = f"ROS_DOMAIN_ID={domain_id}".encode()
    found = []
    for entry in pathlib.Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            if (
                wanted in (entry / "environ").read_bytes().split(b"\0")
                and b"/librmw" in (entry / "maps").read_bytes()
            ):
                command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                found.append(f"{entry.name}: {command.strip()}")
        except OSError:  # gone meanwhile, or another user's
            continue
    return found


@pytest.fixture
def ros_domain_id() -> Iterator[int]:
    """A DDS domain no other test or session uses while this test runs.

    The lock ends with the test, so a process of the test's that outlives it would talk to the next test
    given the domain (its nodes in that test's graph, its messages on that test's topics): at the end each
    one still running is killed and fails the test that left it; a domain still holding a process when
    claimed (left by a test whose worker died) is passed over, with its processes printed."""
    lock_dir = pathlib.Path(tempfile.gettempdir()) / "beams_ros_domains"
    lock_dir.mkdir(exist_ok=True)
    for domain_id in TEST_DOMAIN_IDS:
        handle = open(lock_dir / f"{domain_id}.lock", "w")  # noqa: SIM115 (held for the test's duration)
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            continue
        if occupied := processes_in_domain(domain_id):
            print(f"ROS_DOMAIN_ID {domain_id} passed over: still used by {occupied}")
            handle.close()
            continue
        try:
            yield domain_id
            if left := processes_in_domain(domain_id):
                for line in left:
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(int(line.split(":")[0]), signal.SIGKILL)
                pytest.fail(f"processes left running in ROS_DOMAIN_ID {domain_id} after the test: {left}")
        finally:
            handle.close()
        return
    pytest.fail("no free ROS_DOMAIN_ID for this test")


@pytest.fixture
def ros_env(ros_domain_id: int, monkeypatch: pytest.MonkeyPatch, tmp_path: pathlib.Path) -> dict[str, str]:
    """Environment for node subprocesses (and this process) in the test's own domain, localhost only, with
    its own ROS_HOME (ekf_node's checkpoint: no test resumes from another's)."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros_domain_id))
    monkeypatch.setenv("ROS_HOME", str(tmp_path / "ros_home"))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.fixture
def rclpy_context(ros_env):
    """rclpy initialised in this process, in the test's own domain (nodes built in-process)."""
    rclpy = pytest.importorskip("rclpy", reason="rclpy missing: run the tests through `make test`")
    rclpy.init()
    try:
        yield rclpy
    finally:
        rclpy.try_shutdown()


@dataclass
class RosGraph:
    """An rclpy node in the test's domain, with bounded spinning."""

    node: Any
    executor: Any
    received: dict[str, list[Any]] = field(default_factory=dict)

    def subscribe(self, msg_type: Any, topic: str, qos: Any = 10) -> list[Any]:
        """Record every message on a topic into the returned list."""
        messages = self.received.setdefault(topic, [])
        self.node.create_subscription(msg_type, topic, messages.append, qos)
        return messages

    def diagnostic_values(self, name_part: str) -> dict[str, str]:
        """Latest key/value pairs the /diagnostics statuses whose name holds name_part reported
        (subscribe to /diagnostics first)."""
        return {
            kv.key: kv.value
            for msg in self.received.get("/diagnostics", [])
            for status in msg.status
            if name_part in status.name
            for kv in status.values
        }

    def spin_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Spin until predicate() is true or timeout_s passes; returns predicate()."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def publish_until(
        self, publisher: Any, message: Any, predicate: Callable[[], bool], timeout_s: float
    ) -> bool:
        """Publish message every 0.25 s until predicate() holds (discovery takes a moment) or timeout_s."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            publisher.publish(message)
            if self.spin_until(predicate, 0.25):
                return True
        return predicate()

    def spin_for(self, duration_s: float) -> None:
        deadline = time.monotonic() + duration_s
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def call(
        self, srv_type: Any, name: str, request: Any, timeout_s: float, resend_s: float | None = None
    ) -> Any:
        """Call a service and wait (bounded) for its answer; fails the test on a time-out.

        `resend_s`: send the request again each resend_s without an answer (a request that is safe to
        repeat; a read-only query, QUERY_SERVICES, is sent again by default). A node restarted after a
        kill -9 needs it: the dead process's server stays in the graph
        for the DDS lease (5 s), so wait_for_service answers at once, and a request sent before the new
        server's reader has matched this client (the next discovery announcement, up to 0.25 s) reaches
        only the dead one and is never answered."""
        if resend_s is None and srv_type.__name__ in QUERY_SERVICES:
            resend_s = QUERY_RESEND_S
        client = self.node.create_client(srv_type, name)
        if not client.wait_for_service(timeout_sec=timeout_s):
            pytest.fail(f"service {name} not available within {timeout_s} s")
        deadline = time.monotonic() + timeout_s
        futures = [client.call_async(request)]
        while not any(f.done() for f in futures) and time.monotonic() < deadline:
            wait_s = min(resend_s or timeout_s, deadline - time.monotonic())
            if not self.spin_until(lambda: any(f.done() for f in futures), wait_s) and resend_s:
                futures.append(client.call_async(request))
        done = [f for f in futures if f.done()]
        if not done:
            pytest.fail(f"service {name} did not answer within {timeout_s} s")
        return done[0].result()


@contextlib.contextmanager
def open_ros_graph(domain_id: int) -> Iterator[RosGraph]:
    """The probe node in its own rclpy context (the fixture below; test_system_hosts.py's base station
    process)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node("beams_test_probe", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield RosGraph(node=node, executor=executor)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)


@pytest.fixture
def rclpy_node(ros_env: dict[str, str], ros_domain_id: int) -> Iterator[RosGraph]:
    pytest.importorskip("rclpy", reason="rclpy missing: run the tests through `make test`")
    with open_ros_graph(ros_domain_id) as graph:
        yield graph


@dataclass
class NodeProcess:
    """An installed executable running as a separate process."""

    name: str
    process: subprocess.Popen
    log_path: pathlib.Path
    expected_exit: bool = False

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait_exit(self, timeout_s: float) -> int:
        """Wait (bounded) for a node the test expects to exit by itself; its exit status."""
        self.expected_exit = True
        try:
            return self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{self.name} still running after {timeout_s} s\n{self.log()}")

    def stop(self, sig: int = signal.SIGINT) -> int:
        """Send a signal and wait (bounded) for the exit status."""
        self.expected_exit = True
        if self.process.poll() is None:
            self.process.send_signal(sig)
        try:
            return self.process.wait(timeout=SHUTDOWN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=SHUTDOWN_TIMEOUT_S)
            pytest.fail(f"{self.name} ignored signal {sig} for {SHUTDOWN_TIMEOUT_S} s\n{self.log()}")

    def assert_clean_exit(self, sig: int = signal.SIGINT) -> None:
        status = self.stop(sig)
        output = self.log()
        assert status == 0, f"{self.name} exited with {status} on signal {sig}:\n{output}"
        assert "Traceback" not in output, f"{self.name} printed a traceback:\n{output}"


def executable_path(package: str, executable: str) -> pathlib.Path:
    path = INSTALL_BASE / package / "lib" / package / executable
    if not path.exists():
        pytest.fail(f"{path} is not installed: run `make build`")
    return path


@pytest.fixture
def installed_executable() -> Callable[[str, str], pathlib.Path]:
    """executable_path, for a command a test runs itself (its own stdin and output)."""
    return executable_path


@pytest.fixture
def start_node(ros_env: dict[str, str], tmp_path: pathlib.Path) -> Iterator[Callable[..., NodeProcess]]:
    """Start installed executables; at teardown each gets SIGINT and must exit 0 with no traceback."""
    started: list[NodeProcess] = []

    def start(
        package: str,
        executable: str,
        params: dict[str, Any] | None = None,
        namespace: str = "",
        extra_args: list[str] | None = None,
        own_process_group: bool = False,
        command_prefix: list[str] | None = None,
        arguments: list[str] | None = None,
    ) -> NodeProcess:
        # command_prefix runs the node through a wrapper that execs it (`ip netns exec <ns>`: another host);
        # arguments are the program's own, before --ros-args (`--standby`)
        executable_command = [str(executable_path(package, executable)), *(arguments or [])]
        command = [*(command_prefix or []), *executable_command, "--ros-args"]
        if params:
            params_file = tmp_path / f"{executable}_{len(started)}.yaml"
            params_file.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
            command += ["--params-file", str(params_file)]
        if namespace:
            command += ["-r", f"__ns:=/{namespace.lstrip('/')}"]
        command += extra_args or []
        log_path = tmp_path / f"{executable}_{len(started)}.log"
        with open(log_path, "w") as log_file:
            process = subprocess.Popen(
                command,
                env=ros_env,
                stdout=log_file,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                # a group of its own receives signals as a terminal or a launcher sends them (os.killpg)
                start_new_session=own_process_group,
            )
        node = NodeProcess(name=f"{package}/{executable}", process=process, log_path=log_path)
        started.append(node)
        return node

    yield start
    failures = []
    for node in started:
        if node.expected_exit:
            continue  # the test stopped it, or waited for its exit, and asserted what it needed
        if node.process.poll() is not None:
            failures.append(f"{node.name} exited by itself with {node.process.returncode}:\n{node.log()}")
            continue
        status = node.stop()
        output = node.log()
        if status != 0 or "Traceback" in output:
            failures.append(f"{node.name} exited with {status} on SIGINT:\n{output}")
    if failures:
        pytest.fail("\n".join(failures))
