"""One fact, which nodes run as a hot standby pair (issue 18): the launch file and the demo read it from
beams_bringup.system (RobotNode.hot_standby); the fault campaign, which starts its own processes and
cannot import beams_bringup (test_layering.py), keeps HOT_STANDBY, checked here against system.py's
node list from the sources (no ROS needed)."""

import ast
import pathlib

SRC = pathlib.Path(__file__).resolve().parents[2] / "src"


def _assigned(path: pathlib.Path, name: str):
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError(f"{path} has no {name}")


def _system_standby_executables() -> set[str]:
    tree = ast.parse((SRC / "beams_bringup" / "beams_bringup" / "system.py").read_text())
    executables = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "RobotNode":
            keywords = {k.arg: ast.literal_eval(k.value) for k in node.keywords}
            if keywords.get("hot_standby"):
                executables.add(ast.literal_eval(node.args[1]))
    return executables


def test_the_campaign_runs_the_hot_standby_pairs_the_launch_file_runs():
    campaign = SRC / "beams_tools" / "beams_tools" / "campaign_command.py"
    processes, pairs = _assigned(campaign, "PROCESSES"), _assigned(campaign, "HOT_STANDBY")
    standby = _system_standby_executables()
    assert standby, "system.py names no hot standby node"
    assert {processes[first][1] for first in pairs} == standby
    # the pair's two processes run one executable, with one set of remaps
    assert all(processes[first] == processes[second] for first, second in pairs.items())
