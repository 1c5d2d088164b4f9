"""Every parameter of every node, refused at start-up: for each spec of each node's table
(beams_tools.parameter_docs.TABLES), a value its spec refuses (out of range, not a choice, a list of the
wrong length, the wrong type), generated from the spec, given through a parameter file to the node's
console script run in this process (its `main`, as setup.py names it: run_node). Each ends with status 2
and one line naming the parameter, never a traceback; a file parameter naming a file of the wrong content
is refused describing what was expected, never echoing the file's text."""

import ast
import contextlib
import importlib
import pathlib
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

import pytest
import yaml

from beams_tools.parameter_docs import TABLES

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from field_walk import bad_value

SRC = pathlib.Path(__file__).resolve().parents[2] / "src"
# a node a bad value did not stop is stopped (SIGTERM: run_node's quiet shutdown, status 0) after this
ACCEPTED_AFTER_S = 5.0
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


@contextlib.contextmanager
def _stopped_after(timeout_s: float) -> Iterator[None]:
    """SIGTERM to this process after timeout_s (a node that accepted the value), signals restored after."""
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    timer = threading.Timer(timeout_s, signal.raise_signal, (signal.SIGTERM,))
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        for number, handler in handlers.items():
            signal.signal(number, handler)


def test_every_node_table_is_walked():
    assert {table.split()[0] for table in TABLES} <= set(MAINS), sorted(MAINS)
    assert all(len(specs) for specs in TABLES.values())


def test_every_bad_start_up_value_is_one_line_and_exit_2(ros_env, tmp_path, capfd):
    secret = tmp_path / "secret.yaml"
    secret.write_text(f"{SECRET}: [unclosed\n")
    failures = []
    for k, (executable, case, params) in enumerate(CASES):
        params = {name: str(secret) if value == "{secret}" else value for name, value in params.items()}
        params_file = tmp_path / f"params{k}.yaml"
        params_file.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
        module, function = MAINS[executable].split(":")
        main = getattr(importlib.import_module(module), function)
        capfd.readouterr()
        with _stopped_after(ACCEPTED_AFTER_S), pytest.raises(SystemExit) as exit_status:
            main([executable, "--ros-args", "--params-file", str(params_file)])
        output = capfd.readouterr()
        text = output.out + output.err
        lines = [line for line in text.splitlines() if line.strip()]
        name = case.split(": ")[1].split()[0]
        expected = 0 if any(case.endswith(f"{p} file") for p in STARTS_WITHOUT) else 2
        if exit_status.value.code != expected:
            failures.append(f"{case} = {params}: exit {exit_status.value.code}\n{text[-1500:]}")
        elif "Traceback" in text or SECRET in text:
            failures.append(f"{case}: a traceback or the file's text\n{text[-1500:]}")
        elif expected == 2 and not (len(lines) == 1 and name in lines[0]):
            failures.append(f"{case} = {params}: {len(lines)} lines, not naming {name}\n{text[-1500:]}")
    assert not failures, f"{len(failures)} of {len(CASES)}:\n" + "\n".join(failures)
