"""A simulated HV supply on a pseudo-terminal: the serial side every simulated dialect shares.

`PtyDevice` owns the pty, serves it in a thread (lines in, answers out with the dialect's echo and terminators),
steps the channels' plants on the device's clock, keeps a log of the lines received, and injects the same faults
into every dialect: ``over_current`` (an arc: film breakdown), ``no_reply`` (silence; lines are still executed),
``deaf`` (the device stops reading its input, as with a pulled cable on its receive line: nothing is executed or
answered; when it resumes, `clear_faults`, it first loses the line it comes back in the middle of), ``garbled`` and
``partial`` replies, ``disconnect``, ``device_reset``, ``readback_drift`` and ``load_change`` (the load's capacitance ten times
larger, e.g. a short across part of the film), at once (``inject``) or as the device answers a given line
(``inject_after``: a fault in the middle of the host's set-up). A subclass gives the framing and answers the
command set: ``execute(line)`` returns the answer line, or None for a line the device does not answer.

Time is the device's ``clock`` (`hv_driver.clock`; default the real monotonic clock). On a `SimulatedClock` the
device is not started on a pty: `sim_fallback.memory_port.MemoryPort` hands each line to `feed` and its answer
back at once, on the same clock as the driver.
"""
import dataclasses
import os
import select
import threading
import tty
from collections import deque

import numpy as np

from hv_driver.clock import MONOTONIC

from .hv_plant import ChannelDefaults, DeaLoad, PlantChannel, PlantEvent

FAULTS = ("over_current", "no_reply", "deaf", "garbled", "partial", "disconnect", "device_reset", "readback_drift",
          "load_change")
DRIFT_RATE = 500.0       # [V/s] readback error growth under readback_drift
LOAD_CHANGE_FACTOR = 10  # capacitance multiplier under load_change
MAX_LINE = 4096          # [bytes] a longer line without terminator is dropped


