"""Processes started by tests, and how every one of them ends with its test.

``start`` runs a command in its own process group; ``run`` is ``subprocess.run`` that, on a timeout or any
exception, kills the whole tree; ``kill_tree`` freezes a process and everything it started (its
descendants, whatever their process groups: the launcher puts each node in its own), then kills them all.
``adopt_orphans`` makes this process adopt the orphans of its descendants (a killed launcher's nodes), so
they stay in its tree. tests/conftest.py kills what a test leaves behind, also when pytest-timeout fails it.
"""
from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

PR_SET_CHILD_SUBREAPER = 36  # linux/prctl.h


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


def adopt_orphans() -> None:
    """Linux: become the child subreaper, so an orphaned descendant is re-parented here (not to init) and
    ``descendants`` still finds it."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)


def reap(pids, timeout: float = 5.0) -> None:
    """Collect the exit status of those ``pids`` that are children of this process and have been killed
    (adopted orphans would otherwise stay zombies). Only for processes no Popen object still waits for."""
    deadline = time.monotonic() + timeout
    for pid in pids:
        while True:
            try:
                done, _ = os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:
                break  # not a child of this process, or already collected
            if done or time.monotonic() > deadline:
                break
            time.sleep(0.01)


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


def run(command: list[str], timeout: float, **popen_kwargs) -> subprocess.CompletedProcess:
    """``subprocess.run(command, timeout=timeout, capture_output=True, text=True)``, except that on the
    timeout (or a test timeout raised meanwhile) everything the command started is killed as well."""
    process = start(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen_kwargs)
    try:
        out, err = process.communicate(timeout=timeout)
    except BaseException:
        kill_tree([process.pid])
        process.communicate()
        raise
    return subprocess.CompletedProcess(command, process.returncode, out, err)
