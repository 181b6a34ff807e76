"""On-disk cache of arrays that take seconds to build and a moment to load (the finger search's lookahead
fields).

A file is named after a digest of everything its arrays depend on: the caller's key (the inputs), the
source of the modules that build them (the code version) and the numpy and scipy versions. The file holds
that digest and a checksum of its arrays; a file whose digest or checksum does not match (stale, truncated,
corrupt, renamed) is reported, rebuilt and replaced, never used. Files are written atomically
(``planner.atomic_file``), so a concurrent process never reads half a file.
"""
from __future__ import annotations

import hashlib
import importlib
import inspect
import logging
import os
import zipfile
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import scipy

from planner.atomic_file import atomic_write

LOG = logging.getLogger(__name__)
FORMAT = 1  # bump when the file layout below changes
_DIGEST, _CHECKSUM = "__digest__", "__checksum__"


def cache_directory() -> Path:
    """Where cached arrays are kept: $SOFTBLOCK_CACHE, else ~/.cache/softblock."""
    return Path(os.environ.get("SOFTBLOCK_CACHE") or Path.home() / ".cache" / "softblock")


def key_digest(parts: Iterable, modules: Iterable[str] = ()) -> str:
    """sha256 of ``parts`` (numbers, strings, arrays, nested tuples), of the source of the named ``modules``
    and of the library versions the arrays depend on."""
    digest = hashlib.sha256(repr((FORMAT, np.__version__, scipy.__version__)).encode())
    for module in modules:
        digest.update(inspect.getsource(importlib.import_module(module)).encode())
    _update(digest, parts)
    return digest.hexdigest()


def _update(digest, part) -> None:
    if isinstance(part, np.ndarray):
        digest.update(repr((part.dtype.str, part.shape)).encode())
        digest.update(np.ascontiguousarray(part).reshape(-1).view(np.uint8))  # its bytes, not a copy of them
    elif isinstance(part, (tuple, list)):
        digest.update(f"<{len(part)}>".encode())
        for item in part:
            _update(digest, item)
    else:
        digest.update(repr(part).encode())


def checksum(arrays: dict[str, np.ndarray]) -> str:
    """sha256 of the arrays' names, dtypes, shapes and contents."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        digest.update(name.encode())
        _update(digest, arrays[name])
    return digest.hexdigest()


def load_or_build(name: str, digest: str, build: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The arrays stored for ``digest`` (see ``key_digest``) if the file is intact, else ``build()``'s,
    stored for the next process (a read-only cache directory only costs the rebuild)."""
    path = cache_directory() / f"{name}-{digest[:24]}.npz"
    stored, problem = _load(path, digest)
    if stored is not None:
        return stored
    if problem:
        LOG.warning("cache file %s %s: rebuilding it", path, problem)
    arrays = build()
    try:
        with atomic_write(path, "wb") as stream:
            np.savez(stream, **arrays, **{_DIGEST: np.array(digest), _CHECKSUM: np.array(checksum(arrays))})
    except (OSError, ValueError) as error:
        LOG.warning("cannot store cache file %s (%s); the next process builds it again", path, error)
    return arrays


def _load(path: Path, digest: str) -> tuple[dict[str, np.ndarray] | None, str]:
    """(arrays, "") for an intact file of ``digest``; (None, "") if there is none; (None, what is wrong)."""
    try:
        with np.load(path, allow_pickle=False) as stored:
            arrays = {key: stored[key] for key in stored.files}
    except FileNotFoundError:
        return None, ""
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        return None, f"is unreadable ({type(error).__name__}: {error})"
    if str(arrays.pop(_DIGEST, "")) != digest:
        return None, "was built for other inputs or code"
    if str(arrays.pop(_CHECKSUM, "")) != checksum(arrays):
        return None, "does not match its checksum"
    return arrays, ""
