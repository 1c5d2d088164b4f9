"""The demo's process runner: the robot's nodes as child processes, each restarted when it dies.

What `ros2 launch` does with `respawn=True, respawn_delay=RESPAWN_DELAY_S` (beams.launch.py), for the
environments without launch (the PyPI wheels): a node that exits while the supervisor is not stopping is
started again, with the same command, RESPAWN_DELAY_S later; its log file gets a line saying so and the
output of the new process. A node that refused its parameters at start-up (exit status 2, run_node's
EXIT_INVALID_PARAMETERS) is not restarted: it would refuse them again. A node with a hot standby is two
processes (beams_tools.robot_processes.RobotNode.processes), each restarted alike; `active` names the one that
holds the node's role.
"""

import signal
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from beams_common.standby import role_holder_pid
from beams_tools.robot_processes import RESPAWN_DELAY_S

EXIT_INVALID_PARAMETERS = 2  # run_node's start-up refusal (beams_common.ros.node_support)
STOP_TIMEOUT_S = 15.0


@dataclass
class SupervisedNode:
    """One node the supervisor runs: its command, its current process and its restarts."""

    name: str
    command: Sequence[str]
    log_path: Path
    process: subprocess.Popen | None = None
    restarts: int = 0
    exits: list[int] = field(default_factory=list)
    restart_due_s: float | None = None  # when the next start is due (after a death)
    gave_up: str = ""  # why it is not restarted ('' while it is)


class NodeSupervisor:
    """Start every node, restart each one that dies (`poll`, called from the caller's loop), stop all."""

    def __init__(
        self,
        commands: Mapping[str, Sequence[str]],
        env: Mapping[str, str],
        log_dir: Path,
        respawn_delay_s: float = RESPAWN_DELAY_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.nodes = {
            name: SupervisedNode(name, list(command), log_dir / f"{name}.log")
            for name, command in commands.items()
        }
        self._env = dict(env)
        self.respawn_delay_s = respawn_delay_s
        self._clock = clock
        self._stopping = False

    def start(self) -> None:
        for node in self.nodes.values():
            node.log_path.write_text("")
            self._launch(node)

    def poll(self) -> list[str]:
        """Notice the nodes that died and restart those whose delay has passed; what happened, as lines."""
        events = []
        now_s = self._clock()
        for node in self.nodes.values():
            if self._stopping or node.gave_up:
                continue
            if node.restart_due_s is None:
                status = node.process.poll() if node.process is not None else None
                if status is None:
                    continue
                node.exits.append(status)
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
                self._launch(
                    node, note=f"--- restart {node.restarts} after exit {_status_text(node.exits[-1])} ---\n"
                )
                events.append(f"{node.name} restarted (restart {node.restarts})")
        return events

    def pid(self, name: str) -> int | None:
        """The running process id of a node (None between a death and its restart)."""
        node = self.nodes[name]
        if node.process is None or node.process.poll() is not None:
            return None
        return node.process.pid

    def processes_of(self, executable: str) -> list[str]:
        """The names of the processes running `executable` (two for a hot standby pair)."""
        return [node.name for node in self.nodes.values() if Path(node.command[0]).name == executable]

    def active(self, executable: str) -> str | None:
        """Of the processes running `executable`, the name of the one holding its node's role
        (beams_common.standby): the active one of a hot standby pair; None while none does."""
        names = self.processes_of(executable)
        if not names:
            raise KeyError(f"no process runs {executable}")
        holder_pid = role_holder_pid(self.nodes[names[0]].command, executable, self._env)
        return next((name for name in names if holder_pid is not None and self.pid(name) == holder_pid), None)

    def stop(self) -> dict[str, int]:
        """SIGINT to every node (no restart from now on), then the exit status of each (SIGKILL after
        STOP_TIMEOUT_S); a node waiting for its restart counts with the status it died with."""
        self._stopping = True
        running = [
            node for node in self.nodes.values() if node.process is not None and node.process.poll() is None
        ]
        for node in running:
            node.process.send_signal(signal.SIGINT)
        statuses = {}
        for node in self.nodes.values():
            if node in running:
                try:
                    statuses[node.name] = node.process.wait(timeout=STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    node.process.kill()
                    statuses[node.name] = node.process.wait(timeout=STOP_TIMEOUT_S)
            else:
                statuses[node.name] = node.process.poll() if node.process is not None else -1
        return statuses

    def _launch(self, node: SupervisedNode, note: str = "") -> None:
        node.restart_due_s = None
        log: TextIO
        with open(node.log_path, "a") as log:
            log.write(note)
            log.flush()
            node.process = subprocess.Popen(
                node.command, env=self._env, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
            )


def _status_text(status: int) -> str:
    if status >= 0:
        return str(status)
    try:
        return f"{status} (signal {signal.Signals(-status).name})"
    except ValueError:  # a signal number Python does not name
        return str(status)
