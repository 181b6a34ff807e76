"""The stack's shipped data, installed as the package ``softblock_config``: the look-up table, assemblies,
sample objects, sequences, per-block calibration, node parameter files and the stack description.

Code finds these files with ``config_file("assemblies/gripper.yaml")``, which works the same from the
source tree (editable install) and from an installed wheel.
"""
from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def config_file(relative: str | Path = "") -> Path:
    """Path of a shipped data file (or of the data folder itself for ``""``); it need not exist."""
    return Path(str(files(__name__))) / relative
