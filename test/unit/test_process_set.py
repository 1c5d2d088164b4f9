"""The robot's process set is described once (beams_tools.robot_processes): the launch file, the demo's
supervisor and the fault campaign start exactly the processes it lists, with its hot standby pairs, its
one-process option and its respawn delay. The launch file is run on stand-ins for launch and launch_ros (the
PyPI wheels lack them; test_ros2_cli.py runs the real tool where it is installed); the demo's and the
campaign's command lines are built as they run them."""

import importlib.util
import pathlib
import sys
import types

import pytest

from beams_tools.robot_processes import (
    DISCOVERY_PROFILE,
    ONE_PROCESS,
    ONE_PROCESS_NODES,
    PARAMS_FILE,
    RESPAWN_DELAY_S,
    ROBOT_NODES,
    RobotNode,
    robot_processes,
)

LAUNCH_FILE = pathlib.Path(__file__).resolve().parents[2] / "src/beams_bringup/launch/beams.launch.py"


def described(standby: bool, one_process: bool = False) -> dict[str, list[list[str]]]:
    """executable -> the arguments (before --ros-args) of each of its processes."""
    return {
        node.executable: sorted(node.processes(standby).values()) for node in robot_processes(one_process)
    }


def started(commands: dict[str, list[str]]) -> dict[str, list[list[str]]]:
    processes: dict[str, list[list[str]]] = {}
    for command in commands.values():
        processes.setdefault(pathlib.Path(command[0]).name, []).append(
            command[1 : command.index("--ros-args")]
        )
    return {executable: sorted(arguments) for executable, arguments in processes.items()}


@pytest.fixture
def fake_install(monkeypatch):
    """Installed executables named by their path (only the command lines are built)."""
    monkeypatch.setattr(RobotNode, "installed", lambda node, base: f"{base}/{node.package}/{node.executable}")
    return pathlib.Path("/nonexistent")


class _Recorded:
    """A launch action or substitution: what it was given."""

    def __init__(self, *args, **kwargs) -> None:
        self.args, self.kwargs = args, kwargs


def _launch_stand_ins(monkeypatch) -> None:
    names = {
        "launch": ("Condition", "LaunchDescription"),
        "launch.actions": ("DeclareLaunchArgument", "SetEnvironmentVariable"),
        "launch.conditions": ("IfCondition", "UnlessCondition"),
        "launch.substitutions": (
            "AndSubstitution",
            "NotSubstitution",
            "EnvironmentVariable",
            "EqualsSubstitution",
            "LaunchConfiguration",
            "PathJoinSubstitution",
        ),
        "launch_ros.actions": ("Node",),
        "launch_ros.substitutions": ("FindPackageShare",),
    }
    for module_name, classes in names.items():
        module = types.ModuleType(module_name)
        for name in classes:
            setattr(module, name, type(name, (_Recorded,), {}))
        monkeypatch.setitem(sys.modules, module_name, module)
    monkeypatch.setitem(sys.modules, "launch_ros", types.ModuleType("launch_ros"))


def _true(substitution, arguments: dict[str, str]) -> bool:
    """A launch condition's substitution evaluated for the launch arguments, as launch does."""
    kind, values = type(substitution).__name__, substitution.args
    if kind == "LaunchConfiguration":
        return arguments[values[0]] == "true"
    if kind == "EqualsSubstitution":
        return arguments[values[0].args[0]] == values[1]
    if kind == "NotSubstitution":
        return not _true(values[0], arguments)
    assert kind == "AndSubstitution", kind
    return _true(values[0], arguments) and _true(values[1], arguments)


def _runs(node_action, standby: bool, source: str, virtual_turret: bool, one_process: bool = False) -> bool:
    """Whether a Node action runs with its standby argument `standby`, the source `source` and the
    arguments `virtual_turret` and `one_process`."""
    condition = node_action.kwargs["condition"]
    if condition is None:
        return True
    flags = {"ekf_standby": standby, "virtual_turret": virtual_turret, "one_process": one_process}
    arguments = {"source": source, **{name: str(flag).lower() for name, flag in flags.items()}}
    value = _true(condition.args[0], arguments)
    return value if type(condition).__name__ == "IfCondition" else not value


