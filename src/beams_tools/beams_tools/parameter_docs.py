"""The node reference's parameter tables (docs/nodes.md, between `<!-- parameters: NAME -->` and `<!--
/parameters -->`) and beams_bringup's parameter file, written from the nodes' ParameterTables so that neither
drifts from what the nodes declare (test/static/test_docs_in_sync.py).

`python -m beams_tools.parameter_docs` prints every node's table; `--write docs/nodes.md` replaces the tables
between the markers, `--write src/beams_bringup/config/beams_params.yaml` the parameter file."""

import argparse
import pathlib
import re
import sys
import textwrap

from beams_calibration.parameters import CALIBRATION_PARAMETERS
from beams_common.config.parameters import ParameterSpec
from beams_driver import serial_source
from beams_driver.parameters import DRIVER_PARAMETERS
from beams_ekf.parameters import EKF_PARAMETERS
from beams_sim import sim_source
from beams_sim.parameters import SIM_WORLD_PARAMETERS
from beams_triangulation.parameters import TRIANGULATION_PARAMETERS

TABLES: dict[str, tuple[ParameterSpec, ...]] = {
    "driver_node": DRIVER_PARAMETERS.specs,
    "driver_node source sim": sim_source.EDGE_SOURCE.parameters,
    "driver_node source serial": serial_source.EDGE_SOURCE.parameters,
    "sim_world_node": SIM_WORLD_PARAMETERS.specs,
    "triangulation_node": TRIANGULATION_PARAMETERS.specs,
    "ekf_node": EKF_PARAMETERS.specs,
    "calibration_node": CALIBRATION_PARAMETERS.specs,
}
_BLOCK = re.compile(r"(<!-- parameters: (?P<name>[^>]+?) -->\n)(?P<body>.*?)(<!-- /parameters -->)", re.S)


def _value(value: object) -> str:
    """A value as YAML 1.1 (PyYAML) and rcl both read it back: a float's exponent needs a dot."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    text = repr(value) if isinstance(value, float) else str(value)
    return text.replace("e", ".0e") if "e" in text and "." not in text else text


def _limits(spec: ParameterSpec) -> str:
    parts = []
    if spec.choices:
        parts.append(" / ".join(spec.choices))
    if spec.minimum is not None or spec.maximum is not None:
        parts.append(f"[{_value(spec.minimum)}, {_value(spec.maximum)}]")
    if spec.lengths:
        low, high = spec.lengths
        parts.append(f"{low} values" if low == high else f"{low}-{high} values")
    return ", ".join(parts)


def markdown_table(specs: tuple[ParameterSpec, ...]) -> str:
    """The Markdown table of some parameters: name, default, limits, runtime or read-only, meaning."""
    rows = ["| parameter | default | limits | `ros2 param set` | meaning |", "|---|---|---|---|---|"]
    for spec in specs:
        change = "applied" if spec.runtime else "read-only"
        description = spec.description.replace("|", "&#124;")
        rows.append(
            f"| `{spec.name}` | `{_value(spec.default)}` | {_limits(spec)} | {change} | {description} |"
        )
    return "\n".join(rows) + "\n"


PARAMETER_FILE_HEADER = """\
# The BeAMS suite's parameters at their defaults, one section per node (`/**/<node>`: in any namespace),
# read by `ros2 launch beams_bringup beams.launch.py`. GENERATED from the nodes' specs: edit a spec, then
#   python -m beams_tools.parameter_docs --write src/beams_bringup/config/beams_params.yaml
# A robot's own values go in a copy of this file (--params-file) or a launch override (docs/nodes.md)."""


_COMMENT = textwrap.TextWrapper(
    110, initial_indent="    # ", subsequent_indent="    # ", break_on_hyphens=False
)


def parameter_file() -> str:
    """beams_bringup's parameter file: a section per node of TABLES (a table `<node> <part>`, an edge
    source's, joins its node's), every parameter at its default under its full description."""
    lines = [PARAMETER_FILE_HEADER]
    for name, specs in TABLES.items():
        node, _, part = name.partition(" ")
        if part:
            lines += ["", f"    # ---- {name} ----"]
        else:
            lines += ["", f"# ---- {node} ----", f"/**/{node}:", "  ros__parameters:"]
        for spec in specs:
            lines += _COMMENT.wrap(spec.full_description())
            lines.append(f"    {spec.name}: {_value(spec.default)}")
    return "\n".join(lines) + "\n"


def write(document: str) -> str:
    """The document with every marked table written anew."""

    def replace(match: re.Match) -> str:
        name = match.group("name").strip()
        if name not in TABLES:
            raise KeyError(f"the document names a parameter table {name!r}; known: {sorted(TABLES)}")
        return match.group(1) + markdown_table(TABLES[name]) + match.group(4)

    return _BLOCK.sub(replace, document)


def tables_in(document: str) -> dict[str, str]:
    """The tables a document holds, by name."""
    return {m.group("name").strip(): m.group("body") for m in _BLOCK.finditer(document)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", type=pathlib.Path, help="docs/nodes.md or beams_params.yaml to write")
    options = parser.parse_args(argv)
    if options.write:
        yaml_file = options.write.suffix == ".yaml"
        options.write.write_text(parameter_file() if yaml_file else write(options.write.read_text()))
        return 0
    for name, specs in TABLES.items():
        print(f"{name}\n\n{markdown_table(specs)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
