"""Reading a YAML document against a schema: every value checked for its type, shape and finiteness.

The calibration file (`calibration_file`) and the calibration dataset (`beams_calibration.dataset`) are
edited by hand: their parsers take each entry through these readers instead of trusting the structure
(a list where a mapping is expected used to end a running node with an AttributeError). Each reader
returns the value or raises SchemaError naming the entry by its path (`power_bias.a`,
`configurations[3].beacons[0].window_rad`) and what was expected; `schema_problem` turns a parse into
a reason string.
"""

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from beams_common.intake.validation import bounded

T = TypeVar("T")
# Longest free text accepted (labels, stages, warnings), and most items in one list of a document.
MAX_TEXT_CHARS = 1000
MAX_ITEMS = 100_000
# Largest file read (bytes): a dataset of 10,000 configurations takes about 4 MB.
MAX_FILE_BYTES = 16 * 2**20


class SchemaError(ValueError):
    """A document entry of the wrong type, shape or value; the message starts with the entry's path."""


def read_yaml(path: Path) -> Any:
    """The YAML document of a file (OSError when unreadable); SchemaError when larger than
    MAX_FILE_BYTES, not UTF-8, not YAML, or nested beyond the parser's recursion limit."""
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise SchemaError(f"{size} bytes, more than the {MAX_FILE_BYTES} a BeAMS file can hold")
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError, RecursionError) as error:
        mark = getattr(error, "problem_mark", None)  # where, never what: the file's text is not echoed
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        raise SchemaError(f"not valid YAML{where}: a UTF-8 YAML document expected") from None


def _shown(value: Any) -> str:
    """A value read from a file as a reason shows it: a number itself, anything else only by its type."""
    return (
        repr(value)
        if isinstance(value, int | float) and not isinstance(value, bool)
        else type(value).__name__
    )


def mapping(value: Any, path: str, keys: tuple[str, ...] = ()) -> Mapping[str, Any]:
    """A YAML mapping holding at least `keys`."""
    if not isinstance(value, Mapping):
        expected = f"a mapping with {', '.join(keys)}" if keys else "a mapping"
        raise SchemaError(f"{path}: expected {expected}, got {_shown(value)}")
    missing = [key for key in keys if key not in value]
    if missing:
        raise SchemaError(f"{path}: missing entry {', '.join(map(repr, missing))}")
    return value


def items(value: Any, path: str, length: int | None = None, *, minimum: int = 0) -> list[Any]:
    """A YAML list (of exactly `length` items when given, at least `minimum`, at most MAX_ITEMS)."""
    if not isinstance(value, list):
        raise SchemaError(f"{path}: expected a list, got {_shown(value)}")
    if length is not None and len(value) != length:
        raise SchemaError(f"{path}: expected {length} items, got {len(value)}")
    if not minimum <= len(value) <= MAX_ITEMS:
        raise SchemaError(f"{path}: expected {minimum} to {MAX_ITEMS} items, got {len(value)}")
    return value


def number(value: Any, path: str, *, minimum: float | None = None, maximum: float | None = None) -> float:
    """A finite real number (an int or a float, not a bool or a string) within [minimum, maximum]."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SchemaError(f"{path}: expected a number, got {_shown(value)}")
    try:
        result = float(value)
    except OverflowError:  # an integer beyond a float's range
        result = math.inf
    if not math.isfinite(result):
        raise SchemaError(f"{path}: expected a finite number, got {_shown(value)}")
    return _within(result, path, minimum, maximum)


def integer(value: Any, path: str, *, minimum: int | None = None, maximum: int | None = None) -> int:
    """An integer (not a bool, not a float) within [minimum, maximum]."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise SchemaError(f"{path}: expected an integer, got {_shown(value)}")
    return _within(value, path, minimum, maximum)


def _within(value: T, path: str, minimum: float | None, maximum: float | None) -> T:
    if minimum is not None and value < minimum:
        raise SchemaError(f"{path}: {value!r} is below its minimum {minimum}")
    if maximum is not None and value > maximum:
        raise SchemaError(f"{path}: {value!r} is above its maximum {maximum}")
    return value


def text(value: Any, path: str) -> str:
    """Free text: a string, or a scalar YAML read as something else (a date, a number), as text."""
    if isinstance(value, list | dict) or value is None:
        raise SchemaError(f"{path}: expected text, got {_shown(value)}")
    result = str(value)
    if len(result) > MAX_TEXT_CHARS:
        raise SchemaError(f"{path}: text of {len(result)} characters, at most {MAX_TEXT_CHARS}")
    return result


def optional(
    document: Mapping[str, Any], key: str, read: Callable[[Any, str], T], path: str, default: T
) -> T:
    """`read(document[key])` when the key is present and not null, else `default`."""
    value = document.get(key)
    return default if value is None else read(value, f"{path}.{key}" if path else key)


def header(document: Any, file_format: str, version: int) -> Mapping[str, Any]:
    """The top-level mapping of a document whose `format` and `version` must be these."""
    top = mapping(document, "top level")
    if top.get("format") != file_format:
        raise SchemaError(f"format is not {file_format!r}")
    if top.get("version") != version:
        raise SchemaError(f"version {_shown(top.get('version'))} is not supported (expected {version})")
    return top


def required(document: Mapping[str, Any], key: str, path: str = "") -> Any:
    """`document[key]`; SchemaError "missing entry" when absent."""
    if key not in document:
        raise SchemaError(f"{path or 'top level'}: missing entry {key!r}")
    return document[key]


def beacon_lists(
    document: Mapping[str, Any], path: str = "beacons"
) -> tuple[list[int], list[float], list[float]]:
    """The `beacons` entry, a list of {id, x_m, y_m}, as parallel lists (ids >= 0, finite coordinates in
    m), for BeaconMap.from_lists."""
    value = required(document, path)
    ids, xs, ys = [], [], []
    for index, item in enumerate(items(value, path)):  # BeaconMap then says how many it needs
        where = f"{path}[{index}]"
        beacon = mapping(item, where, ("id", "x_m", "y_m"))
        ids.append(integer(beacon["id"], f"{where}.id", minimum=0, maximum=65535))
        xs.append(number(beacon["x_m"], f"{where}.x_m"))
        ys.append(number(beacon["y_m"], f"{where}.y_m"))
    return ids, xs, ys


def schema_problem(parse: Callable[[Any], Any], document: Any) -> str:
    """The reason `parse(document)` refuses the document, or '' when it parses."""
    try:
        parse(document)
    except ValueError as error:
        return bounded(str(error))
    return ""
