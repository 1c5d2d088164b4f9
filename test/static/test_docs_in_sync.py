"""The generated documentation is the code's: the node reference's parameter tables and beams_bringup's
parameter file are the nodes' specs (one spec per parameter, documented where declared), and the README's
picture is the nodes' own graph."""

import os
import pathlib
import subprocess
import sys

import yaml

from beams_bringup.architecture_docs import picture_in
from beams_common.config.parameters import load_parameter_file, node_section
from beams_ekf.parameters import EKF_PARAMETERS
from beams_tools.parameter_docs import TABLES, markdown_table, parameter_file, tables_in
from beams_tools.robot_processes import PARAMS_FILE as PARAMS_FILE_NAME
from beams_tools.robot_processes import ROBOT_NODES
from beams_triangulation.parameters import TRIANGULATION_PARAMETERS

ROOT = pathlib.Path(__file__).resolve().parents[2]
NODES_DOC = ROOT / "docs" / "nodes.md"
README = ROOT / "README.md"
PARAMS_FILE = ROOT / "src" / "beams_bringup" / "config" / PARAMS_FILE_NAME
GENERATOR_TIMEOUT_S = 120.0


def test_every_parameter_table_in_the_node_reference_is_the_nodes_spec():
    documented = tables_in(NODES_DOC.read_text())
    assert set(documented) == set(TABLES), "docs/nodes.md lacks or names an unknown parameter table"
    for name, specs in TABLES.items():
        assert documented[name] == markdown_table(specs), (
            f"docs/nodes.md's {name} table differs from the spec: "
            "run `python -m beams_tools.parameter_docs "
            "--write docs/nodes.md`"
        )


def test_the_table_says_which_parameters_change_at_runtime():
    table = markdown_table(TABLES["triangulation_node"])
    assert "| `max_position_std_m` | `0.05` | [1.0e-09, 1000.0] | applied |" in table
    assert "| `use_odometry` | `true` |  | read-only |" in table


def test_the_readme_picture_is_the_nodes_graph(ros_env, tmp_path):
    """The generator creates every node in a process of its own, in this test's ROS domain (its own
    graph), in an empty working directory (the calibration node's relative dataset path)."""
    result = subprocess.run(
        [sys.executable, "-m", "beams_bringup.architecture_docs"],
        env={**ros_env, "PYTHONPATH": os.environ.get("PYTHONPATH", "")},
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=GENERATOR_TIMEOUT_S,
    )
    assert result.returncode == 0, result.stderr
    picture = result.stdout
    # what the picture must show, so that a generator gone blind cannot pass
    for edge in (
        "driver_node --> t_beams_bearings",
        "t_beams_bearings --> triangulation_node",
        "t_beams_bearings --> ekf_node",
        "t_beams_pose --> ekf_node",
        "t_odom --> ekf_node",
        "ekf_node --> t_beams_ekf_odometry",
        'f_map(("map")) -->|"ekf_node, /tf"| f_odom(("odom"))',
    ):
        assert edge in picture, picture
    assert picture_in(README.read_text()) == picture, (
        "README's picture differs from the nodes' graph: run `python -m beams_bringup.architecture_docs "
        "--write README.md` (in a ROS domain of its own)"
    )


def test_the_parameter_file_is_the_nodes_specs():
    assert PARAMS_FILE.read_text() == parameter_file(), (
        "beams_bringup's beams_params.yaml differs from the specs: run `python -m beams_tools.parameter_docs "
        "--write src/beams_bringup/config/beams_params.yaml`"
    )


def test_the_parameter_file_has_every_robot_node_and_the_nodes_take_it():
    """A section per node the launch file starts (and calibration_node), each one valid for its table as
    the nodes and replay_bag read it (a float written so that YAML reads a string would fail here)."""
    document = yaml.safe_load(PARAMS_FILE.read_text())
    nodes = {node.executable for node in ROBOT_NODES} | {"calibration_node"}
    assert {key.removeprefix("/**/") for key in document} == nodes
    for name, specs in TABLES.items():
        section = node_section(document, name.split()[0])
        assert {spec.name: section[spec.name] for spec in specs} == {
            spec.name: spec.default for spec in specs
        }
    for table in (TRIANGULATION_PARAMETERS, EKF_PARAMETERS):
        assert load_parameter_file(PARAMS_FILE, table) == table.defaults()
