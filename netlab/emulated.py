"""The ``python -m netlab`` program as a child process: two emulated hosts, their link, and the processes a
test or benchmark runs on them.

    with EmulatedHosts(("rig", "workstation"), Conditions(delay_s=0.05)) as lab:
        driver = lab.start("rig", ["python", "-m", "my_node"], env=env)
        lab.partition(); ...; lab.heal()

Everything started is killed when the block ends (SIGINT first, SIGKILL after ``stop_timeout``); the
program itself, when it ends, kills whatever still runs in the namespaces and deletes them, also when this
process dies (its stdin closes).
"""
from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import asdict

from .hosts import DEFAULT_SUBNET, Host
from .link import Conditions

STARTUP_TIMEOUT = 30.0  # [s] namespaces and devices on a loaded machine
REPLY_TIMEOUT = 10.0    # [s] for one command's answer
LINK_NICENESS = -20
# Processes stop on SIGINT; one started from a shell that ignores it (a background job, nohup) would inherit the
# ignoring and outlast every stop until the SIGKILL, so each starts with SIGINT at its default.
DEFAULT_SIGINT = ["env", "--default-signal=INT"]


class LabError(RuntimeError):
    """The emulator did not start, answered an error or did not answer in time."""


class EmulatedHosts:
    def __init__(self, names: tuple[str, str] = ("rig", "workstation"), conditions: Conditions = Conditions(),
                 subnet: str = DEFAULT_SUBNET, seed: int | None = None, stop_timeout: float = 10.0):
        self.names, self.subnet, self.seed = names, subnet, seed
        self.initial_conditions = conditions
        self.stop_timeout = stop_timeout
        self.hosts: dict[str, Host] = {}
        self.processes: list[subprocess.Popen] = []
        self._emulator: subprocess.Popen | None = None
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._lock = threading.Lock()

    # --- the emulator ----------------------------------------------------------------------------------
    def open(self) -> EmulatedHosts:
        c = self.initial_conditions
        # The highest priority: a cable is never descheduled, and the emulated link should not be either.
        command = ["nice", "-n", str(LINK_NICENESS), sys.executable, "-m", "netlab", "--hosts", ",".join(self.names),
                   "--subnet", self.subnet,
                   "--delay-s", repr(c.delay_s), "--jitter-s", repr(c.jitter_s), "--loss", repr(c.loss)]
        if self.seed is not None:
            command += ["--seed", str(self.seed)]
        self._emulator = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          stderr=subprocess.PIPE, text=True, process_group=0)
        threading.Thread(target=self._pump, daemon=True).start()
        ready = self._next_reply(STARTUP_TIMEOUT, "the emulated hosts to come up")
        self.hosts = {name: Host(name, **fields) for name, fields in ready["hosts"].items()}
        return self

    def _pump(self) -> None:
        for line in self._emulator.stdout:
            self._lines.put(line)
        self._lines.put(None)

    def _next_reply(self, timeout: float, what: str) -> dict:
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            raise LabError(f"no answer from the link emulator within {timeout:g} s waiting for {what}") from None
        if line is None:
            self._emulator.wait(timeout=5.0)
            raise LabError(f"the link emulator ended (code {self._emulator.returncode}) while waiting for {what}: "
                           f"{self._emulator.stderr.read()[-2000:]}")
        answer = json.loads(line)
        if answer.get("ok") is False:
            raise LabError(f"the link emulator refused: {answer['error']}")
        return answer

    def command(self, line: str) -> dict:
        """Send one command line (see netlab.cli) and return its answer."""
        with self._lock:
            self._emulator.stdin.write(line + "\n")
            self._emulator.stdin.flush()
            return self._next_reply(REPLY_TIMEOUT, repr(line))

    def set_conditions(self, conditions: Conditions) -> dict:
        return self.command("set " + " ".join(f"{k}={v!r}" for k, v in asdict(conditions).items()))

    def partition(self) -> dict:
        return self.command("partition")

    def heal(self) -> dict:
        return self.command("heal")

    def stats(self) -> dict:
        return self.command("stats")["stats"]

    # --- processes on the hosts ------------------------------------------------------------------------
    def start(self, host: str, argv: list[str], env: Mapping[str, str] | None = None,
              **popen_kwargs) -> subprocess.Popen:
        """Run ``argv`` on ``host`` in a process group of its own; it is stopped when the lab closes."""
        process = subprocess.Popen(self.hosts[host].command([*DEFAULT_SIGINT, *argv]), env=dict(env or os.environ),
                                   process_group=0, **popen_kwargs)
        self.processes.append(process)
        return process

    def stop(self, process: subprocess.Popen, timeout: float | None = None) -> int:
        """SIGINT to the process group, SIGKILL after ``timeout`` (default ``stop_timeout``); the exit code."""
        return self.stop_together([process], timeout)[0]

    def stop_together(self, processes: list[subprocess.Popen], timeout: float | None = None) -> list[int]:
        """stop() for several processes at once, so that their stops overlap: SIGINT to each group, SIGKILL to
        those still running ``timeout`` later; their exit codes."""
        timeout = self.stop_timeout if timeout is None else timeout
        for process in processes:
            if process.poll() is None:
                _signal_group(process, signal.SIGINT)
        deadline = time.monotonic() + timeout
        for process in processes:
            try:
                process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                _signal_group(process, signal.SIGKILL)
                process.wait()
        return [process.returncode for process in processes]

    def close(self) -> None:
        for process in reversed(self.processes):
            self.stop(process)
        if self._emulator is None:
            return
        if self._emulator.poll() is None:
            try:
                self._emulator.stdin.close()  # end of input: the emulator removes the hosts and exits
                self._emulator.wait(self.stop_timeout)
            except (OSError, subprocess.TimeoutExpired):
                self._emulator.kill()
                self._emulator.wait()

    def __enter__(self) -> EmulatedHosts:
        try:
            return self.open()
        except BaseException:
            self.close()
            raise

    def __exit__(self, *exc) -> None:
        self.close()


def _signal_group(process: subprocess.Popen, signum: int) -> None:
    try:
        os.killpg(process.pid, signum)
    except ProcessLookupError:
        pass
