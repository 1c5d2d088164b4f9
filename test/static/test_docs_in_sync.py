"""The README's parameter tables are the nodes' specs: one spec per parameter, documented where declared."""

import pathlib

from beams_bringup.parameter_docs import TABLES, markdown_table, tables_in

README = pathlib.Path(__file__).resolve().parents[3] / "README.md"


def test_every_parameter_table_in_the_readme_is_the_nodes_spec():
    documented = tables_in(README.read_text())
    assert set(documented) == set(TABLES), "README lacks or names an unknown parameter table"
    for name, specs in TABLES.items():
        assert documented[name] == markdown_table(specs), (
            f"README's {name} table differs from the spec: run `python -m beams_bringup.parameter_docs "
            "--write README.md`"
        )


def test_the_table_says_which_parameters_change_at_runtime():
    table = markdown_table(TABLES["triangulation_node"])
    assert "| `max_position_std_m` | `0.05` | [1e-09, 1000.0] | applied |" in table
    assert "| `use_odometry` | `true` |  | read-only |" in table
