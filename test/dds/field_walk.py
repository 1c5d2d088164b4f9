"""Coverage generated from the definitions: every leaf field of a ROS message or service type (rosidl's
SLOT_TYPES, nested messages, fixed arrays and sequences walked), the bad values each kind of field is
given, the bad values of each parameter spec, and the invariants every output field is checked against.

test_generated_fields.py builds each node in the test process, feeds its subscription callbacks real
message objects and reads what its publishers were handed; this module knows nothing of the nodes.
"""

import functools
import importlib
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from hypothesis import strategies as st

from beams_common.config.parameters import ParameterSpec

# a field of the elements of an array or a sequence (a covariance's 36 entries, the base message's bearings)
EVERY = "*"
# REP-105's frames, the turret's (driver_node's default) and the test's sensor frame
FRAMES = frozenset({"map", "odom", "base_link", "beams_sensor", "beams"})
# a frame id tf2 can look up: a ROS name (no space, no leading digit, not empty)
FRAME_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z0-9_]+)*")
# a Eurobot table (3 m x 2 m) with a metre of margin: where a pose in the map frame can be
TABLE_X_M, TABLE_Y_M, TABLE_MARGIN_M = (0.0, 3.0), (0.0, 2.0), 1.0
# a published covariance's standard deviation beyond this (m or rad) says nothing: absurd
MAX_SIGMA = 4.0
# the z, roll, pitch variance a planar estimate publishes (beams_common.ros.messages.UNKNOWN_VARIANCE)
UNKNOWN_VARIANCE = 1e6


@dataclass(frozen=True)
class Leaf:
    """One field: its path from the message (names, EVERY for the elements of an array or a sequence),
    its kind (float, int, uint, bool, string, stamp: a builtin_interfaces/Time, sequence) and bits."""

    path: tuple
    kind: str
    bits: int = 64

    @property
    def name(self) -> str:
        return ".".join(str(part) for part in self.path)


def message_class(namespaced: Any) -> type:
    return getattr(importlib.import_module(".".join(namespaced.namespaces)), namespaced.name)


@functools.cache
def leaves(cls: type) -> tuple[Leaf, ...]:
    """Every leaf field of a message class, from its definition (rosidl's SLOT_TYPES)."""
    return tuple(_walk(cls, ()))


def _walk(cls: type, prefix: tuple) -> Iterator[Leaf]:
    for name, slot in zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES, strict=True):
        yield from _leaves_of(slot, (*prefix, name))


def _leaves_of(slot: Any, path: tuple) -> Iterator[Leaf]:
    from rosidl_parser.definition import AbstractGenericString, AbstractNestedType, Array, NamespacedType

    if isinstance(slot, NamespacedType):
        nested = message_class(slot)
        if slot.name == "Time" and slot.namespaces[0] == "builtin_interfaces":
            yield Leaf(path, "stamp")
        yield from _walk(nested, path)
    elif isinstance(slot, AbstractNestedType):  # an array or a sequence (and its length): its elements
        if not isinstance(slot, Array):
            yield Leaf(path, "sequence")
        yield from _leaves_of(slot.value_type, (*path, EVERY))
    elif isinstance(slot, AbstractGenericString):
        yield Leaf(path, "string")
    else:  # a BasicType
        typename = slot.typename
        if typename in ("double", "float", "long double"):
            yield Leaf(path, "float", 32 if typename == "float" else 64)
        elif typename == "boolean":
            yield Leaf(path, "bool")
        elif typename.startswith("uint") or typename in ("octet", "byte", "char"):
            yield Leaf(path, "uint", int(typename[4:]) if typename.startswith("uint") else 8)
        else:
            yield Leaf(path, "int", int(typename[3:]))


FLOATS = (math.nan, math.inf, -math.inf, 1e308, -1e308, 0.0, -1.0, -1e-12, 1e-300, 5.0, -3.0, 1e6, 0.3)
STRINGS = ("", "wrong", "map", "odom", "base_link", "world", "MAP", " map", "map\n", "é" * 300)
# stamp changes: seconds from the good one, or an absolute stamp (s, ns)
STAMP_OFFSETS_S = (-1.0, 1.0, -0.3, 0.2)
STAMPS_ABSOLUTE = ((0, 0), (2**31 - 1, 999_999_999), (1, 0))


