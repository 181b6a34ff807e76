"""Where the nodes find the project's files (assemblies, tables, object images)."""
from __future__ import annotations

from pathlib import Path

from planner.table import REPO_ROOT


def resolve_path(path: str | Path) -> Path:
    """``path`` as given if it exists or is absolute, else relative to the project root (config/ lives there)."""
    path = Path(path).expanduser()
    if path.is_absolute() or path.exists():
        return path
    return REPO_ROOT / path
