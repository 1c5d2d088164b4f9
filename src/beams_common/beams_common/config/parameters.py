"""One spec per parameter: name, type, default, range or choices, description, runtime-changeable or not.

A node declares its parameters from its table (beams_common.ros.parameters), validates a runtime change
against the same table in its parameter callback, and the offline tools (replay_bag) validate a parameter
file against it: an out-of-range value is refused everywhere with the same reason. Pure (no rclpy), in
the spirit of generate_parameter_library.
"""

import math
import pathlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from beams_common.calibration.file_schema import SchemaError, read_yaml

Value = bool | int | float | str | list


class ParameterError(ValueError):
    """A parameter value a node cannot run with; the message names the parameter and what to change."""


@dataclass(frozen=True)
class ParameterSpec:
    """A parameter: its type is the default's (bool, int, float, str or a list of one of them).

    minimum/maximum bound every number (each item of a list); choices restrict a string; length fixes a
    list's length (an int, or (min, max)); runtime says whether `ros2 param set` may change it while the
    node runs (else it is read-only); check is an extra test returning a reason, or None when valid.
    """

    name: str
    default: Value
    description: str
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple[str, ...] | None = None
    length: int | tuple[int, int] | None = None
    runtime: bool = False
    check: Callable[[Any], str | None] | None = None

    @property
    def item_type(self) -> type:
        """The type of the value, or of each item of a list."""
        if isinstance(self.default, list):
            return type(self.default[0]) if self.default else str
        return type(self.default)

    @property
    def lengths(self) -> tuple[int, int] | None:
        """The fewest and most items of a list whose length is fixed, None otherwise."""
        return (self.length, self.length) if isinstance(self.length, int) else self.length

    def full_description(self) -> str:
        """The description with the range, choices and length, as `ros2 param describe` shows it."""
        parts = [self.description]
        if self.choices:
            parts.append(f"One of {list(self.choices)}.")
        if self.minimum is not None or self.maximum is not None:
            parts.append(f"Range [{self.minimum}, {self.maximum}].")
        if self.lengths:
            low, high = self.lengths
            parts.append(f"Length {low}." if low == high else f"Length {low} to {high}.")
        parts.append("Changeable at runtime." if self.runtime else "Read-only: set at start-up.")
        return " ".join(parts)

    def reason(self, value: Any) -> str | None:
        """Why value is not valid for this parameter, or None when it is."""
        if value is None:  # ROS gives an empty list (`[]`, no element to type it) no value at all
            return f"{self.name} has no value (an empty list?): {self._expected()}"
        if isinstance(self.default, list):
            if not isinstance(value, list | tuple):
                return f"{self.name} must be a list, got {value!r}"
            items = list(value)
            low, high = self.lengths or (0, len(items))
            if not low <= len(items) <= high:
                needs = f"{low}" if low == high else f"{low} to {high}"
                return f"{self.name} needs {needs} values, got {len(items)}"
        else:
            items = [value]
        for item in items:
            problem = self._item_reason(item)
            if problem:
                return problem
        return self.check(value) if self.check else None

    def _expected(self) -> str:
        if isinstance(self.default, list):
            low, high = self.lengths or (1, "n")
            return f"give {low}" + ("" if low == high else f" to {high}") + f" values, e.g. {self.default}"
        return f"give a value, e.g. {self.default!r}"

    def _item_reason(self, item: Any) -> str | None:
        kind = self.item_type
        numeric = kind in (int, float)
        if kind is bool and not isinstance(item, bool):
            return f"{self.name} must be true or false, got {item!r}"
        if numeric and (isinstance(item, bool) or not isinstance(item, int | float)):
            return f"{self.name} must be a number, got {item!r}"
        if kind is int and not isinstance(item, int):
            return f"{self.name} must be an integer, got {item!r}"
        if kind is str and not isinstance(item, str):
            return f"{self.name} must be a string, got {item!r}"
        if numeric:
            if not math.isfinite(item):
                return f"{self.name} must be finite, got {item}"
            if self.minimum is not None and item < self.minimum:
                return f"{self.name} = {item} is below its minimum {self.minimum}"
            if self.maximum is not None and item > self.maximum:
                return f"{self.name} = {item} is above its maximum {self.maximum}"
        if self.choices is not None and item not in self.choices:
            return f"{self.name} must be one of {list(self.choices)}, got {item!r}"
        return None


