"""Write a file so that it is either complete or untouched: into a temporary file beside it, then rename.

A write that fails part-way (disk full, a killed process) leaves the old file as it was, and the target
is replaced as a name: writing onto a symlink replaces the link, never the file it points to. Used by the
look-up table generator and the recording recovery.
"""
from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path


def check_writable_target(path: str | Path) -> Path:
    """``path`` if it is absent or a regular file; ValueError for a directory, a device or a FIFO."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path} is a directory; give a file name")
    if path.exists() and not path.is_file():
        raise ValueError(f"{path} is not a regular file; give a file name")
    return path


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "w", replace: bool = True, **open_kwargs):
    """Context manager yielding a file opened on a temporary file next to ``path``; on a clean exit the data
    is flushed to disk and the temporary file renamed to ``path``, on an exception it is removed. Without
    ``replace`` a ``path`` that exists by then is kept (FileExistsError): the file is linked, not renamed."""
    path = check_writable_target(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        # mkstemp's 0600 would make the new file private: keep the old file's mode, or the usual 0644
        os.fchmod(handle, stat.S_IMODE(path.stat().st_mode) if path.exists() else 0o644)
        with open(handle, mode, **open_kwargs) as stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        if replace:
            os.replace(temporary, path)
        else:
            os.link(temporary, path)
            os.remove(temporary)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.remove(temporary)
        raise
