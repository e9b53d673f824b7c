"""Declared parameters (`ParameterSpec`) as ROS parameters: descriptors with the declaration's meaning, range and
read_only, and the values checked against it, for every node of the package."""
from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterUninitializedException,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from aoa_localizer.core.spec import ConfigError, ParameterSpec, unknown_names


def descriptor(p: ParameterSpec) -> ParameterDescriptor:
    """The ROS descriptor of a declared parameter: its meaning, read_only when fixed at start, its range when
    closed on both sides (ROS ranges cannot be open; the declaration's check refuses the rest with the reason)."""
    spec = p.spec
    d = ParameterDescriptor(description=spec.doc.replace("`", ""), read_only=spec.read_only)
    if p.default is None:
        d.dynamic_typing = True  # unset until given; then any number
    closed = not (spec.low_open or spec.high_open)
    if closed and spec.low is not None and spec.high is not None:
        if spec.kind is int:
            d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)]
        elif spec.kind is float:
            d.floating_point_range = [FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high),
                                                         step=0.0)]
    if isinstance(p.default, list):
        d.type = ParameterType.PARAMETER_STRING_ARRAY if spec.items is str else ParameterType.PARAMETER_DOUBLE_ARRAY
    if spec.choices:
        d.additional_constraints = f"one of {', '.join(spec.choices)}"
    return d


def value_of(node: Node, p: ParameterSpec):
    """A declared parameter's value (a list as a list); its default while a list declared by type is unset."""
    try:
        value = node.get_parameter(p.name).value
    except ParameterUninitializedException:
        return p.default
    return list(value) if isinstance(value, (list, tuple)) else value


def declare(node: Node, specs: list[ParameterSpec], check: bool = True) -> dict:
    """Declare every spec on `node` and return the values; raises ConfigError (the caller refuses to start) for a
    value outside its declaration when `check`."""
    values = {}
    _take_whole_numbers(node, [p.name for p in specs if p.spec.kind is float])
    for p in specs:
        d = descriptor(p)
        try:
            if isinstance(p.default, list):  # an empty list has no type of its own: declared by type, unset: default
                kind = Parameter.Type.STRING_ARRAY if p.spec.items is str else Parameter.Type.DOUBLE_ARRAY
                node.declare_parameter(p.name, kind, d)
            else:
                node.declare_parameter(p.name, p.default, d)
        except InvalidParameterTypeException as exc:  # rclpy's words name the type only: say what is valid
            given = _overrides(node).get(p.name)
            was_bool = given is not None and given.type_ is Parameter.Type.BOOL
            hint = " (YAML reads on/off/yes/no as booleans: quote them)" if was_bool else ""
            raise ConfigError(f"{p.name} must be {p.spec.describe()}{hint}; {exc}") from exc
        except InvalidParameterValueException as exc:  # outside the descriptor's range: the declaration's words
            given = _overrides(node).get(p.name)
            if given is not None:
                p.spec.check(p.name, given.value)
            raise ConfigError(f"{p.name} must be {p.spec.describe()}; {exc}") from exc
        values[p.name] = value_of(node, p)
    if check:
        for p in specs:
            p.spec.check(p.name, values[p.name])
    return values


def _take_whole_numbers(node: Node, names: list[str]):
    """A whole number given for a decimal parameter is that decimal, as ROS users type them (`-p
    goal_radius_m:=200`): at start (the overrides) and at run time (a callback before rclpy checks the type)."""
    overrides = _overrides(node)
    for name in names:
        given = overrides.get(name)
        if given is not None and given.type_ == Parameter.Type.INTEGER:
            overrides[name] = Parameter(name, Parameter.Type.DOUBLE, float(given.value))
    decimal: set = getattr(node, "_aoa_decimal_names", set())
    if not decimal:  # the first declaration on this node: the run-time callback, once
        node.add_pre_set_parameters_callback(lambda params: [
            Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            if p.name in decimal and p.type_ == Parameter.Type.INTEGER else p for p in params])
        node._aoa_decimal_names = decimal  # type: ignore[attr-defined]
    decimal.update(names)


def refuse_unknown(node: Node):
    """After every declaration: ConfigError for an override (-p, --params-file) of a name not declared, with the
    nearest known name. rclpy silently ignores those and has no public accessor for them."""
    declared = set(node._parameters)
    unknown = sorted(set(_overrides(node)) - declared)
    if unknown:
        raise ConfigError(unknown_names(unknown, sorted(declared)))


def _overrides(node: Node) -> dict:
    """The values given at start (-p, --params-file) by name: rclpy keeps them privately, with no accessor."""
    return getattr(node, "_parameter_overrides", {})