@dataclass(frozen=True)
class ParameterTable:
    """A node's parameters, and the checks that involve several of them (`together`)."""

    node_name: str
    specs: tuple[ParameterSpec, ...]
    together: tuple[Callable[[Mapping[str, Any]], str | None], ...] = field(default=())

    def __post_init__(self) -> None:
        names = [spec.name for spec in self.specs]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.node_name}: a parameter is specified twice in {names}")

    def __getitem__(self, name: str) -> ParameterSpec:
        for spec in self.specs:
            if spec.name == name:
                return spec
        raise KeyError(name)

    def __add__(self, other: "ParameterTable") -> "ParameterTable":
        return ParameterTable(self.node_name, self.specs + other.specs, self.together + other.together)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(spec.name for spec in self.specs)

    def default(self, name: str) -> Value:
        """The default of parameter `name` (its spec's: the one source of a setting's default)."""
        return self[name].default

    def defaults(self) -> dict[str, Any]:
        return {spec.name: spec.default for spec in self.specs}

    def require(self, **values: Any) -> None:
        """Raise ParameterError with the reason when one of these values is not valid (a settings class's
        range check, for one built without the table)."""
        for name, value in values.items():
            problem = self[name].reason(value)
            if problem:
                raise ParameterError(problem)

    def validate(self, values: Mapping[str, Any], *, ignore: Iterable[str] = ()) -> dict[str, Any]:
        """Every parameter's value (values over the defaults), checked one by one and together.

        A name the table does not know raises ParameterError (a typo in a parameter file would otherwise
        be ignored), unless listed in `ignore` (parameters every ROS node has, such as use_sim_time).
        """
        unknown = sorted(set(values) - set(self.names) - set(ignore))
        if unknown:
            raise ParameterError(f"{self.node_name} has no parameter {', '.join(unknown)}")
        merged = {**self.defaults(), **{k: v for k, v in values.items() if k in self.names}}
        for spec in self.specs:
            problem = spec.reason(merged[spec.name])
            if problem:
                raise ParameterError(problem)
        for check in self.together:
            problem = check(merged)
            if problem:
                raise ParameterError(problem)
        return merged


# Parameters every ROS 2 node has; a parameter file may set them for any node.
ROS_NODE_PARAMETERS = ("use_sim_time", "start_type_description_service")


def node_section(document: Mapping[str, Any], node_name: str) -> dict[str, Any]:
    """The `ros__parameters` a ROS parameter file gives node_name: the entries `/**`, `/**/<node>`,
    `<node>` and `/<node>` merged in that order (the more specific wins), as rcl applies them."""
    merged: dict[str, Any] = {}
    for key in ("/**", f"/**/{node_name}", node_name, f"/{node_name}"):
        entry = document.get(key)
        if isinstance(entry, Mapping):
            merged.update(entry.get("ros__parameters", {}) or {})
    return merged


def load_parameter_file(path: str | pathlib.Path, table: ParameterTable) -> dict[str, Any]:
    """The values a ROS parameter file gives the table's node, validated as the node validates them."""
    try:
        document = read_yaml(pathlib.Path(path)) or {}
    except SchemaError as error:
        raise ParameterError(f"{path}: {error}") from None
    if not isinstance(document, Mapping):
        raise ParameterError(f"{path}: not a ROS parameter file (a mapping of node names)")
    section = node_section(document, table.node_name)
    try:
        return table.validate(section, ignore=ROS_NODE_PARAMETERS)
    except ParameterError as error:
        raise ParameterError(f"{path}: {error}") from None


def is_topic_name(name: str) -> bool:
    """True for a valid ROS topic name (letters, digits, underscores and slashes, no empty token, not
    starting with a digit), as rcl checks it."""
    if not name or name.endswith("/") or "//" in name:
        return False
    tokens = name.lstrip("~").lstrip("/").split("/")
    return all(
        t and (t[0].isalpha() or t[0] == "_") and all(c.isalnum() or c == "_" for c in t) for t in tokens
    )