@pytest.mark.parametrize("one_process", [False, True])
@pytest.mark.parametrize("standby", [True, False])
@pytest.mark.parametrize(("source", "virtual_turret"), [("sim", False), ("serial", False), ("serial", True)])
def test_the_launch_file_starts_the_described_processes(
    monkeypatch, standby, source, virtual_turret, one_process
):
    _launch_stand_ins(monkeypatch)
    spec = importlib.util.spec_from_file_location("beams_launch", LAUNCH_FILE)
    launch = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(launch)
    actions = launch.generate_launch_description().args[0]
    nodes = [action for action in actions if type(action).__name__ == "Node"]
    (turret,) = [n for n in nodes if n.kwargs["executable"] == "virtual_turret"]  # beside the robot's nodes
    assert turret.kwargs["package"] == "beams_sim" and not turret.kwargs.get("respawn")
    link, device = turret.kwargs["arguments"]
    assert link == "--link" and device.args == ("device",)  # the driver's device
    assert turret.kwargs["parameters"][0].args[0][-1] == PARAMS_FILE  # sim_world_node's section: its world
    nodes.remove(turret)
    assert {(n.kwargs["package"], n.kwargs["executable"]) for n in nodes} == {
        (node.package, node.executable) for node in (*ROBOT_NODES, ONE_PROCESS)
    }
    assert all(n.kwargs["respawn"] and n.kwargs["respawn_delay"] == RESPAWN_DELAY_S for n in nodes)
    assert all(n.kwargs["parameters"][0].args[0][-1] == PARAMS_FILE for n in nodes)
    running: dict[str, list[list[str]]] = {}
    assert _runs(turret, standby, source, virtual_turret, one_process) == virtual_turret
    for n in nodes:
        if _runs(n, standby, source, virtual_turret, one_process):
            running.setdefault(n.kwargs["executable"], []).append(n.kwargs["arguments"])
    expected = {
        executable: arguments
        for executable, arguments in described(standby, one_process).items()
        if source == "sim" or executable != "sim_world_node"
    }
    assert {executable: sorted(arguments) for executable, arguments in running.items()} == expected
    standby_arguments = {a.args[0] for a in actions if type(a).__name__ == "DeclareLaunchArgument"}
    assert {node.standby_argument for node in ROBOT_NODES if node.hot_standby} <= standby_arguments
    profile = next(a for a in actions if type(a).__name__ == "SetEnvironmentVariable")
    assert profile.args[1].kwargs["default_value"].args[0][-1] == DISCOVERY_PROFILE
    # the docstring says the delay
    assert f"({RESPAWN_DELAY_S:g} s)" in LAUNCH_FILE.read_text()


@pytest.mark.parametrize("one_process", [False, True])
@pytest.mark.parametrize("standby", [True, False])
def test_the_demo_supervises_the_described_processes(
    monkeypatch, tmp_path, fake_install, standby, one_process
):
    from beams_bringup import demo
    from beams_sim.simulated_match import SENSOR_MODELS
    from beams_tools.supervisor import NodeSupervisor

    monkeypatch.setattr(demo, "installed_params_file", lambda: tmp_path / PARAMS_FILE)
    monkeypatch.setattr(demo, "INSTALL_BASE", fake_install)
    sensor = demo.sensor_setup(SENSOR_MODELS[0], tmp_path, False)
    commands = demo.node_commands(90.0, sensor, standby, one_process)
    assert started(commands) == described(standby, one_process)
    assert set(commands) == {
        name for node in robot_processes(one_process) for name in node.processes(standby)
    }
    driver = ONE_PROCESS.executable if one_process else "driver_node"
    assert commands[driver][-len(sensor.driver_arguments) :] == list(sensor.driver_arguments)
    assert all(
        command[command.index("--ros-args") + 2] == str(tmp_path / PARAMS_FILE)
        for command in commands.values()
    )
    assert NodeSupervisor(commands, {}, tmp_path).respawn_delay_s == RESPAWN_DELAY_S


def test_the_campaign_runs_the_described_processes_its_relay_and_the_calibration_node(tmp_path, fake_install):
    from beams_tools.campaign_command import Campaign, CampaignConfig

    campaign = Campaign(CampaignConfig(install_base=fake_install, output_dir=tmp_path))
    commands = {name: node.command for name, node in campaign.processes.nodes.items()}
    assert started(commands) == {**described(True), "fault_relay_node": [[]], "calibration_node": [[]]}
    assert campaign.processes.respawn_delay_s == RESPAWN_DELAY_S
    # ekf_node's checkpoint in the campaign's own directory: no run resumes from another's
    assert campaign.processes.env["ROS_HOME"].startswith(str(tmp_path))
    # a node's first process is named as the schedule names the node (a kill's, a duplicate's)
    assert {node.name for node in ROBOT_NODES} <= set(commands)


def test_the_respawn_delay_is_short_but_not_zero():
    # short enough for issue 18's 2 s (a node's start-up takes the rest), not zero (a crash loop idles)
    assert 0.1 <= RESPAWN_DELAY_S <= 0.5


def test_the_one_process_robot_runs_the_described_nodes():
    """beams_bringup's robot runs the nodes robot_processes says, each class from its node's module."""
    from beams_bringup.robot import NODES

    assert [cls.__module__ for cls in NODES] == [f"{n.package}.{n.executable}" for n in ONE_PROCESS_NODES]
