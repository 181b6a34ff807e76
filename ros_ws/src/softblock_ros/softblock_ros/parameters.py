"""How every node declares its parameters: one schema entry per parameter (name, unit, range, description),
the default read from the core's own dataclass field or function argument of the same name.

``declare(node, SCHEMA)`` checks before anything is declared: a key in the node's section of a parameter
file (or a ``-p`` override) that the schema lacks is refused, an integer is accepted for a float parameter,
and every bad value is answered with one `ParameterError` line naming the parameter, the value and what is
allowed. Parameters are read-only: a node reads them once, at start.

    python -m softblock_ros.parameters     # the nodes' parameter tables, as in the docs (Markdown)
"""
from __future__ import annotations

import dataclasses
import importlib
import inspect
import math
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

# Keys rclpy itself reads from a parameter file besides a node's declared parameters.
RCLPY_KEYS = ("use_sim_time", "start_type_description_service")
RCLPY_PREFIXES = ("qos_overrides.",)
TYPES = {bool: Parameter.Type.BOOL, int: Parameter.Type.INTEGER, float: Parameter.Type.DOUBLE,
         str: Parameter.Type.STRING}
ARRAY_TYPES = {int: Parameter.Type.INTEGER_ARRAY, float: Parameter.Type.DOUBLE_ARRAY, str: Parameter.Type.STRING_ARRAY}


class ParameterError(ValueError):
    """A parameter value the node cannot start with; the message is one line naming parameter, value and rule."""


def core_default(source, name: str):
    """Default of field ``name`` of a dataclass, or of argument ``name`` of a function or class constructor."""
    if dataclasses.is_dataclass(source):
        field = {f.name: f for f in dataclasses.fields(source)}[name]
        return field.default if field.default is not dataclasses.MISSING else field.default_factory()
    return inspect.signature(source).parameters[name].default


@dataclass(frozen=True)
class Param:
    """One parameter: ``kind`` is bool, int, float or str, ``size`` makes it a list (an int: exactly that many
    items; a (min, max) pair: that many); ``low``/``high`` bound numbers (and every item of a number list)."""

    name: str
    default: Any
    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    kind: type = float
    size: int | tuple[int, int] | None = None
    choices: tuple[str, ...] = ()

    @classmethod
    def of(cls, source, name: str, description: str, unit: str = "", low=None, high=None, *, field: str | None = None,
           none_as=None, **options) -> Param:
        """A parameter whose default is ``source``'s field/argument ``field`` (default: the same name); a core
        default of None (a feature off) becomes ``none_as``."""
        default = core_default(source, field or name)
        default = none_as if default is None else default
        kind = options.pop("kind", type(default[0]) if isinstance(default, (list, tuple)) and default else type(default))
        if isinstance(default, tuple):
            default = list(default)
        return cls(name, default, description, unit, low, high, kind, **options)

    # -- checks ----------------------------------------------------------------------------------------
    def _number(self, value) -> str:
        return str(int(value)) if self.kind is int else f"{value:g}"

    def _range_text(self) -> str:
        """What the parameter allows, e.g. ``1..10000 V`` or ``1..16 items, each 0..63``."""
        unit = f" {self.unit}" if self.unit else ""
        if self.choices:
            text = f"one of {', '.join(self.choices)}"
        elif self.kind in (str, bool):
            text = {str: "any text", bool: "true or false"}[self.kind]
        elif self.low is not None and self.high is not None:
            text = f"{self._number(self.low)}..{self._number(self.high)}{unit}"
        else:
            text = f"a {self.kind.__name__}{unit}"
        if self.size is None:
            return text
        low, high = (self.size, self.size) if isinstance(self.size, int) else self.size
        return f"{low if low == high else f'{low}..{high}'} items, each {text}"

    def _fail(self, value, rule: str):
        raise ParameterError(f"parameter {self.name}={value!r} refused: {rule}")

    def _scalar(self, value, shown):
        if self.kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)  # `3000` in a YAML file means 3000.0
        if type(value) is not self.kind:
            self._fail(shown, f"must be a {self.kind.__name__}" + (f" ({self._range_text()})"
                                                                    if self.kind in (int, float) else ""))
        if self.kind in (int, float):
            # Infinity only where the range reaches it (a watchdog switched off with .inf), NaN never.
            if math.isnan(value) or (math.isinf(value) and value not in (self.low, self.high)) or (
                    self.low is not None and value < self.low) or (self.high is not None and value > self.high):
                self._fail(shown, f"allowed {self._range_text()}")
        if self.choices and value not in self.choices:
            self._fail(shown, f"allowed {self._range_text()}")
        return value

    def check(self, value):
        """The value as the node uses it (ints widened to floats, lists as lists); ParameterError otherwise."""
        if self.size is None:
            return self._scalar(value, value)
        if value is None:  # a params file's `[]` reaches rclpy without a type, as an unset value
            value = []
        if not isinstance(value, (list, tuple)):
            self._fail(value, f"must be a list of {self.kind.__name__}s")
        low, high = (self.size, self.size) if isinstance(self.size, int) else self.size
        if not low <= len(value) <= high:
            count = f"exactly {low}" if low == high else f"at least {low}" if high >= 1_000_000 else f"{low}..{high}"
            self._fail(list(value), f"give {count} item(s)")
        return [self._scalar(item, list(value)) for item in value]

    # -- declaration -----------------------------------------------------------------------------------
    def descriptor(self) -> ParameterDescriptor:
        """Read-only, with the description and unit, the range of a number, the choices of a string (in
        ``additional_constraints``, as ``ros2 param describe`` shows them)."""
        descriptor = ParameterDescriptor(description=self.text(), read_only=True)
        if self.choices:
            descriptor.additional_constraints = self._range_text()
        if self.kind in (int, float) and self.low is not None and self.high is not None and self.size is None:
            if self.kind is float:
                descriptor.floating_point_range = [FloatingPointRange(from_value=float(self.low),
                                                                      to_value=float(self.high))]
            else:
                descriptor.integer_range = [IntegerRange(from_value=int(self.low), to_value=int(self.high))]
        return descriptor

    def parameter_type(self) -> Parameter.Type:
        return (ARRAY_TYPES if self.size is not None else TYPES)[self.kind]

    def text(self) -> str:
        unit = f" [{self.unit}]" if self.unit else ""
        choices = f" ({self._range_text()})" if self.choices else ""
        return f"{self.description}{unit}{choices}"


