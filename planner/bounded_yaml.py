"""Every YAML the project reads, read bounded before it is parsed (no ROS).

Stack descriptions, parameter files, assemblies, object catalogs, calibrations, sequences and the QoS text
inside recordings come from users, clients and other programs. A file must be a regular file (a FIFO or a
device is refused without a blocking open), at most ``max_size`` bytes are read, lists and mappings nest at
most MAX_DEPTH levels, and YAML anchors and aliases are refused: they let a 400-byte file expand to
gigabytes (a "billion laughs") or refer to itself. Every problem is one YAMLInputError (a ValueError) naming
the source and the place, without quoting the document.
"""
from __future__ import annotations

import os
from pathlib import Path

import yaml

from .regular_file import NotARegularFileError, open_regular

MAX_FILE_SIZE = 256 * 1024  # [bytes] the project's YAML files are below 20 KB
MAX_DEPTH = 32              # nested lists and mappings in a document
MAX_PROBLEM = 80            # characters of a parser's problem quoted in an error


class YAMLInputError(ValueError):
    """A YAML file or text that is refused before or while parsing; the message is one line."""


class BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader without anchors and aliases, and with a nesting limit (the composer recurses)."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None):
            problem = "anchors and aliases (&name, *name) are not allowed; write the value out"
            raise yaml.MarkedYAMLError(problem=problem, problem_mark=event.start_mark)
        if self._depth >= MAX_DEPTH:
            raise yaml.MarkedYAMLError(problem=f"nested deeper than {MAX_DEPTH} levels",
                                       problem_mark=event.start_mark)
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _one_line(source: str, error: yaml.YAMLError) -> YAMLInputError:
    """The place and the problem, without the document's text (PyYAML's message quotes the line)."""
    mark = getattr(error, "problem_mark", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    problem = " ".join((getattr(error, "problem", None) or str(error)).split())
    return YAMLInputError(f"{source}: invalid YAML: {where}{problem[:MAX_PROBLEM]}")


def parse_yaml(text: str | bytes, source: str, max_size: int = MAX_FILE_SIZE, read=yaml.load):
    """The document in ``text`` (at most ``max_size`` characters or bytes); YAMLInputError otherwise. ``read``:
    yaml.load (Python values) or yaml.compose (the node tree: each scalar's text and quoting style, untyped)."""
    if len(text) > max_size:
        raise YAMLInputError(f"{source}: larger than {max_size} bytes, the limit for this file")
    try:
        return read(text, Loader=BoundedLoader)  # a SafeLoader
    except yaml.YAMLError as error:
        raise _one_line(source, error) from None
    except ValueError as error:  # a constructor's, e.g. an integer of more than 4300 digits
        raise YAMLInputError(f"{source}: invalid YAML: {str(error)[:MAX_PROBLEM]}") from None


def read_regular_file(path: str | Path, max_size: int) -> bytes:
    """The bytes of a regular file (planner.regular_file) of at most ``max_size`` bytes; YAMLInputError
    otherwise."""
    try:
        with os.fdopen(open_regular(path), "rb") as stream:
            data = stream.read(max_size + 1)
    except NotARegularFileError as error:
        raise YAMLInputError(str(error)) from None
    except OSError as error:
        raise YAMLInputError(f"{path}: cannot read: {error.strerror}") from None
    if len(data) > max_size:
        raise YAMLInputError(f"{path}: larger than {max_size} bytes, the limit for this file")
    return data


def load_yaml_file(path: str | Path, max_size: int = MAX_FILE_SIZE, read=yaml.load):
    """Read (bounded, see the module docstring) and parse one YAML file (``read``: see parse_yaml);
    YAMLInputError otherwise."""
    return parse_yaml(read_regular_file(path, max_size), str(path), max_size, read)
