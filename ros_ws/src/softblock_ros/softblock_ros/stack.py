"""The stack description (config/stack.yaml): which nodes run, how each starts, with which parameter files,
at which niceness, in which namespace and which machines their DDS traffic reaches (softblock_ros.network).
The launcher, the demo and the ros2 launch file all read it."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from planner.bounded_yaml import load_yaml_file
from recording.topics import is_namespace
from softblock_config import config_file

from .network import NetworkSettings, parse_network
from .parameter_files import check_parameter_file

DEFAULT_STACK_FILE = config_file("stack.yaml")
MAX_FILE_SIZE = 64 * 1024  # [bytes] a stack description is a page of YAML
NODE_KEYS = {"name", "module", "arguments", "executable", "parameters", "niceness", "optional"}


@dataclass(frozen=True)
class NodeSpec:
    name: str
    module: str                         # python -m <module> <arguments...>
    executable: str                     # ros2 run softblock_ros <executable>
    arguments: tuple[str, ...] = ()
    parameters: tuple[Path, ...] = ()   # parameter files, in order
    niceness: int = 0
    optional: bool = False             # started only when named (e.g. the live view)


@dataclass(frozen=True)
class StackDescription:
    namespace: str
    nodes: tuple[NodeSpec, ...]
    network: NetworkSettings = NetworkSettings()

    def node(self, name: str) -> NodeSpec:
        for spec in self.nodes:
            if spec.name == name:
                return spec
        raise ValueError(f"unknown node {name!r}; known: {', '.join(self.names)}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(spec.name for spec in self.nodes)

    @property
    def default_names(self) -> tuple[str, ...]:
        """The nodes started when none are named: all but the optional ones."""
        return tuple(spec.name for spec in self.nodes if not spec.optional)


def _fail(source, where: str, value, expectation: str):
    raise ValueError(f"{source}: {where}={value!r}: {expectation}")


def check_namespace(namespace, where: str, optional: bool = True) -> str:
    """``namespace`` if it is one rcl takes (recording.topics.is_namespace), or "" (none) where ``optional``;
    ValueError otherwise (rcl would end every node's start)."""
    if not isinstance(namespace, str) or (namespace or not optional) and not is_namespace(namespace):
        none = "\"\" (none) or " if optional else ""
        raise ValueError(f"{where}={namespace!r}: expected {none}a namespace such as /robot1 (letters, digits and '_' "
                         "after each '/')")
    return namespace


def _strings(source, where: str, value) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(item, str) and item for item in value):
        _fail(source, where, value, "a list of non-empty strings")
    return tuple(value)


def _node(source, index: int, entry, folder: Path) -> NodeSpec:
    where = f"nodes[{index}]"
    if not isinstance(entry, dict):
        _fail(source, where, entry, "a mapping with name, module and executable")
    unknown = sorted(set(entry) - NODE_KEYS)
    if unknown:
        _fail(source, where, unknown, f"unknown key(s); allowed: {sorted(NODE_KEYS)}")
    for key in ("name", "module", "executable"):
        if not isinstance(entry.get(key), str) or not entry[key]:
            _fail(source, f"{where}.{key}", entry.get(key), "a non-empty string")
    niceness = entry.get("niceness", 0)
    if isinstance(niceness, bool) or not isinstance(niceness, int) or not 0 <= niceness <= 19:
        _fail(source, f"{where}.niceness", niceness, "an integer 0..19")
    if not isinstance(entry.get("optional", False), bool):
        _fail(source, f"{where}.optional", entry["optional"], "true or false")
    parameters = tuple(folder / name for name in _strings(source, f"{where}.parameters", entry.get("parameters", [])))
    for path in parameters:
        if path.parent != folder or not path.is_file():
            _fail(source, f"{where}.parameters", path.name, f"a parameter file in {folder}")
        check_parameter_file(path)
    return NodeSpec(entry["name"], entry["module"], entry["executable"],
                    _strings(source, f"{where}.arguments", entry.get("arguments", [])), parameters, niceness,
                    entry.get("optional", False))


def load_stack(path: str | Path = DEFAULT_STACK_FILE) -> StackDescription:
    """Read (bounded: planner.bounded_yaml) and check a stack description; ValueError names the file, the entry
    and the field."""
    path = Path(path)
    document = load_yaml_file(path, MAX_FILE_SIZE)
    if not isinstance(document, dict) or set(document) - {"namespace", "nodes", "network"}:
        _fail(path, "top level", document if not isinstance(document, dict) else sorted(document),
              "a mapping with the keys namespace, nodes and network")
    namespace = check_namespace(document.get("namespace", ""), f"{path}: namespace")
    entries = document.get("nodes")
    if not isinstance(entries, list) or not entries:
        _fail(path, "nodes", entries, "a non-empty list of nodes")
    nodes = tuple(_node(path, index, entry, path.parent) for index, entry in enumerate(entries))
    names = [spec.name for spec in nodes]
    if len(set(names)) != len(names):
        _fail(path, "nodes", names, "node names must be unique")
    return StackDescription(namespace, nodes, parse_network(path, document.get("network")))
