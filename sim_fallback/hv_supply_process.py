"""The simulated supply in a process of its own, driven through its command line (stdin/stdout).

A real supply is a separate device; running the simulation in the driver's own process makes it share
the interpreter lock with the driver and its ROS executor, so under load it answers late and the driver
sees link faults that a real supply would never cause. Same API as ``SimulatedSupply`` for what a
driver host needs: ``start()`` -> ``port`` (``ports``: one per device of a rig), ``inject()``, ``clear_faults()``,
``stop()``; ``watch()`` / ``edges()`` read the simulated outputs' own rising edges (benchmarks).
"""
from __future__ import annotations

import subprocess
import sys
import threading

from .pty_device import FAULTS
from .rig import channels_per_device, check_address

START_TIMEOUT = 30.0  # [s] for the child to print its pty path (interpreter start-up on a loaded machine)
REPLY_TIMEOUT = 10.0  # [s] for the answer to one command


class SimulatedSupplyProcess:
    """dialect: which simulator (sim_fallback.rig.SIMULATORS); devices: how many (each on its own pty); channels:
    per device, where the dialect has several."""

    def __init__(self, channels: int = 2, watchdog_s: float | None = None, dialect: str = "iseg-edcp",
                 devices: int = 1):
        if channels < 1 or devices < 1:
            raise ValueError(f"channels={channels}, devices={devices}: at least 1 each")
        self.dialect, self.devices = dialect, devices
        self.channels = channels_per_device(dialect, channels)
        self.watchdog_s = watchdog_s
        self.ports: list[str] = []
        self._process: subprocess.Popen | None = None
        self._lock = threading.Lock()

    @property
    def pid(self) -> int | None:
        return self._process.pid if self._process is not None else None

    @property
    def port(self) -> str | None:
        return self.ports[0] if self.ports else None

    def start(self) -> SimulatedSupplyProcess:
        command = [sys.executable, "-m", "sim_fallback.rig", "--dialect", self.dialect, "--devices",
                   str(self.devices), "--channels", str(self.channels), "--watchdog", str(self.watchdog_s or 0)]
        self._process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                         bufsize=1)
        self.ports = [self._read_line(START_TIMEOUT, "its pty path") for _ in range(self.devices)]
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

    def _address(self, channel: int | None, device: int | None) -> str:
        check_address(channel, device, self.channels, self.devices)
        return ("" if channel is None else f" {channel}") + ("" if device is None else f" device={device}")

    def inject(self, fault: str, channel: int | None = None, device: int | None = None) -> None:
        """Inject ``fault`` (see ``sim_fallback.pty_device.FAULTS``) into a channel of a device (None: every one);
        ValueError for an unknown fault, channel or device."""
        if fault not in FAULTS:  # checked here too: the name goes into the child's command line
            raise ValueError(f"fault={fault!r}: one of {', '.join(FAULTS)}")
        self._command(fault + self._address(channel, device))

    def clear_faults(self) -> None:
        self._command("clear")

    def watch(self, channel: int, level: float, device: int = 0) -> None:
        """Record the rising crossings of ``level`` [V] by the simulated output from now on."""
        self._address(channel, device)  # checked
        self._command(f"watch {channel} {float(level)!r} device={device}")

    def edges(self, channel: int, device: int = 0) -> list[float]:
        """The simulated output's rising crossings of the watched level (time.monotonic of this machine)."""
        reply = self._command(f"edges{self._address(channel, device)}")
        return [float(t) for t in reply.split(",") if t]

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
