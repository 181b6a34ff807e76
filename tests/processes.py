"""Processes started by tests, and how every one of them ends with its test.

``start`` runs a command in its own process group; ``kill_tree`` freezes a process and everything it
started (its descendants, whatever their process groups: the launcher puts each node in its own), then
kills them all. tests/conftest.py kills what a test leaves behind, also when pytest-timeout fails it.
"""
from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path


def _parents() -> dict[int, int]:
    """pid -> parent pid of every live (not zombie) process, from /proc."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            # /proc/<pid>/stat: "pid (comm) state ppid ..."; comm may hold spaces and parentheses
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue  # ended meanwhile
        if fields[0] != "Z":
            parents[int(entry.name)] = int(fields[1])
    return parents


def descendants(pid: int) -> set[int]:
    """Live processes below ``pid`` (children, their children, ...)."""
    children: dict[int, list[int]] = {}
    for child, parent in _parents().items():
        children.setdefault(parent, []).append(child)
    found, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def _signal(pids, signum) -> None:
    for pid in pids:
        try:
            os.kill(pid, signum)
        except ProcessLookupError:
            pass


def kill_tree(pids) -> None:
    """SIGKILL ``pids`` and all their descendants. They are stopped first, so none can start a process that
    escapes (an orphan would be adopted by init and no longer found below them)."""
    frozen: set[int] = set()
    while True:
        tree = set(pids).union(*(descendants(pid) for pid in pids)) - {os.getpid()}
        if tree <= frozen:
            break
        _signal(tree - frozen, signal.SIGSTOP)
        frozen |= tree
    _signal(frozen, signal.SIGKILL)


def start(command: list[str], **popen_kwargs) -> subprocess.Popen:
    """Popen in a new process group, so a terminal's or a test's signals reach it only on purpose."""
    return subprocess.Popen(command, process_group=0, **popen_kwargs)


def stop(process: subprocess.Popen, timeout: float, signum: int = signal.SIGINT) -> int | None:
    """Send ``signum`` and wait up to ``timeout`` s for the exit status; past it, kill the process and all it
    started and return None."""
    if process.poll() is None:
        process.send_signal(signum)
    try:
        return process.wait(timeout)
    except subprocess.TimeoutExpired:
        kill_tree([process.pid])
        process.wait()
        return None
