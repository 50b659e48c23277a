"""The observer's parameters as ROS 2 parameters: declared from the schemas the runner
validates against (runner settings + the chosen observer's), each with a descriptor;
runtime changes validated by rebuilding the runner before they are taken.

Used by the plain and the managed node alike.  The values the runner gets are exactly
what the replay gets from the same params file (``runner.params_file``), so both accept
and refuse the same files with the same message.
"""
from __future__ import annotations

import math
import sys
from typing import Any, Callable

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterAlreadyDeclaredException
from rclpy.parameter import Parameter

from ..core.errors import ConfigError
from ..observers import REGISTRY, observer_class
from ..core.params import Param
from ..plant.block import PLANT_PARAMS, PREFIX as PLANT_PREFIX
from ..runner.settings import ROS_BUILTIN, SETTINGS

#: Param.kind -> ROS 2 parameter type
ROS_TYPE = {
    "bool": Parameter.Type.BOOL,
    "int": Parameter.Type.INTEGER,
    "double": Parameter.Type.DOUBLE,
    "string": Parameter.Type.STRING,
    "double_array": Parameter.Type.DOUBLE_ARRAY,
    "int_array": Parameter.Type.INTEGER_ARRAY,
    "string_array": Parameter.Type.STRING_ARRAY,
}
ARRAY_KINDS = ("double_array", "int_array", "string_array")
_INT64_MIN, _INT64_MAX = -(2 ** 63), 2 ** 63 - 1


def descriptor(p: Param) -> ParameterDescriptor:
    """A ParameterDescriptor for ``p`` (description, range, read_only, choices)."""
    d = ParameterDescriptor(description=p.description, read_only=bool(p.read_only))
    constraints = []
    if p.choices:
        constraints.append("one of: " + ", ".join(p.choices))
    lower = p.lower
    if lower is not None or p.max is not None:
        if p.kind == "double":
            lo = -sys.float_info.max if lower is None else float(lower)
            hi = sys.float_info.max if p.max is None else float(p.max)
            d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
        elif p.kind == "int":
            lo = _INT64_MIN if lower is None else math.ceil(lower)
            hi = _INT64_MAX if p.max is None else int(p.max)
            d.integer_range = [IntegerRange(from_value=lo, to_value=hi, step=0)]
        else:  # ROS ranges apply to scalars only: state the element range in words
            parts = ([f"> {p.gt}"] if p.gt is not None else []) + \
                    ([f">= {p.min}"] if p.min is not None else []) + \
                    ([f"<= {p.max}"] if p.max is not None else [])
            constraints.append("every element " + " and ".join(parts))
    if p.required:
        constraints.append("required")
    d.additional_constraints = "; ".join(constraints)
    return d


def typed_override(p: Param, full_name: str, param: Parameter) -> Any:
    """The override ``param`` converted to ``p``'s type (ConfigError naming it otherwise).

    ``None`` for an unset value (an empty YAML list reaches rclpy as NOT_SET).
    """
    if param.type_ == Parameter.Type.NOT_SET or param.value is None:
        return [] if p.kind in ARRAY_KINDS else None
    return p.coerce(param.value, full_name)


def _declare(node, full: str, p: Param, value: Any) -> None:
    """Declare ``full`` so that it has a value: ``ros2 param get`` / ``dump`` (rclpy's
    get_parameters service answers nothing at all for a request naming a parameter without
    one).  An empty array: its type, then the empty array of that type (rclpy infers the type
    of [] as a byte array); a scalar without a value (a derived or optional one): dynamically
    typed and unset, since any value would change its meaning; its kind is in the
    descriptor's constraints and the schema still checks every change (typed_override)."""
    d = descriptor(p)
    if value is None:
        d.dynamic_typing = True
        d.additional_constraints = "; ".join(
            c for c in (f"type {p.kind}, unset: derived or not used", d.additional_constraints) if c)
        node.declare_parameter(full, None, d, ignore_override=True)
    elif p.kind in ARRAY_KINDS and len(value) == 0:
        # a read-only one cannot be set after it is declared: writable until it holds []
        writable = descriptor(p)
        writable.read_only = False
        node.declare_parameter(full, ROS_TYPE[p.kind], writable, ignore_override=True)
        node.set_parameters([Parameter(full, ROS_TYPE[p.kind], [])])
        d.type = ROS_TYPE[p.kind].value
        node.set_descriptor(full, d)
    else:
        node.declare_parameter(full, value, d, ignore_override=True)


