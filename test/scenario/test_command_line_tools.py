"""Every command-line tool (setup.py's console scripts but the nodes) over bad cases generated for the
kinds of path it is given: a missing, empty, random, truncated or wrong-type input, an output it cannot
write, an argument it does not know. Each ends with status 2 and one line on stderr starting with its name
(argparse: its usage and error), never a traceback, never a file's text echoed, and leaves no output
behind; where a nominal run is cheap, status 0 comes with a usable output. The cases run the console
script's function in this process (seconds, not a Python start-up each); one per tool runs the
installed executable, with a timeout."""

import ast
import importlib
import os
import pathlib
import shutil
import subprocess
from collections.abc import Callable

import numpy as np
import pytest

from beams_calibration.dataset import save_dataset
from beams_common.calibration.calibration_file import load_calibration
from beams_sim.simulated_match import simulate_match
from beams_sim.world import EurobotTrajectory
from beams_thesis import thesis_setup
from beams_tools.bag_io import beams_typestore, read_messages
from beams_tools.bag_messages import simulated_messages, write_bag

ROOT = pathlib.Path(__file__).resolve().parents[2]
INSTALL_BASE = pathlib.Path(os.environ.get("BEAMS_INSTALL_BASE", ROOT / "install"))
TIMEOUT_S = 120.0
# what a file a tool refuses must never show of itself
SECRET = "beams-secret-4f7a"


def _console_scripts() -> dict[str, tuple[str, str]]:
    """{script: (package, "module:function")} of every package's setup.py."""
    scripts = {}
    for setup in sorted((ROOT / "src").glob("*/setup.py")):
        for node in ast.walk(ast.parse(setup.read_text())):
            if isinstance(node, ast.keyword) and node.arg == "entry_points":
                for entry in ast.literal_eval(node.value).get("console_scripts", []):
                    name, target = (part.strip() for part in entry.split("="))
                    scripts[name] = (setup.parent.name, target)
    return scripts


# The tools: every console script but the nodes (test/dds/test_parameter_refusals.py starts those) and
# the robot's nodes in one process (test/dds/test_one_process.py).
TOOLS = {n: entry for n, entry in _console_scripts().items() if not n.endswith("_node") and n != "robot"}
# How each tool is given its paths: {input kind} and {output kind}.ext placeholders, cheap settings.
USAGE = {
    "replay_bag": ["{bag}", "{out_dir}", "--plot", "{out_file}.png"],
    "estimate_noise": ["{still_bags}", "-o", "{out_file}.yaml"],
    "calibrate": ["{dataset}", "-o", "{out_file}.yaml", "--no-leave-one-out"],
    "calibration_session": ["--wait", "0.5", "--yes"],  # no calibration_node in its domain
    "simulate_thesis_dataset": ["{out_file}.yaml"],
    "variance_plot": ["--family", "2", "--max-window", "2", "--output", "{out_file}.png"],
    "error_map": ["--step", "0.25", "--sigma-deg", "1", "-o", "{out_file}.png"],
    "demo": ["--duration", "1", "--output", "{out_dir}"],
    "fault_campaign": ["--duration", "1", "--output", "{out_dir}"],
    "virtual_turret": ["--link", "{out_file}.pty", "--firmware", "/nonexistent/turret.elf"],
}
# A tool's cheap nominal run and what makes its output usable (None: no cheap run).
NOMINAL: dict[str, Callable[[pathlib.Path], bool] | None] = {
    "replay_bag": lambda out: any(
        t == "/beams/ekf/odometry" for t, _, _ in read_messages(out, beams_typestore())
    ),
    "calibrate": lambda out: load_calibration(out) is not None,
    "variance_plot": lambda out: out.stat().st_size > 10_000,
    "error_map": lambda out: out.stat().st_size > 10_000,
    "estimate_noise": None,  # test_estimate_noise_cli.py: minutes of still bags
    "calibration_session": None,  # test/dds/test_calibration_guided_session.py
    "simulate_thesis_dataset": None,  # a minute of simulation; calibrate's nominal run reads such a dataset
    "demo": None,  # a simulated match over DDS
    "fault_campaign": None,  # test/dds/test_fault_campaign.py
    "virtual_turret": None,  # runs until interrupted: test/dds/test_virtual_turret.py
}


