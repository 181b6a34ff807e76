"""The simulated supply in a process of its own, driven through its command line (stdin/stdout).

A real supply is a separate device; running the simulation in the driver's own process makes it share
the interpreter lock with the driver and its ROS executor, so under load it answers late and the driver
sees link faults that a real supply would never cause. Same API as ``SimulatedSupply`` for what a
driver host needs: ``start()`` -> ``port``, ``inject()``, ``clear_faults()``, ``stop()``.
"""
from __future__ import annotations

import subprocess
import sys
import threading

from .hv_supply import FAULTS

START_TIMEOUT = 30.0  # [s] for the child to print its pty path (interpreter start-up on a loaded machine)
REPLY_TIMEOUT = 10.0  # [s] for the answer to one command


class SimulatedSupplyProcess:
    def __init__(self, channels: int = 2, watchdog_s: float | None = None):
        if channels < 1:
            raise ValueError(f"channels={channels}: at least 1")
        self.channels = channels
        self.watchdog_s = watchdog_s
        self.port: str | None = None
        self._process: subprocess.Popen | None = None
        self._lock = threading.Lock()

    def start(self) -> SimulatedSupplyProcess:
        command = [sys.executable, "-m", "sim_fallback.hv_supply", "--channels", str(self.channels),
                   "--watchdog", str(self.watchdog_s or 0)]
        self._process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                         bufsize=1)
        self.port = self._read_line(START_TIMEOUT, "its pty path")
        return self

    def _read_line(self, timeout: float, what: str) -> str:
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.append(self._process.stdout.readline()), daemon=True)
        reader.start()
        reader.join(timeout)
        if not lines or not lines[0]:
            self.stop()
            raise RuntimeError(f"simulated supply process gave no {what} within {timeout:g} s")
        return lines[0].strip()

    def _command(self, line: str) -> str:
        if self._process is None or self._process.poll() is not None:
            raise RuntimeError("simulated supply process is not running")
        with self._lock:
            self._process.stdin.write(line + "\n")
            self._process.stdin.flush()
            reply = self._read_line(REPLY_TIMEOUT, f"answer to {line!r}")
        if reply.startswith("error: "):
            raise ValueError(reply.removeprefix("error: "))
        return reply

    def inject(self, fault: str, channel: int | None = None) -> None:
        """Inject ``fault`` (see ``sim_fallback.hv_supply.FAULTS``); ValueError for an unknown one."""
        if fault not in FAULTS:  # checked here too: the name goes into the child's command line
            raise ValueError(f"fault={fault!r}: one of {', '.join(FAULTS)}")
        if channel is not None and not (isinstance(channel, int) and 0 <= channel < self.channels):
            raise ValueError(f"channel={channel!r}: between 0 and {self.channels - 1}")
        self._command(fault if channel is None else f"{fault} {channel}")

    def clear_faults(self) -> None:
        self._command("clear")

    def stop(self) -> None:
        process, self._process = self._process, None
        if process is None:
            return
        try:
            process.stdin.write("quit\n")
            process.stdin.flush()
            process.wait(timeout=5.0)
        except (OSError, ValueError, subprocess.TimeoutExpired):
            process.kill()
            process.wait()

    def __enter__(self) -> SimulatedSupplyProcess:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
