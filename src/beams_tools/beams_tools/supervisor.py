"""The process runner of the demo, the fault campaign and the benches, for the environments without launch
(the PyPI wheels): what `ros2 launch` does with `respawn=True, respawn_delay=RESPAWN_DELAY_S`, except
for a node that refused its parameters (exit status 2: it would refuse them again). What a user sees:
docs/integrity.md ("A node that dies anyway"). A caller's own kill (`signal`) holds a process: neither
a death nor restarted until `resume`.
"""

import signal
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from beams_common.ros.standby import role_holder_pid
from beams_tools.robot_processes import RESPAWN_DELAY_S

EXIT_INVALID_PARAMETERS = 2  # run_node's start-up refusal (beams_common.ros.node_support)
STOP_TIMEOUT_S = 15.0
RESTART_NOTE = "--- restart"


@dataclass
class SupervisedNode:
    """One process the supervisor runs: its command, its current process and its restarts."""

    name: str
    command: Sequence[str]
    log_path: Path
    process: subprocess.Popen | None = None
    restarts: int = 0
    exits: list[int] = field(default_factory=list)
    restart_due_s: float | None = None  # when the next start is due (after a death)
    gave_up: str = ""  # why it is not restarted ('' while it is)
    held: bool = False  # signalled by the caller: its exit is not a death, it is not restarted
    started_s: float = 0.0  # when its current process started (the supervisor's clock)
    rss_samples: list[tuple[float, float]] = field(default_factory=list)  # its current process's (s, MB)

    def log_tail(self, lines: int = 15) -> str:
        """The last lines its current process wrote."""
        text = self.log_path.read_text(errors="replace") if self.log_path.exists() else ""
        _, note, tail = text.rpartition(RESTART_NOTE)
        return "\n".join((tail.partition("\n")[2] if note else tail).splitlines()[-lines:])


