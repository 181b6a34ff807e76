"""Where the nodes find files named in parameters and requests (assemblies, tables, object images)."""
from __future__ import annotations

from pathlib import Path

from softblock_config import config_file


def resolve_path(path: str | Path) -> Path:
    """``path`` as given if it is absolute or exists (relative to the working directory), else the shipped
    data file of that name (``assemblies/gripper.yaml`` -> the installed config/assemblies/gripper.yaml)."""
    path = Path(path).expanduser()
    if path.is_absolute() or path.exists():
        return path
    return config_file(path)
