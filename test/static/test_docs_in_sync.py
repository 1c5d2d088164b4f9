"""The generated documentation is the code's: the node reference's parameter tables are the nodes' specs
(one spec per parameter, documented where declared), and the README's picture is the nodes' own graph."""

import os
import pathlib
import subprocess
import sys

from beams_bringup.architecture_docs import picture_in
from beams_tools.parameter_docs import TABLES, markdown_table, tables_in

ROOT = pathlib.Path(__file__).resolve().parents[2]
NODES_DOC = ROOT / "docs" / "nodes.md"
README = ROOT / "README.md"
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
    assert "| `max_position_std_m` | `0.05` | [1e-09, 1000.0] | applied |" in table
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