def _bag_cases(good: pathlib.Path, directory: pathlib.Path, typestore) -> dict[str, pathlib.Path]:
    """Bad bags: none, an empty directory, random bytes, a truncated recording, text where the metadata
    goes, a bearings topic of the wrong type, a bag without the expected topics."""
    random_bytes = directory / "random.mcap"
    random_bytes.write_bytes(np.random.default_rng(3).bytes(4096))
    (directory / "empty_dir").mkdir()
    truncated = shutil.copytree(good, directory / "truncated")
    for storage_file in truncated.glob("*.mcap"):
        storage_file.write_bytes(storage_file.read_bytes()[: storage_file.stat().st_size // 2])
    metadata = shutil.copytree(good, directory / "bad_metadata")
    (metadata / "metadata.yaml").write_text(f"{SECRET}: [unclosed\n")
    text = typestore.types["std_msgs/msg/String"]
    odometry = [m for m in read_messages(good, typestore) if m[0] == "/odom"][:50]
    wrong = [(t, "/beams/bearings", "std_msgs/msg/String", text(data=SECRET)) for t in range(1, 50)]
    return {
        "missing": directory / "no_such_bag",
        "empty_dir": directory / "empty_dir",
        "random_bytes": random_bytes,
        "truncated": truncated,
        "bad_metadata": metadata,
        "wrong_type": write_bag(directory / "wrong_type", wrong, typestore),
        "no_bearings": write_bag(
            directory / "no_bearings",
            [(t, topic, "nav_msgs/msg/Odometry", m) for topic, t, m in odometry],
            typestore,
        ),
    }


def _file_cases(directory: pathlib.Path, good: pathlib.Path) -> dict[str, pathlib.Path]:
    """Bad YAML files: none, empty, random bytes, a directory, text that is no YAML, the wrong shape,
    a truncated one."""
    cases = {"missing": directory / "no_such.yaml", "directory": directory}
    contents = {
        "empty": b"",
        "random_bytes": np.random.default_rng(4).bytes(2048),
        "not_yaml": f"{SECRET}: [unclosed\n".encode(),
        "wrong_shape": f"- {SECRET}\n- 2\n".encode(),
        "truncated": good.read_bytes()[: good.stat().st_size // 2],
    }
    for name, content in contents.items():
        cases[name] = directory / f"{name}.yaml"
        cases[name].write_bytes(content)
    return cases


@pytest.fixture(scope="module")
def paths(tmp_path_factory) -> dict[str, dict[str, pathlib.Path]]:
    """{kind: {case: path}}, "good" the nominal input of each kind."""
    directory = tmp_path_factory.mktemp("inputs")
    typestore = beams_typestore()
    match = simulate_match(8.0, seed=5)
    bag = write_bag(directory / "bag", simulated_messages(match, typestore), typestore)
    still = [
        write_bag(
            directory / f"still{k}",
            simulated_messages(
                simulate_match(12.0, k, trajectory=EurobotTrajectory.static(pose, 12.0)), typestore
            ),
            typestore,
        )
        for k, pose in enumerate([(1.5, 1.0, 0.0), (0.9, 1.2, 1.0), (2.0, 0.5, -2.0)])
    ]
    dataset = directory / "dataset.yaml"
    save_dataset(thesis_setup.geometric_dataset(thesis_setup.reference_poses()), dataset)
    (directory / "bags").mkdir()
    (directory / "files").mkdir()
    bags = _bag_cases(bag, directory / "bags", typestore)
    return {
        "bag": {"good": bag, **bags},
        "still_bags": {"good": still, **bags},
        "dataset": {"good": dataset, **_file_cases(directory / "files", dataset)},
    }


def _unwritable(directory: pathlib.Path) -> dict[str, pathlib.Path]:
    """Where an output cannot go: under a regular file, in a read-only directory (/proc for root)."""
    (directory / "a_file").write_text("not a directory")
    read_only = directory / "read_only"
    read_only.mkdir(exist_ok=True)
    read_only.chmod(0o555)
    return {
        "under_a_file": directory / "a_file" / "x",
        "read_only_dir": pathlib.Path("/proc/beams") if os.geteuid() == 0 else read_only / "x",
    }


def _arguments(tool: str, inputs: dict[str, object], outputs: dict[str, pathlib.Path]) -> list[str]:
    arguments = []
    for token in USAGE[tool]:
        kind, _, extension = token.strip("{").partition("}")
        if token.startswith("{") and kind in outputs:
            arguments.append(f"{outputs[kind]}{extension}")
        elif token.startswith("{"):
            value = inputs[kind]
            arguments += [str(v) for v in value] if isinstance(value, list) else [str(value)]
        else:
            arguments.append(token)
    return arguments


def _run(tool: str, arguments: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    """The installed executable."""
    package = TOOLS[tool][0]
    command = INSTALL_BASE / package / "lib" / package / tool
    if not command.exists():
        pytest.fail(f"{command} is not installed: run `make build`")
    return subprocess.run(
        [str(command), *arguments],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        env=env,
        stdin=subprocess.DEVNULL,
    )


def _call(tool: str, arguments: list[str], capfd) -> subprocess.CompletedProcess:
    """The console script's function in this process (its exit status, its output)."""
    module, function = TOOLS[tool][1].split(":")
    main = getattr(importlib.import_module(module), function)
    capfd.readouterr()
    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr("sys.argv", [tool])  # argparse's program name, as the installed script's
            status = main(arguments)
    except SystemExit as exit_status:  # argparse
        status = exit_status.code
    except Exception as error:  # the console script would have shown a traceback
        return subprocess.CompletedProcess(arguments, 1, "", f"Traceback: {error!r} escaped")
    output = capfd.readouterr()
    return subprocess.CompletedProcess(arguments, status, output.out, output.err)


def _refused(tool: str, result: subprocess.CompletedProcess, usage_error: bool) -> str:
    """Why the run is not a clean refusal, or ''."""
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    if result.returncode != 2:
        return f"exit status {result.returncode}"
    if "Traceback" in result.stderr + result.stdout or SECRET in result.stderr + result.stdout:
        return "a traceback or the file's text"
    if usage_error:
        return "" if lines and lines[-1].startswith(f"{tool}: error:") else "no argparse error"
    return "" if len(lines) == 1 and lines[0].startswith(f"{tool}: ") else f"{len(lines)} lines on stderr"


def test_every_tool_has_its_usage_here():
    assert set(TOOLS) == set(USAGE) == set(NOMINAL)


@pytest.mark.parametrize("tool", sorted(USAGE))
def test_a_tool_refuses_bad_input_in_one_line_and_writes_nothing(tool, paths, ros_env, tmp_path, capfd):
    """Every bad case of every kind of path the tool takes, each against the nominal others; each case
    writes its nominal outputs into a directory of its own, which must stay empty."""
    kinds = [t.strip("{").partition("}")[0] for t in USAGE[tool] if t.startswith("{")]
    good_inputs = {kind: paths[kind]["good"] for kind in kinds if kind in paths}
    output_kinds = [kind for kind in kinds if kind.startswith("out_")]
    cases: list[tuple[str, dict, dict, bool]] = [("unknown option", good_inputs, {}, True)]
    for kind in good_inputs:
        cases += [
            (f"{kind} {case}", {**good_inputs, kind: path}, {}, False) for case, path in paths[kind].items()
        ]
    for kind in output_kinds:
        cases += [
            (f"{kind} {case}", good_inputs, {kind: path}, False)
            for case, path in _unwritable(tmp_path).items()
        ]
    if not kinds:  # calibration_session: no calibration_node in its domain
        cases.append(("no node to talk to", {}, {}, False))
    runs = []
    for k, (name, inputs, unwritable, usage_error) in enumerate(
        c for c in cases if not c[0].endswith(" good")
    ):
        out = tmp_path / f"case{k}"
        out.mkdir()
        arguments = _arguments(tool, inputs, {kind: out / kind for kind in output_kinds} | unwritable)
        runs.append((name, out, [*arguments, "--no-such-option"] if usage_error else arguments, usage_error))
    failures = []
    # the first refusal past argparse again through the installed executable: the console script's own
    # exit status (a missing input where the tool takes one: refused before any work)
    for k, (name, out, arguments, usage_error) in enumerate([*runs, runs[1]]):
        installed = k == len(runs)
        result = _run(tool, arguments, ros_env) if installed else _call(tool, arguments, capfd)
        problem = _refused(tool, result, usage_error)
        left = sorted(p.name for p in out.iterdir())
        if problem or left:
            where = "installed" if installed else "in process"
            failures.append(
                f"{name} ({where}): {problem or f'left {left}'} ({arguments})\n{result.stderr[-2000:]}"
            )
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize("tool", sorted(t for t, usable in NOMINAL.items() if usable))
def test_status_0_comes_with_a_usable_output(tool, paths, tmp_path, capfd):
    kinds = [t.strip("{").partition("}")[0] for t in USAGE[tool] if t.startswith("{")]
    inputs = {kind: paths[kind]["good"] for kind in kinds if kind in paths}
    outputs = {kind: tmp_path / kind for kind in kinds if kind.startswith("out_")}
    arguments = _arguments(tool, inputs, outputs)
    result = _call(tool, arguments, capfd)
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    main_output = next(pathlib.Path(a) for a in arguments if a.startswith(str(tmp_path)))
    assert NOMINAL[tool](main_output), arguments
