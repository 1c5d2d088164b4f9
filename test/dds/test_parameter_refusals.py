"""Every parameter of every node, refused at start-up: for each spec of each node's table
(beams_tools.parameter_docs.TABLES), a value its spec refuses (out of range, not a choice, a list of the
wrong length, the wrong type), generated from the spec, given through a parameter file to the node's
installed executable (its console script, as setup.py names it: run_node), each in a process of its own
as a robot starts it. Each ends with status 2 and one line naming the parameter, never a traceback; a
file parameter naming a file of the wrong content is refused describing what was expected, never
echoing the file's text.

Not in this process: 153 mains in one process, each a stop timer's SIGTERM away from the next, once
froze it at 125 % CPU inside a parameter declaration for ten minutes (CI, 2026-11-28; the stack names
no signal handler, and the cause was not found); a process per case is also how the nodes run."""

import ast
import pathlib
import signal
import subprocess
import sys
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import yaml

from beams_tools.parameter_docs import TABLES

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from field_walk import bad_value

SRC = pathlib.Path(__file__).resolve().parents[2] / "src"
# a node a bad value did not stop is stopped (SIGTERM: run_node's quiet shutdown, status 0) after this
ACCEPTED_AFTER_S = 30.0  # a start-up on a loaded machine took over 5 s (SIGTERM before it judged)
STOP_TIMEOUT_S = 15.0
PARALLEL_CASES = 2  # node start-ups at once: about 1.3 s of CPU each, mostly imports
SECRET = "beams-secret-9c21"
# the parameters naming a file or a device, and the value the node needs for the table to be declared
FILE_PARAMETERS = ("calibration_file", "sim_bias_file", "dataset_file", "checkpoint_file", "device")
SOURCE = {"driver_node source sim": {"source": "sim"}, "driver_node source serial": {"source": "serial"}}
# a bad checkpoint is refused with its reason and the filter starts from its priors (docs/nodes.md)
STARTS_WITHOUT = ("checkpoint_file",)


def _mains() -> dict[str, str]:
    """{executable: "module:function"} of the nodes' console scripts."""
    mains = {}
    for setup in SRC.glob("*/setup.py"):
        for node in ast.walk(ast.parse(setup.read_text())):
            if isinstance(node, ast.keyword) and node.arg == "entry_points":
                for entry in ast.literal_eval(node.value).get("console_scripts", []):
                    name, target = (part.strip() for part in entry.split("="))
                    mains[name] = target
    return {name: target for name, target in mains.items() if name.endswith("_node")}


def _cases() -> Iterator[tuple[str, str, dict[str, Any]]]:
    """(executable, case id, parameters) for every spec of every table, and each file parameter's file."""
    for table, specs in TABLES.items():
        executable = table.split()[0]
        for spec in specs:
            yield executable, f"{table}: {spec.name}", {**SOURCE.get(table, {}), spec.name: bad_value(spec)}
            if spec.name in FILE_PARAMETERS:
                yield (
                    executable,
                    f"{table}: {spec.name} file",
                    {**SOURCE.get(table, {}), spec.name: "{secret}"},
                )


CASES = list(_cases())
MAINS = _mains()


def _run(command: list[str], env: dict[str, str]) -> tuple[int, str]:
    """Run a node; SIGTERM (run_node's quiet shutdown, status 0) if it is still running after
    ACCEPTED_AFTER_S (it accepted the value); its exit status and output."""
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        output, _ = process.communicate(timeout=ACCEPTED_AFTER_S)
    except subprocess.TimeoutExpired:
        process.send_signal(signal.SIGTERM)
        try:
            output, _ = process.communicate(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            process.kill()
            output, _ = process.communicate()
    return process.returncode, output


def test_every_node_table_is_walked():
    assert {table.split()[0] for table in TABLES} <= set(MAINS), sorted(MAINS)
    assert all(len(specs) for specs in TABLES.values())


def test_every_bad_start_up_value_is_one_line_and_exit_2(ros_env, tmp_path, installed_executable):
    secret = tmp_path / "secret.yaml"
    secret.write_text(f"{SECRET}: [unclosed\n")
    commands = []
    for k, (executable, _case, params) in enumerate(CASES):
        params = {name: str(secret) if value == "{secret}" else value for name, value in params.items()}
        params_file = tmp_path / f"params{k}.yaml"
        params_file.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
        package = MAINS[executable].split(".")[0]
        commands.append(
            # a namespace per case: nodes of one name side by side would share their role (a WARN line)
            [
                str(installed_executable(package, executable)),
                "--ros-args",
                "--params-file",
                str(params_file),
                "-r",
                f"__ns:=/case{k}",
            ]
        )
    with ThreadPoolExecutor(PARALLEL_CASES) as pool:
        outcomes = list(pool.map(lambda command: _run(command, ros_env), commands))
    failures = []
    for (_executable, case, params), (status, text) in zip(CASES, outcomes, strict=True):
        lines = [line for line in text.splitlines() if line.strip()]
        name = case.split(": ")[1].split()[0]
        expected = 0 if any(case.endswith(f"{p} file") for p in STARTS_WITHOUT) else 2
        if status != expected:
            failures.append(f"{case} = {params}: exit {status}\n{text[-1500:]}")
        elif "Traceback" in text or SECRET in text:
            failures.append(f"{case}: a traceback or the file's text\n{text[-1500:]}")
        elif expected == 2 and not (len(lines) == 1 and name in lines[0]):
            failures.append(f"{case} = {params}: {len(lines)} lines, not naming {name}\n{text[-1500:]}")
    assert not failures, f"{len(failures)} of {len(CASES)}:\n" + "\n".join(failures)