class NodeParameters:
    """The declared parameters of one observer node and their typed values."""

    def __init__(self, node):
        self.node = node
        self.specs: dict[str, Param] = {}      # full name -> Param, for runtime changes
        self.flat: dict[str, Any] = {}         # full name -> typed value (the runner's input)

    def declare(self) -> None:
        """Declare ``observer.type``'s schema with the overrides of the params files.
        Parameters already declared (a managed node configured again) keep their values."""
        node = self.node
        overrides: dict[str, Parameter] = dict(node._parameter_overrides)
        type_param = SETTINGS[0]
        raw = overrides.get("observer.type")
        if node.has_parameter("observer.type"):
            raw = node.get_parameter("observer.type")
        type_name = None if raw is None else typed_override(type_param, "observer.type", raw)
        if type_name is None:
            raise ConfigError("observer.type", "missing: say which observer to run (one of "
                              + ", ".join(sorted(REGISTRY)) + ") in the params file or with "
                              "-p observer.type:=NAME")
        classes = [observer_class(type_name)]
        for role in getattr(classes[0], "CHILD_ROLES", ()):     # a composition's children
            full = f"{type_name}.{role}"
            spec = next(p for p in classes[0].PARAMS if p.name == role)
            raw = node.get_parameter(full) if node.has_parameter(full) else overrides.get(full)
            child = spec.default if raw is None else typed_override(spec, full, raw)
            if child is None:
                raise ConfigError(full, f"required: {spec.description}")
            classes.append(observer_class(child))
        # the plant: the plant block, or an arm family's URDF and conventions (full names)
        plant = [(p.name, p) for p in classes[0].ARM_PARAMS] if getattr(classes[0], "ARM", False) \
            else [(PLANT_PREFIX + p.name, p) for p in PLANT_PARAMS]
        specs = [(p.name, p) for p in SETTINGS] + \
                [(f"{c.TYPE}.{p.name}", p) for c in classes for p in c.PARAMS] + plant
        for full, p in specs:
            if node.has_parameter(full):
                value = typed_override(p, full, node.get_parameter(full))
            else:
                value = p.default
                if full in overrides:
                    value = typed_override(p, full, overrides[full])
                elif value is not None:
                    value = p.coerce(value, full)
                try:
                    _declare(node, full, p, value)
                except ParameterAlreadyDeclaredException:
                    pass
            self.specs[full] = p
            if value is not None:
                self.flat[full] = value

    def with_unknown_overrides(self) -> dict[str, Any]:
        """The declared values plus every override nobody declared, so the runner refuses
        typos (naming them), as the replay does."""
        flat = dict(self.flat)
        for name, param in self.node._parameter_overrides.items():
            if name in flat or name in self.specs or name in ROS_BUILTIN:
                continue
            if name.startswith("qos_overrides."):
                continue
            flat[name] = param.value
        return flat

    def convert(self, params: list[Parameter]) -> list[Parameter]:
        """Runtime ``ros2 param set x 1`` for a double: convert instead of refusing."""
        out = []
        for param in params:
            p = self.specs.get(param.name)
            if p is not None and param.type_ != ROS_TYPE[p.kind] \
                    and param.type_ != Parameter.Type.NOT_SET:
                try:
                    value = p.coerce(param.value, param.name)
                    if p.kind in ARRAY_KINDS and len(value) == 0:
                        value = []
                    param = Parameter(param.name, ROS_TYPE[p.kind], value)
                except Exception:  # noqa: BLE001  (a pre-set callback that raises kills the node)
                    pass  # ROS refuses it with 'Wrong parameter type', naming both types
            out.append(param)
        return out

    def changed(self, params: list[Parameter]) -> dict[str, Any] | None:
        """The flat parameters with ``params`` applied (None: none of ours changed);
        ConfigError naming the parameter for a value the schema refuses."""
        new = dict(self.flat)
        changed = False
        for param in params:
            p = self.specs.get(param.name)
            if p is None:
                continue  # use_sim_time, qos_overrides...: ROS's own
            value = typed_override(p, param.name, param)
            if value is None:
                new.pop(param.name, None)
            else:
                new[param.name] = value
            changed = True
        return new if changed else None


def check_declared(node, parameter_list: list[Parameter], base: Callable) -> None:
    """rclpy's check for undeclared parameters, naming them (Jazzy's rclpy empties the
    list it reports: "undeclared parameter(s): []")."""
    from rclpy.exceptions import ParameterNotDeclaredException
    if not node._allow_undeclared_parameters:
        names = [p.name for p in parameter_list if isinstance(p, Parameter)
                 and p.name not in node._parameters]
        if names:
            raise ParameterNotDeclaredException(names)
    base(parameter_list)