class NodeSupervisor:
    """Start every process, restart each one that dies (`poll`, called from the caller's loop), stop all."""

    def __init__(
        self,
        commands: Mapping[str, Sequence[str]],
        env: Mapping[str, str],
        log_dir: Path,
        respawn_delay_s: float = RESPAWN_DELAY_S,
        clock: Callable[[], float] = time.monotonic,
        on_exit: Callable[[SupervisedNode, int], None] = lambda node, status: None,
    ) -> None:
        self._log_dir = log_dir
        self.nodes = {
            name: SupervisedNode(name, list(command), log_dir / f"{name}.log")
            for name, command in commands.items()
        }
        self.env = dict(env)
        self.respawn_delay_s = respawn_delay_s
        self.clock = clock
        self._on_exit = on_exit
        self._stopping = False
        self._removed: list[tuple[SupervisedNode, float]] = []  # SIGINT sent, not yet exited; deadline

    def start(self) -> None:
        for node in self.nodes.values():
            node.log_path.write_text("")
            self._launch(node)

    def add(self, name: str, command: Sequence[str]) -> None:
        """Start one more process, supervised alike (a duplicated node)."""
        self.nodes[name] = SupervisedNode(name, list(command), self._log_dir / f"{name}.log")
        self._launch(self.nodes[name])

    def remove(self, name: str) -> None:
        """SIGINT to a process, no longer supervised; `poll` reaps it, with SIGKILL after STOP_TIMEOUT_S:
        waiting for its exit here would stall the caller's loop."""
        self.signal(name, signal.SIGINT)
        self._removed.append((self.nodes.pop(name), self.clock() + STOP_TIMEOUT_S))

    def signal(self, name: str, sig: int) -> None:
        """Send `sig` to a process and, unless it only pauses or continues it (SIGSTOP, SIGCONT), hold it: its
        exit is not a death, no restart until `resume`."""
        node = self.nodes[name]
        if sig not in (signal.SIGSTOP, signal.SIGCONT):
            node.held, node.restart_due_s = True, None
        if self.pid(name) is not None:
            node.process.send_signal(sig)

    def resume(self, name: str) -> None:
        """Start a held process again."""
        node = self.nodes[name]
        node.restarts += 1
        self._launch(node, note=f"{RESTART_NOTE} {node.restarts}, resumed ---\n")

    def poll(self) -> list[str]:
        """Notice the processes that died, restart those whose delay has passed; what happened, as lines."""
        events = []
        now_s = self.clock()
        for entry in list(self._removed):
            node, deadline_s = entry
            if node.process.poll() is not None:
                self._removed.remove(entry)
            elif now_s > deadline_s:
                node.process.kill()
        for node in list(self.nodes.values()):
            if self._stopping or node.gave_up or node.held:
                continue
            if node.restart_due_s is None:
                status = node.process.poll() if node.process is not None else None
                if status is None:
                    continue
                node.exits.append(status)
                self._on_exit(node, status)
                if status == EXIT_INVALID_PARAMETERS:
                    node.gave_up = f"exited {status} (it refused its parameters): not restarted"
                    events.append(f"{node.name} {node.gave_up}")
                    continue
                node.restart_due_s = now_s + self.respawn_delay_s
                events.append(
                    f"{node.name} exited {_status_text(status)}: restart in {self.respawn_delay_s:g} s"
                )
            if now_s >= node.restart_due_s:
                node.restarts += 1
                note = f"{RESTART_NOTE} {node.restarts} after exit {_status_text(node.exits[-1])} ---\n"
                self._launch(node, note)
                events.append(f"{node.name} restarted (restart {node.restarts})")
        return events

    def pid(self, name: str) -> int | None:
        """The running process id of a process (None between a death and its restart)."""
        node = self.nodes[name]
        if node.process is None or node.process.poll() is not None:
            return None
        return node.process.pid

    def processes_of(self, executable: str) -> list[str]:
        """The names of the processes running `executable` (two for a hot standby pair)."""
        return [node.name for node in self.nodes.values() if Path(node.command[0]).name == executable]

    def active(self, executable: str, names: Sequence[str] = ()) -> str | None:
        """Of the processes running `executable` (or of `names`), the name of the one holding its node's
        role (beams_common.ros.standby): the active one of a hot standby pair; None while none does."""
        names = names or self.processes_of(executable)
        if not names:
            raise KeyError(f"no process runs {executable}")
        holder_pid = role_holder_pid(self.nodes[names[0]].command, executable, self.env)
        return next((name for name in names if holder_pid is not None and self.pid(name) == holder_pid), None)

    def stop(self) -> dict[str, int]:
        """SIGINT to every process (no restart from now on), then the exit status of each (SIGKILL after
        STOP_TIMEOUT_S); a process waiting for its restart counts with the status it died with."""
        self._stopping = True
        running = [node for node in self.nodes.values() if self.pid(node.name) is not None]
        for node in running:
            node.process.send_signal(signal.SIGINT)
        statuses = {}
        for node in [*(entry[0] for entry in self._removed), *self.nodes.values()]:  # the newest last
            if node.process is None:
                statuses[node.name] = -1
                continue
            try:
                statuses[node.name] = node.process.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                node.process.kill()
                statuses[node.name] = node.process.wait(timeout=STOP_TIMEOUT_S)
        return {name: statuses[name] for name in self.nodes}

    def _launch(self, node: SupervisedNode, note: str = "") -> None:
        node.restart_due_s, node.held, node.started_s, node.rss_samples = None, False, self.clock(), []
        with open(node.log_path, "a") as log:
            log.write(note)
            log.flush()
            node.process = subprocess.Popen(
                node.command, env=self.env, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
            )


def _status_text(status: int) -> str:
    if status >= 0:
        return str(status)
    try:
        return f"{status} (signal {signal.Signals(-status).name})"
    except ValueError:  # a signal number Python does not name
        return str(status)