class PtyDevice:
    """Base of the simulated supplies.

    channels: outputs of this device; defaults / load: per-channel power-up configuration and load;
    watchdog_s: outputs go off (emergency) when no line arrives for this long; None (default) = no host watchdog;
    rng: seed or numpy Generator for garbled replies; clock: the device's time (`hv_driver.clock`).
    """

    command_terminator: bytes = b"\r\n"
    reply_terminator: bytes = b"\r\n"
    echo: bool = False
    default_defaults = ChannelDefaults()

    def __init__(self, channels: int = 1, defaults: ChannelDefaults | None = None, load: DeaLoad = DeaLoad(),
                 watchdog_s: float | None = None, rng=0, tick_s: float = 0.001, clock=MONOTONIC):
        if channels < 1:
            raise ValueError(f"channels={channels}: at least 1")
        self.plant = [PlantChannel(defaults or self.default_defaults, load) for _ in range(channels)]
        self._loads = [load] * channels
        self.watchdog_s = watchdog_s
        self._rng = np.random.default_rng(rng)
        self._tick = tick_s
        self.clock = clock
        self._lock = threading.Lock()
        self._modes: set[str] = set()
        self._armed: list[tuple[str, str, list[int]]] = []  # (command, fault, channels) of inject_after
        self.command_log: deque[tuple[float, str]] = deque(maxlen=20000)
        self.port: str | None = None
        self._master = self._slave = None
        self._thread: threading.Thread | None = None
        self._running = False
        self.connected = True  # False after an injected disconnect (the cable is pulled)
        self._last_command = self._last_step = clock()
        self._line = bytearray()
        self._mid_line = False  # input resumed after ``deaf``: bytes up to the next line end are a lost line

    # --- lifecycle -----------------------------------------------------------------------------
    def start(self):
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no line discipline: bytes pass unchanged, no tty echo
        self.port = os.ttyname(self._slave)
        self._running = True
        self._last_command = self._last_step = self.clock()
        self._thread = threading.Thread(target=self._serve, name=f"sim-{type(self).__name__}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    # --- fault injection -----------------------------------------------------------------------
    def inject(self, fault: str, channel: int | None = None) -> float:
        """Inject ``fault`` (one of FAULTS; channel None = every channel); returns its time stamp."""
        targets = self._fault_targets(fault, channel)
        with self._lock:
            now = self.clock()
            self._step(now)
            self._apply_fault(fault, targets, now)
        return now

    def inject_after(self, command: str, fault: str, channel: int | None = None) -> None:
        """Inject ``fault`` right after the device has answered the next line that equals ``command``: a fault
        in the middle of a conversation, placed by the host's own progress rather than by a test's timing."""
        targets = self._fault_targets(fault, channel)
        with self._lock:
            self._armed.append((command, fault, targets))

    def _fault_targets(self, fault: str, channel: int | None) -> list[int]:
        if fault not in FAULTS:
            raise ValueError(f"fault={fault!r}: one of {', '.join(FAULTS)}")
        return self._channels(channel)

    def _apply_fault(self, fault: str, targets: list[int], now: float) -> None:
        """Start ``fault`` on ``targets`` (the lock held, the plants stepped to ``now``)."""
        if fault == "over_current":
            for ch in targets:
                if self.plant[ch].output_on:
                    self.plant[ch].arcing = True
                    self.plant[ch].events |= PlantEvent.ARC
        elif fault == "readback_drift":
            for ch in targets:
                self.plant[ch].drift_rate = DRIFT_RATE
        elif fault == "load_change":
            for ch in targets:
                load = self._loads[ch]
                self.plant[ch].load = dataclasses.replace(load, capacitance=load.capacitance * LOAD_CHANGE_FACTOR)
        elif fault == "device_reset":
            for ch in self.plant:
                ch.switch_off(now, emergency=False)
                ch.power_on_reset()
            self.reset_device_state()
        elif fault == "disconnect":
            self._disconnect()
        else:
            self._modes.add(fault)

    def clear_faults(self) -> None:
        """End injected faults and those still waiting for their command (a disconnect stays: the pty is gone)."""
        with self._lock:
            self._modes.clear()
            self._armed.clear()
            for ch, load in zip(self.plant, self._loads):
                ch.arcing = False
                ch.drift = ch.drift_rate = 0.0
                ch.load = load

    def _channels(self, channel: int | None) -> list[int]:
        if channel is None:
            return list(range(len(self.plant)))
        if not 0 <= channel < len(self.plant):
            raise ValueError(f"channel={channel}: between 0 and {len(self.plant) - 1}")
        return [channel]

    def _disconnect(self) -> None:
        self.connected = False
        if self._master is not None:
            os.close(self._master)
            self._master = None

    def watch(self, channel: int, level: float) -> None:
        """Record the times the output of ``channel`` rises and falls through ``level`` [V] from now on."""
        with self._lock:
            self.plant[channel].watch_level = level
            self.plant[channel].rising_edges.clear()
            self.plant[channel].falling_edges.clear()

    def edges(self, channel: int, falling: bool = False) -> list[float]:
        """Rising (``falling``: falling) crossings of the watched level (on the device's clock) so far."""
        with self._lock:
            self._step(self.clock())
            plant = self.plant[channel]
            return list(plant.falling_edges if falling else plant.rising_edges)

    # --- the device ----------------------------------------------------------------------------
    def execute(self, line: str) -> str | None:
        """Answer of one received line (None: no answer)."""
        raise NotImplementedError

    def reset_device_state(self) -> None:
        """Device-wide state a reset restores besides the channels' (none by default)."""

    # --- simulation ----------------------------------------------------------------------------
    def _step(self, now: float) -> None:
        dt, self._last_step = now - self._last_step, now
        for ch in self.plant:
            ch.step(now, dt)

    def _check_watchdog(self, silent_until: float, now: float) -> None:
        """Emergency off when no command arrived from the last one until ``silent_until`` (watchdog_s)."""
        if self.watchdog_s is not None and silent_until - self._last_command > self.watchdog_s:
            for ch in self.plant:
                if ch.output_on:
                    ch.switch_off(now, emergency=True)

    def poll(self, silent_since: float | None = None) -> None:
        """Advance the outputs to the clock's time and apply the host watchdog (no line arrived since
        ``silent_since``; default: now)."""
        with self._lock:
            now = self.clock()
            self._step(now)
            self._check_watchdog(now if silent_since is None else silent_since, now)

    def feed(self, data: bytes) -> bytes:
        """Receive ``data`` from the host at the clock's time; returns the bytes the device sends back."""
        with self._lock:
            now = self.clock()
            self._step(now)
            self._check_watchdog(now, now)
            return self._receive(data) if self.connected else b""

    def _serve(self) -> None:
        while self._running:
            master = self._master
            waited_from = self.clock()
            readable = []
            if master is not None:
                try:
                    readable, _, _ = select.select([master], [], [], self._tick)
                except (OSError, ValueError):
                    readable = []
            else:
                self.clock.sleep(self._tick)
            data = b""
            if readable:
                try:
                    data = os.read(master, 4096)
                except OSError:
                    data = b""
            with self._lock:
                self._step(self.clock())
                out = self._receive(data) if data else b""
                if out and self._master is not None:
                    try:
                        os.write(self._master, out)
                    except OSError:
                        pass
            # A simulator descheduled on a loaded host must not read its own delay as a silent host
            # (a device sees bytes as they arrive): bytes that waited in the pty were received above,
            # and an empty wait proves silence only up to when it began.
            self.poll(waited_from)

    def _receive(self, data: bytes) -> bytes:
        """Take in the host's bytes (the lock held, the plants stepped); returns what the device sends back."""
        terminator, out = self.command_terminator, b""
        if "deaf" in self._modes:
            self._line.clear()
            self._mid_line = True
            return out
        for byte in data:
            self._line.append(byte)
            if self._line.endswith(terminator) and self._mid_line:  # the tail of a line whose start was lost
                self._line.clear()
                self._mid_line = False
            elif self._line.endswith(terminator):
                line = self._line[:-len(terminator)].decode("ascii", errors="replace")
                self._line.clear()
                self._last_command = self.clock()
                self.command_log.append((self._last_command, line))
                out += self._reply(line, self.execute(line))
                for armed in [armed for armed in self._armed if armed[0] == line]:
                    self._armed.remove(armed)
                    self._apply_fault(armed[1], armed[2], self._last_command)
            elif len(self._line) > MAX_LINE:
                self._line.clear()
        return out

    def _reply(self, line: str, answer: str | None) -> bytes:
        if "no_reply" in self._modes or not self.connected:
            return b""
        out = (line.encode("ascii", errors="replace") + self.reply_terminator) if self.echo else b""
        if answer is not None:
            out += answer.encode("ascii") + self.reply_terminator
        if not out:
            return b""
        if "garbled" in self._modes:
            body = bytearray(out[:-len(self.reply_terminator)])
            if body:
                for i in self._rng.choice(len(body), size=max(1, len(body) // 4), replace=False):
                    body[i] = int(self._rng.integers(33, 127))
            out = bytes(body) + self.reply_terminator
        elif "partial" in self._modes:
            out = out[: len(out) // 2]
        return out

    def status_text(self) -> str:
        with self._lock:
            return "; ".join(f"ch{i}: {'ON' if ch.output_on else 'off'} {ch.voltage:.1f} V set {ch.voltage_set:.1f} V "
                             f"{ch.measured_current * 1e6:.2f} uA" for i, ch in enumerate(self.plant))