def values_of(leaf: Leaf) -> st.SearchStrategy:
    """The bad values of one leaf: NaN, +-inf, +-1e308, 0, negative, empty and wrong strings, stamps off
    by a second, far in the future or zero, values finite but off the table, and any of the type."""
    if leaf.kind == "float":
        special = [v if leaf.bits == 64 or not math.isfinite(v) else max(min(v, 3e38), -3e38) for v in FLOATS]
        width = 32 if leaf.bits == 32 else 64
        return st.sampled_from(special) | st.floats(width=width)
    if leaf.kind in ("int", "uint"):
        low, high = (
            (0, 2**leaf.bits - 1)
            if leaf.kind == "uint"
            else (-(2 ** (leaf.bits - 1)), 2 ** (leaf.bits - 1) - 1)
        )
        return st.sampled_from(sorted({low, high, 0, 1, min(high, 9), min(high, 4)})) | st.integers(low, high)
    if leaf.kind == "bool":
        return st.booleans()
    if leaf.kind == "string":
        return st.sampled_from(STRINGS) | st.text(max_size=20)
    if leaf.kind == "stamp":
        return st.tuples(st.just("offset"), st.sampled_from(STAMP_OFFSETS_S)) | st.tuples(
            st.just("absolute"), st.sampled_from(STAMPS_ABSOLUTE)
        )
    return st.sampled_from(["empty", "repeated", "flood"])  # a sequence's length


def walk(cls: type, skip: tuple[str, ...] = ()) -> list[tuple[Leaf, Any, int | None]]:
    """One case per leaf of `cls` (not under `skip`), the bad values of its kind taken in turn, every
    element of a sequence changed: the explicit examples that make the walk cover every field."""
    cases = []
    for index, leaf in enumerate(leaf for leaf in leaves(cls) if not leaf.name.startswith(skip)):
        choices = {
            "float": FLOATS,
            "int": (-1, 0, -(2 ** (leaf.bits - 1)), 2 ** (leaf.bits - 1) - 1),
            "uint": (0, 2**leaf.bits - 1, 9, 1),
            "bool": (True, False),
            "string": STRINGS,
            "stamp": (*(("offset", s) for s in STAMP_OFFSETS_S), *(("absolute", t) for t in STAMPS_ABSOLUTE)),
            "sequence": ("empty", "repeated", "flood"),
        }[leaf.kind]
        value = choices[index % len(choices)]
        if leaf.kind == "float" and leaf.bits == 32 and math.isfinite(value):
            value = max(min(value, 3e38), -3e38)
        cases.append((leaf, value, None))
    return cases


@st.composite
def field_cases(draw, cls: type, skip: tuple[str, ...] = ()) -> tuple[Leaf, Any, int | None]:
    """(leaf, value, element): a leaf of `cls` (not under a path starting with one of `skip`), a bad
    value for it and, for a field of an array's or a sequence's elements, which element (modulo the
    length; None: every one)."""
    candidates = [leaf for leaf in leaves(cls) if not leaf.name.startswith(skip)]
    leaf = draw(st.sampled_from(candidates))
    element = draw(st.none() | st.integers(0, 63)) if EVERY in leaf.path else None
    return leaf, draw(values_of(leaf)), element


def mutated(message: Any, leaf: Leaf, value: Any, element: int | None = None) -> Any:
    """The message with `leaf` set to `value` (in place; returned)."""
    _set(message, leaf.path, leaf.kind, value, element)
    return message


