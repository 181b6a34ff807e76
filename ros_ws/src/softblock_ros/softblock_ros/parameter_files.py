"""ROS parameter files (``--params-file``), checked before rcl parses them (no rclpy import).

rcl refuses a file it cannot read from inside rclpy.init (a traceback) and would expand a billion laughs. So a file
is read bounded (planner.bounded_yaml) and accepted only in the shape rcl reads, with values rcl reads the way they
are meant: ``<node>: {ros__parameters: {<name>: <value or nested names>}}``, where a node is ``name``,
``namespace/name``, ``/namespace/name`` or a ``/**`` wildcard. rcl types each unquoted scalar itself (``09`` is a
double, ``1e5`` too, ``y`` a bool), not as PyYAML does, and refuses a list whose items it types differently; a list
item is therefore accepted only where its type is plain (a quoted string, a decimal integer or number, a bool word,
a word). A value left empty (or ``~``, ``null``), an empty group of parameters (rcl misreads what follows it), a
YAML tag and a repeated key are refused too. Every refusal is one ValueError line naming the file, the line and what
to write instead.
"""
from __future__ import annotations

import re
from pathlib import Path

import yaml

from planner.bounded_yaml import BoundedLoader, load_yaml_file

SHAPE = "not a parameter file: expected <node name>: {ros__parameters: {...}}"
_SEGMENT = r"[A-Za-z_][A-Za-z0-9_]*"
# name, ns/name, /ns/name, /**, /*/name; rcl refuses a leading digit, '-', '.', '//', a trailing '/'
NODE_NAME = re.compile(rf"(/({_SEGMENT}|\*\*?))+|{_SEGMENT}(/{_SEGMENT})*")
PARAMETER_NAME = re.compile(rf"{_SEGMENT}(\.{_SEGMENT})*")
# How rcl types an unquoted scalar (rcl_yaml_param_parser), where PyYAML agrees on the text being one value.
RCL_BOOL_WORDS = frozenset("y Y yes Yes YES true True TRUE on On ON n N no No NO false False FALSE off Off OFF".split())
RCL_INTEGER = re.compile(r"[-+]?(0|[1-9][0-9]{0,17})")  # strtol: no octal/hex look-alikes, no overflow
RCL_DOUBLE = re.compile(r"[-+]?([0-9]{1,30}\.[0-9]{0,30}|\.[0-9]{1,30})([eE][-+]?[0-9]{1,2})?"
                        r"|[-+]?\.(inf|Inf|INF)|\.(nan|NaN|NAN)")
RCL_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_./-]*")
_STRTOD_WORDS = {"inf", "infinity", "nan"}  # rcl reads these as doubles, in any case


def _rcl_type(item: yaml.ScalarNode) -> str | None:
    """The type rcl gives a list item, or None where the text is not plainly one."""
    if item.style is not None:  # quoted, or a block scalar
        return "string"
    text = item.value
    if text in RCL_BOOL_WORDS:
        return "bool"
    if RCL_INTEGER.fullmatch(text):
        return "integer"
    if RCL_DOUBLE.fullmatch(text):
        return "double"
    if RCL_WORD.fullmatch(text) and text.lower() not in _STRTOD_WORDS:
        return "string"
    return None


