"""Declaring a node's parameters from its ParameterTable, and applying runtime changes with the same checks.

A parameter whose spec says `runtime=False` is declared read-only: `ros2 param set` is refused by rclpy
with "parameter is read-only". A runtime one goes through the table's validation (alone and together with
the others) and the node's `prepare` in the on-set callback, a refusal from either being the reply
`ros2 param set` prints; the prepared change is applied in the post-set callback, a step that cannot
fail. Nothing is accepted and ignored (ros2/demos set_parameters_callback.py is the model).
"""

import array
from collections.abc import Callable
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node

from beams_common.config.parameters import ParameterError, ParameterSpec, ParameterTable


class ParameterValidationError(ValueError):
    """A parameter value the node cannot run with; the message tells the user what to change."""


def descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    """The ROS descriptor of a spec: description, read-only flag and numeric range."""
    result = ParameterDescriptor(description=spec.full_description(), read_only=not spec.runtime)
    if spec.minimum is not None and spec.maximum is not None:
        if spec.item_type is int:
            result.integer_range = [
                IntegerRange(from_value=int(spec.minimum), to_value=int(spec.maximum), step=0)
            ]
        elif spec.item_type is float:
            result.floating_point_range = [
                FloatingPointRange(from_value=float(spec.minimum), to_value=float(spec.maximum), step=0.0)
            ]
    if spec.choices:
        result.additional_constraints = f"one of {list(spec.choices)}"
    return result


def python_value(value: Any) -> Any:
    """A parameter value as the specs see it: rclpy gives array parameters as array.array or tuples."""
    return list(value) if isinstance(value, array.array | tuple) else value


def declare_table(node: Node, table: ParameterTable) -> dict[str, Any]:
    """Declare every parameter of the table and return their values, validated one by one and together.

    Raises ParameterValidationError naming the parameter (run_node: one line, exit status 2).
    """
    values: dict[str, Any] = {}
    overrides = getattr(node, "_parameter_overrides", {})  # rclpy keeps the --ros-args values there
    for spec in table.specs:
        try:
            values[spec.name] = python_value(
                node.declare_parameter(spec.name, spec.default, descriptor(spec)).value
            )
        except Exception as error:  # rclpy raises several types for out-of-range or mistyped overrides
            # the spec's reason when it has one, so the node and the offline tools say the same
            override = overrides.get(spec.name)
            reason = spec.reason(python_value(override.value)) if override is not None else None
            raise ParameterValidationError(reason or f"{spec.name}: {error}") from None
    try:
        return table.validate(values)
    except ParameterError as error:
        raise ParameterValidationError(str(error)) from None


# The apply step of a runtime change: puts values already validated and prepared to work; cannot fail.
ApplyChange = Callable[[], None]


def apply_runtime_changes(
    node: Node,
    table: ParameterTable,
    current: dict[str, Any],
    prepare: Callable[[dict[str, Any], set[str]], ApplyChange],
) -> None:
    """Validate every runtime change of the table's parameters in the on-set callback, apply it in the
    post-set callback (the ros2/demos set_parameters_callback.py pattern).

    `prepare(values, changed)` gets the validated values (every parameter, the changed names) and does
    whatever may fail (build the new settings, read a calibration file): it raises ValueError (or
    OSError) with the reason to refuse the change, the values and the behaviour in use then stay, or
    returns the apply step, run once rclpy has set the parameters. `current` holds the values in use and
    is updated when a change is applied. Register after every parameter is declared.
    """
    prepared: list[tuple[dict[str, Any], set[str], ApplyChange]] = []  # on-set's, for post-set

    def on_set(parameters: list) -> SetParametersResult:
        prepared.clear()
        changes = {p.name: python_value(p.value) for p in parameters if p.name in table.names}
        if not changes:
            return SetParametersResult(successful=True)
        try:
            validated = table.validate({**current, **changes})
            apply = prepare(validated, set(changes))
        except (ValueError, OSError) as error:  # OSError: a file the change names cannot be read
            node.get_logger().warning(f"parameter change refused: {error}")
            return SetParametersResult(successful=False, reason=str(error))
        prepared.append((validated, set(changes), apply))
        return SetParametersResult(successful=True)

    def post_set(parameters: list) -> None:
        if not prepared or not {p.name for p in parameters} & set(table.names):
            return
        validated, changed, apply = prepared.pop()
        apply()
        current.update(validated)
        node.get_logger().info(f"parameters changed at runtime: {sorted(changed)}")

    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(post_set)