def _set(target: Any, path: tuple, kind: str, value: Any, element: int | None) -> None:
    head, rest = path[0], path[1:]
    if head == EVERY:
        indices = range(len(target)) if element is None else [element % len(target)] if len(target) else []
        for index in indices:
            if rest:
                _set(target[index], rest, kind, value, element)
            else:
                target[index] = value
        return
    if isinstance(head, int):
        if not rest:
            target[head] = value
        else:
            _set(target[head], rest, kind, value, element)
        return
    if rest:
        if rest[0] == EVERY and len(getattr(target, head)) == 0:
            return  # no element to change
        _set(getattr(target, head), rest, kind, value, element)
        return
    if kind == "stamp":
        stamp = getattr(target, head)
        if value[0] == "offset":
            ns = stamp.sec * 10**9 + stamp.nanosec + round(value[1] * 1e9)
            stamp.sec, stamp.nanosec = max(ns, 0) // 10**9, max(ns, 0) % 10**9
        else:
            stamp.sec, stamp.nanosec = value[1]
    elif kind == "sequence":
        items = list(getattr(target, head))
        changed = {"empty": [], "repeated": items + items[:1], "flood": (items or [None])[:1] * 1000}[value]
        setattr(target, head, [item for item in changed if item is not None])
    else:
        setattr(target, head, value)


# --- parameters ----------------------------------------------------------------------------------------


def bad_value(spec: ParameterSpec) -> Any:
    """A value the spec refuses: not a choice, a list one too long, above the maximum or below the
    minimum, else the wrong type."""
    if spec.choices:
        return "not_a_choice"
    if isinstance(spec.default, list):
        if spec.lengths:
            item = spec.default[0] if spec.default else (spec.minimum or 0.0)
            return [item] * (spec.lengths[1] + 1)
        return [1] if spec.item_type is str else ["x"]
    if spec.item_type in (int, float) and spec.maximum is not None and math.isfinite(spec.maximum):
        return spec.item_type(spec.maximum) + spec.item_type(max(1, abs(spec.maximum)))
    if spec.item_type in (int, float) and spec.minimum is not None:
        return spec.item_type(spec.minimum) - 1
    return 12345 if spec.item_type is str else "x"


def parameter_values(spec: ParameterSpec) -> st.SearchStrategy:
    """Values for a parameter: the one its spec refuses (`bad_value`), non-finite, huge, zero, negative
    and its range's edges, empty and wrong strings, the wrong type, and lists of these."""
    kind = spec.item_type
    if kind is float:
        edges = [v for v in (spec.minimum, spec.maximum) if v is not None and math.isfinite(v)]
        items = st.sampled_from([*FLOATS, *edges])
    elif kind is int:
        edges = [int(v) for v in (spec.minimum, spec.maximum) if v is not None and math.isfinite(v)]
        items = st.sampled_from([0, -1, 1, 2**62, *edges])
    elif kind is bool:
        items = st.booleans()
    else:
        items = st.sampled_from([*STRINGS[:6], *(spec.choices or ())])
    if isinstance(spec.default, list):
        value = st.lists(items, max_size=6) | st.just(list(spec.default[:-1]))
    else:
        value = items | st.sampled_from([1, 0.5, "x", True])
    return st.just(bad_value(spec)) | value


# --- invariants on what a node publishes ------------------------------------------------------------


def output_problems(
    message: Any,
    now_s: float,
    allowed_nan: tuple[str, ...] = (),
    geometry: bool = True,
    frames: frozenset[str] = FRAMES,
) -> list[str]:
    """Why a published message breaks an output invariant: a non-finite number (except the fields named
    in `allowed_nan`, whose NaN says "none"), a frame id not one of `frames` (empty only where it locates
    nothing: a diagnostic's header), a stamp in the future; with `geometry` (not for a pose published as
    rejected, which keeps its numbers), a position in the map frame off the table, a quaternion not of
    unit norm, a covariance asymmetric, not positive semi-definite or absurd."""
    check = _Check(now_s, allowed_nan, geometry, frames)
    check.scan(message, _plan(type(message)), "", None, "")
    return check.problems


def on_table(x: float, y: float) -> bool:
    """On a Eurobot table, with TABLE_MARGIN_M around it."""
    return (
        TABLE_X_M[0] - TABLE_MARGIN_M <= x <= TABLE_X_M[1] + TABLE_MARGIN_M
        and TABLE_Y_M[0] - TABLE_MARGIN_M <= y <= TABLE_Y_M[1] + TABLE_MARGIN_M
    )