class _Check:
    def __init__(self, path: str | Path):
        self.path = path
        self._resolver = BoundedLoader("")

    def fail(self, node: yaml.Node, problem: str):
        raise ValueError(f"{self.path}: line {node.start_mark.line + 1}: {problem}")

    def _tagged(self, node: yaml.Node) -> bool:
        """Whether the node carries an explicit YAML tag (``!!str 1``): rcl ignores tags."""
        if isinstance(node, yaml.ScalarNode):
            implicit = (node.style is None, node.style is not None)
            return node.tag != self._resolver.resolve(yaml.ScalarNode, node.value, implicit)
        default = yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG if isinstance(node, yaml.MappingNode) \
            else yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG
        return node.tag != default

    def entries(self, mapping: yaml.MappingNode, what: str):
        """(key text, value node) of a mapping whose keys are distinct, non-empty scalars."""
        seen = set()
        for key, value in mapping.value:
            if not isinstance(key, yaml.ScalarNode) or not key.value:
                self.fail(key, f"a {what} must be a non-empty name")
            for node in (key, value):
                if self._tagged(node):
                    self.fail(node, f"YAML tag {node.tag} under {key.value!r}: ROS reads no tags; write the value "
                                    "plainly")
            if key.value in seen:
                self.fail(key, f"{what} {key.value!r} appears twice")
            seen.add(key.value)
            yield key.value, value

    def document(self, root) -> None:
        if not isinstance(root, yaml.MappingNode):
            raise ValueError(f"{self.path}: {SHAPE}")
        for node_name, section in self.entries(root, "node name"):
            if not NODE_NAME.fullmatch(node_name) or "__" in node_name:
                self.fail(section, f"node name {node_name!r}: expected name, namespace/name, /namespace/name or /** "
                                   "(letters, digits, '_'; no leading digit)")
            keys = [key.value for key, _ in section.value] if isinstance(section, yaml.MappingNode) else None
            if keys != ["ros__parameters"]:
                self.fail(section, f"node {node_name!r}: expected exactly one key, ros__parameters, holding the "
                                   f"parameters; found {'a value' if keys is None else keys}")
            for _, parameters in self.entries(section, "key"):
                if not isinstance(parameters, yaml.MappingNode):
                    self.fail(parameters, f"node {node_name!r}: ros__parameters must be a mapping of parameter names "
                                          "to values")
                self.parameters(parameters, "")

    def parameters(self, mapping: yaml.MappingNode, prefix: str) -> None:
        for key, value in self.entries(mapping, "parameter name"):
            name = prefix + key
            if not PARAMETER_NAME.fullmatch(key):
                self.fail(value, f"parameter name {name!r}: letters, digits, '_' and '.', no leading digit")
            if isinstance(value, yaml.MappingNode):
                if not value.value:  # rcl then misreads the names after it
                    self.fail(value, f"parameter group {name}: empty; leave it out")
                self.parameters(value, name + ".")
            elif isinstance(value, yaml.SequenceNode):
                self.sequence(value, name)
            else:
                self.scalar(value, name)

    def scalar(self, value: yaml.ScalarNode, name: str) -> None:
        if value.tag == "tag:yaml.org,2002:null" or (not value.value and value.style not in ("'", '"')):
            self.fail(value, f"parameter {name} has no value (empty, ~ or null); give one ('' for an empty "
                             "string), or leave the parameter out for its default")

    def sequence(self, value: yaml.SequenceNode, name: str) -> None:
        types = set()
        for index, item in enumerate(value.value):
            if not isinstance(item, yaml.ScalarNode):
                self.fail(item, f"parameter {name}[{index}]: a list holds numbers, bools or strings, not lists or "
                                "mappings")
            if self._tagged(item):
                self.fail(item, f"parameter {name}[{index}]: YAML tag {item.tag}: ROS reads no tags")
            self.scalar(item, f"{name}[{index}]")
            item_type = _rcl_type(item)
            if item_type is None:
                self.fail(item, f"parameter {name}[{index}]: {item.value[:40]!r} is not plainly a number, a bool or "
                                "a word; quote a string, write a number as 12 or 1.5")
            types.add(item_type)
        if len(types) > 1:
            self.fail(value, f"parameter {name}: a list of mixed types ({', '.join(sorted(types))}); a ROS list holds "
                             "one type (quote strings, write 1.0 for a double)")


def check_parameter_file(path: str | Path) -> None:
    """ValueError (one line) unless ``path`` is a bounded YAML parameter file that rcl reads as written (see the
    module docstring)."""
    _Check(path).document(load_yaml_file(path, read=yaml.compose))
