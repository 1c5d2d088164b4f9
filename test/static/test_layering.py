"""The layout's rules, checked on the source (DEVELOPING.md): a package imports only from the packages
drawn above it (no cycle), and rclpy only in the ROS wiring (the `*_node.py` modules, the ROS clients
`*_command.py`, beams_common.ros, the demo, the picture generator). Entry points are imports too: a
package's (setup.py) point into itself, and a package declares entries only in a group that a package
drawn above it consumes (beams_sim's `sim` edge source in beams_driver's `beams_driver.edge_sources`)."""

import ast
import pathlib

import pytest

SRC = pathlib.Path(__file__).resolve().parents[2] / "src"
# what each package may import from the project's packages (beams_msgs: the interfaces, for the ROS side)
ALLOWED = {
    "beams_common": {"beams_msgs"},
    "beams_driver": {"beams_common", "beams_msgs"},
    "beams_sim": {"beams_common", "beams_driver", "beams_msgs"},
    "beams_triangulation": {"beams_common", "beams_msgs"},
    "beams_ekf": {"beams_common", "beams_msgs"},
    "beams_calibration": {"beams_common", "beams_driver", "beams_triangulation", "beams_msgs"},
    # the thesis's reproductions and the offline evaluations: stand on the robot's packages, nothing of
    # the running robot stands on them
    "beams_thesis": {
        "beams_common",
        "beams_driver",
        "beams_sim",
        "beams_triangulation",
        "beams_ekf",
        "beams_calibration",
        "beams_msgs",
    },
    # the tools (issue 18's fault campaign, the offline bag replay and its bag and trajectory tooling, the
    # node reference's generator) and the robot's process set with its runner (robot_processes,
    # supervisor: read by beams_bringup's launch file and demo and by the campaign, so they live below
    # both): stand on the robot's packages
    "beams_tools": {
        "beams_common",
        "beams_driver",
        "beams_sim",
        "beams_triangulation",
        "beams_ekf",
        "beams_calibration",
        "beams_msgs",
    },
    # launch, parameters and the demo's wiring (the demo records its bag with the tools): the top
    "beams_bringup": {
        "beams_common",
        "beams_driver",
        "beams_sim",
        "beams_triangulation",
        "beams_ekf",
        "beams_calibration",
        "beams_tools",
        "beams_msgs",
    },
}
ROS_MODULES = ("rclpy", "launch", "launch_ros")


def _imports(path: pathlib.Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def _modules(package: str) -> list[pathlib.Path]:
    return sorted((SRC / package / package).rglob("*.py"))


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_a_package_imports_only_from_the_packages_above_it(package):
    project = set(ALLOWED) | {"beams_msgs"}
    wrong = {
        f"{path.relative_to(SRC)} imports {name}"
        for path in _modules(package)
        for name in _imports(path) & project - {package}
        if name not in ALLOWED[package]
    }
    assert not wrong, sorted(wrong)


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_rclpy_only_in_the_ros_wiring(package):
    def ros_side(path: pathlib.Path) -> bool:
        ros_files = ("_node.py", "_command.py")
        # the demo runs the nodes; architecture_docs creates them to read their graph
        ros_tools = ("demo.py", "architecture_docs.py")
        return path.name.endswith(ros_files) or "ros" in path.parts[-2:-1] or path.name in ros_tools

    wrong = [
        str(path.relative_to(SRC))
        for path in _modules(package)
        if not ros_side(path) and _imports(path) & set(ROS_MODULES)
    ]
    assert not wrong, wrong


def _entry_points(package: str) -> dict[str, list[str]]:
    """The entry_points setup.py declares: {group: ["name = module:attribute", ...]}."""
    for node in ast.walk(ast.parse((SRC / package / "setup.py").read_text())):
        if isinstance(node, ast.keyword) and node.arg == "entry_points":
            return ast.literal_eval(node.value)
    return {}


def _string_constants(package: str) -> set[str]:
    return {
        node.value
        for path in _modules(package)
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.Constant) and isinstance(node.value, str)
    }


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_a_package_declares_entry_points_into_itself_in_groups_consumed_above_it(package):
    wrong = []
    for group, entries in _entry_points(package).items():
        wrong += [
            f"{group}: {entry}" for entry in entries if entry.split("=")[1].strip().split(".")[0] != package
        ]
        if group == "console_scripts":
            continue
        # the consumer holds the group's name (importlib.metadata.entry_points(group=...))
        consumers = [other for other in sorted(ALLOWED) if group in _string_constants(other)]
        wrong += [f"{group}: no package consumes it"] if not consumers else []
        wrong += [
            f"{group}: consumed by {c}, not above {package}" for c in consumers if c not in ALLOWED[package]
        ]
    assert not wrong, wrong