@functools.cache
def _plan(cls: type) -> tuple:
    """(name, kind, nested plan, sequence or array) of the fields the output checks read."""
    from rosidl_parser.definition import AbstractGenericString, AbstractNestedType, BasicType, NamespacedType

    plan = []
    for name, slot in zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES, strict=True):
        many = isinstance(slot, AbstractNestedType)
        base = slot.value_type if many else slot
        if isinstance(base, NamespacedType):
            plan.append((name, "message", _plan(message_class(base)), many))
        elif isinstance(base, AbstractGenericString) and not many:
            plan.append((name, "string", None, False))
        elif isinstance(base, BasicType) and base.typename in ("double", "float"):
            plan.append((name, "float", None, many))
    return tuple(plan)


@dataclass
class _Check:
    now_s: float
    allowed_nan: tuple[str, ...]
    geometry: bool
    frames: frozenset[str]
    problems: list[str] = field(default_factory=list)

    def scan(self, message: Any, plan: tuple, path: str, owner: Any, frame: str) -> None:
        """One message's fields; `owner` the message holding this one, `frame` the nearest header's."""
        header = getattr(message, "header", None)
        frame = getattr(header, "frame_id", frame)
        for name, kind, nested, many in plan:
            value, where = getattr(message, name), f"{path}{name}"
            if kind == "float":
                if many and not np.all(np.isfinite(np.asarray(value, dtype=float))):
                    self.problems.append(f"{where} has a non-finite entry")
                elif not many and not math.isfinite(value) and not name.endswith(self.allowed_nan):
                    self.problems.append(f"{where} = {value}")
                if self.geometry and name == "covariance" and len(value) == 36:
                    self.problems += [f"{where}: {p}" for p in covariance_problems(np.asarray(value, float))]
            elif kind == "string" and name in ("frame_id", "child_frame_id") and value not in self.frames:
                locating = owner if name == "frame_id" else message
                if value or hasattr(locating, "pose") or hasattr(locating, "transform"):
                    self.problems.append(f"{where} = {value!r}, not a REP-105 frame")
            elif kind == "message":
                for index, item in enumerate(value) if many else [(None, value)]:
                    self.item(
                        name, item, nested, f"{where}.{index}." if many else f"{where}.", message, frame
                    )

    def item(self, name: str, item: Any, plan: tuple, path: str, owner: Any, frame: str) -> None:
        if name == "stamp" and hasattr(item, "nanosec"):
            stamp_s = item.sec + 1e-9 * item.nanosec
            if stamp_s > self.now_s + 1.0:
                self.problems.append(f"{path[:-1]} = {stamp_s} s, ahead of the clock ({self.now_s} s)")
        if (
            self.geometry
            and name in ("position", "translation")
            and frame == "map"
            and not on_table(item.x, item.y)
        ):
            self.problems.append(f"{path[:-1]} ({item.x}, {item.y}) m in the map frame: off the table")
        if self.geometry and name in ("orientation", "rotation"):
            norm = math.sqrt(item.x**2 + item.y**2 + item.z**2 + item.w**2)
            if not abs(norm - 1.0) < 1e-6:
                self.problems.append(f"{path[:-1]}: a quaternion of norm {norm}")
        self.scan(item, plan, path, owner, frame)


def covariance_problems(covariance_6x6: np.ndarray) -> list[str]:
    """A published 6x6 covariance: finite, symmetric, positive semi-definite, its planar (x, y, yaw)
    standard deviations below MAX_SIGMA and the others the planar estimate's 'unknown'."""
    if not np.all(np.isfinite(covariance_6x6)):
        return ["a non-finite entry"]
    full = covariance_6x6.reshape(6, 6)
    scale = max(float(np.max(np.abs(full))), 1e-300)
    if float(np.max(np.abs(full - full.T))) > 1e-9 * scale:
        return ["not symmetric"]
    planar = full[np.ix_((0, 1, 5), (0, 1, 5))]
    if float(np.linalg.eigvalsh(planar / scale)[0]) < -1e-9:
        return ["not positive semi-definite"]
    sigma = np.sqrt(np.maximum(np.diag(planar), 0.0))
    if np.any(sigma > MAX_SIGMA):
        return [f"standard deviations {sigma.tolist()}: absurd"]
    return []