def with_defaults(schema: tuple[Param, ...], **defaults) -> tuple[Param, ...]:
    """``schema`` with other defaults for some parameters (e.g. a node's constructor arguments)."""
    return tuple(dataclasses.replace(param, default=defaults[param.name]) if param.name in defaults else param
                 for param in schema)


def declare(node: Node, schema: tuple[Param, ...]) -> dict[str, Any]:
    """Check the node's parameter overrides against ``schema``, declare every parameter read-only and
    return name -> value. ParameterError (one line) for an unknown key or a bad value; nothing is declared then."""
    names = {param.name for param in schema}
    overrides = node._parameter_overrides  # rclpy keeps the node's params-file and -p values here (no public getter)
    unknown = sorted(name for name in overrides if name not in names and name not in RCLPY_KEYS
                     and not name.startswith(RCLPY_PREFIXES))
    if unknown:
        raise ParameterError(f"unknown parameter(s) {', '.join(unknown)} for node {node.get_name()}; "
                             f"known: {', '.join(sorted(names))}")
    values = {param.name: param.check(overrides[param.name].value if param.name in overrides else param.default)
              for param in schema}
    node.declare_parameters("", [(param.name, values[param.name] if values[param.name] != [] else
                                  param.parameter_type(), param.descriptor()) for param in schema],
                            ignore_override=True)
    return values


def markdown_table(schema: tuple[Param, ...]) -> str:
    """The docs' table of a node's parameters."""
    rows = ["| parameter | default | allowed | description |", "|---|---|---|---|"]
    for param in schema:
        default = f"`{param.default!r}`".replace("|", "\\|") if param.default != "" else '`""`'
        rows.append(f"| `{param.name}` | {default} | {param._range_text()} | {param.description} |")
    return "\n".join(rows)


# Where each node's schema (its PARAMETERS) lives.
NODE_SCHEMAS = {"hv_driver": "softblock_ros.hv_parameters", "assembly_state": "softblock_ros.assembly_state_node",
                "planner": "softblock_ros.planner_node", "sim_arm": "softblock_ros.sim_arm_node",
                "sequencer": "softblock_ros.sequencer_node", "recorder": "softblock_ros.recording.recorder_node",
                "sim_camera": "softblock_ros.sim_camera_node", "estimator": "softblock_ros.estimator_node",
                "foxglove_bridge": "softblock_ros.foxglove_bridge_node"}


def node_schema(node: str) -> tuple[Param, ...]:
    return importlib.import_module(NODE_SCHEMAS[node]).PARAMETERS


def main() -> int:
    for node in NODE_SCHEMAS:
        print(f"<!-- parameters of {node} -->\n{markdown_table(node_schema(node))}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
