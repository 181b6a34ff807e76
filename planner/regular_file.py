"""Opening a file named by a user or a client, as a regular file only, without blocking (no ROS).

A FIFO blocks an open for reading until a writer comes, a device such as /dev/zero never ends: both are
refused from their stat, before any open; the open itself does not block either (O_NONBLOCK), in case the
file was swapped for a FIFO in between, and the opened file is checked again.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path


class NotARegularFileError(ValueError):
    """The path names a FIFO, a device, a socket or a directory."""


def open_regular(path: str | Path) -> int:
    """A read-only descriptor (close-on-exec) of the regular file ``path``; NotARegularFileError for anything
    else, OSError when it cannot be opened."""
    if not stat.S_ISREG(os.stat(path).st_mode):
        raise NotARegularFileError(f"{path}: not a regular file")
    descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    if not stat.S_ISREG(os.fstat(descriptor).st_mode):
        os.close(descriptor)
        raise NotARegularFileError(f"{path}: not a regular file")
    return descriptor
