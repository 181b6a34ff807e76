"""ROS parameter files (``--params-file``), checked before rcl parses them (no rclpy import).

rcl answers a YAML syntax error or an alias with a 20-line traceback, and would expand a billion laughs; read
bounded (planner.bounded_yaml) first, a bad file is one line naming the file and the place.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from planner.bounded_yaml import load_yaml_file


def check_parameter_file(path: str | Path) -> None:
    """ValueError (one line) unless ``path`` is a bounded YAML mapping of node names to mappings, the shape rcl
    reads (``<node>: {ros__parameters: {...}}``)."""
    document = load_yaml_file(path)
    if not isinstance(document, dict) or not all(isinstance(section, dict) for section in document.values()):
        raise ValueError(f"{path}: not a parameter file: expected <node name>: {{ros__parameters: {{...}}}}")


def check_parameter_files(args: Sequence[str]) -> None:
    """check_parameter_file for every ``--params-file FILE`` in a command line."""
    for flag, path in zip(args, args[1:]):
        if flag == "--params-file":
            check_parameter_file(path)
