"""Simulated iseg NHR-style HV supply speaking the EDCP dialect on a pseudo-terminal.

In process: ``sim = SimulatedSupply(channels=2).start()``; open ``sim.port`` with pyserial;
``sim.inject("over_current", channel=0)``; ``sim.clear_faults()``; ``sim.stop()``.
CLI: ``python -m sim_fallback.hv_supply`` prints the pty path, then reads fault commands from
stdin (``<fault> [channel]``, ``clear``, ``status``, ``quit``).
"""
import argparse
import os
import re
import select
import sys
import threading
import time
import tty
from collections import deque

import numpy as np

from hv_driver.dialects.iseg_edcp import ChannelEvent

from .hv_plant import ChannelDefaults, DeaLoad, PlantChannel

FAULTS = ("over_current", "no_reply", "garbled", "partial", "disconnect", "device_reset", "readback_drift")
IDENTITY = "iseg Spezialelektronik GmbH,NHR 42 50r (simulated),SIM00001,1.00"
ERROR_REPLY = "?"  # answer to a line the simulated device cannot execute
DRIFT_RATE = 500.0  # [V/s] readback error growth under readback_drift

_UNIT = re.compile(r"^(?P<header>[*:A-Z]+\??)(?:\s+(?P<args>.*))?$")
_CHANNELS = re.compile(r"\(@(?P<list>[0-9,\-]+)\)")
_SETTING_ARGS = re.compile(r"(?P<value>.*),(?P<channels>\(@[0-9,\-]+\))")


class CommandError(ValueError):
    """The line cannot be executed (unknown header, bad argument, channel out of range)."""


def _number(field: str) -> float:
    try:
        return float(field)
    except ValueError:
        raise CommandError(f"not a number: {field!r}") from None


def _reading(value: float, unit: str) -> str:
    return f"{value:.5E}{unit}"


# Per-channel queries: header -> answer of one channel (channels answer comma-separated).
_QUERIES = {
    ":MEAS:VOLT?": lambda ch: _reading(ch.measured_voltage, "V"),
    ":MEAS:CURR?": lambda ch: _reading(ch.measured_current, "A"),
    ":READ:CHAN:STATUS?": lambda ch: str(int(ch.status)),
    ":READ:CHAN:EVENT:STATUS?": lambda ch: str(int(ch.events)),
    ":READ:VOLT:LIM?": lambda ch: _reading(ch.defaults.voltage_limit, "V"),
    ":READ:RAMP:VOLT?": lambda ch: _reading(ch.ramp_up, "V/s"),
    ":READ:CURR?": lambda ch: _reading(ch.current_limit, "A"),
    ":CONF:TRIP:TIME?": lambda ch: _reading(ch.trip_time_ms, "ms"),
    ":CONF:TRIP:ACTION?": lambda ch: str(ch.trip_action),
}


class SimulatedSupply:
    """A multi-channel EDCP supply with DEA loads on a pty, with fault injection.

    channels: number of outputs; defaults / load: per-channel power-up configuration and load;
    watchdog_s: outputs go off (emergency) when no command arrives for this long; None (default) = off,
        as on an iseg module, which has no host watchdog (a keep-alive supply is modelled by setting it);
    rng: seed or numpy Generator for garbled replies.
    """

    def __init__(self, channels: int = 2, defaults: ChannelDefaults = ChannelDefaults(),
                 load: DeaLoad = DeaLoad(), watchdog_s: float | None = None, rng=0, tick_s: float = 0.001):
        if channels < 1:
            raise ValueError(f"channels={channels}: at least 1")
        self.plant = [PlantChannel(defaults, load) for _ in range(channels)]
        self.watchdog_s = watchdog_s
        self._rng = np.random.default_rng(rng)
        self._tick = tick_s
        self._lock = threading.Lock()
        self._modes: set[str] = set()
        self.command_log: deque[tuple[float, str]] = deque(maxlen=20000)
        self.port: str | None = None
        self._master = self._slave = None
        self._thread: threading.Thread | None = None
        self._running = False
        self._last_command = self._last_step = time.monotonic()
        self._line = bytearray()

    # --- lifecycle -----------------------------------------------------------------------------
    def start(self) -> "SimulatedSupply":
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no line discipline: bytes pass unchanged, no tty echo
        self.port = os.ttyname(self._slave)
        self._running = True
        self._last_command = self._last_step = time.monotonic()
        self._thread = threading.Thread(target=self._serve, name="sim-hv-supply", daemon=True)
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
        if fault not in FAULTS:
            raise ValueError(f"fault={fault!r}: one of {', '.join(FAULTS)}")
        targets = self._channels(channel)
        with self._lock:
            now = time.monotonic()
            self._step(now)
            if fault == "over_current":
                for ch in targets:
                    if self.plant[ch].output_on:
                        self.plant[ch].arcing = True
                        self.plant[ch].events |= ChannelEvent.EVENT_ARC
            elif fault == "readback_drift":
                for ch in targets:
                    self.plant[ch].drift_rate = DRIFT_RATE
            elif fault == "device_reset":
                for ch in self.plant:
                    ch.switch_off(now, emergency=False)
                    ch.power_on_reset()
            elif fault == "disconnect":
                self._disconnect()
            else:
                self._modes.add(fault)
        return now

    def clear_faults(self) -> None:
        """End injected faults (a disconnect stays: the pty is gone)."""
        with self._lock:
            self._modes.clear()
            for ch in self.plant:
                ch.arcing = False
                ch.drift = ch.drift_rate = 0.0

    def _channels(self, channel: int | None) -> list[int]:
        if channel is None:
            return list(range(len(self.plant)))
        if not 0 <= channel < len(self.plant):
            raise ValueError(f"channel={channel}: between 0 and {len(self.plant) - 1}")
        return [channel]

    def _disconnect(self) -> None:
        if self._master is not None:
            os.close(self._master)
            self._master = None

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

    def _serve(self) -> None:
        while self._running:
            master = self._master
            waited_from = time.monotonic()
            readable = []
            if master is not None:
                try:
                    readable, _, _ = select.select([master], [], [], self._tick)
                except (OSError, ValueError):
                    readable = []
            else:
                time.sleep(self._tick)
            data = b""
            if readable:
                try:
                    data = os.read(master, 4096)
                except OSError:
                    data = b""
            with self._lock:
                now = time.monotonic()
                self._step(now)
                if data:
                    self._receive(data)
                # A simulator descheduled on a loaded host must not read its own delay as a silent host
                # (a device sees bytes as they arrive): bytes that waited in the pty were received above,
                # and an empty wait proves silence only up to when it began.
                self._check_watchdog(waited_from, now)

    def _receive(self, data: bytes) -> None:
        for byte in data:
            self._line.append(byte)
            if self._line.endswith(b"\r\n"):
                line = self._line[:-2].decode("ascii", errors="replace")
                self._line.clear()
                self._last_command = time.monotonic()
                self.command_log.append((self._last_command, line))
                self._reply(line, self._execute(line))

    def _reply(self, line: str, answer: str) -> None:
        if "no_reply" in self._modes or self._master is None:
            return
        out = f"{line}\r\n{answer}\r\n".encode("ascii")  # echo of the command line, then the answer
        if "garbled" in self._modes:
            body = bytearray(out[:-2])
            for i in self._rng.choice(len(body), size=max(1, len(body) // 4), replace=False):
                body[i] = int(self._rng.integers(33, 127))
            out = bytes(body) + b"\r\n"
        elif "partial" in self._modes:
            out = out[: len(out) // 2]
        try:
            os.write(self._master, out)
        except OSError:
            pass

    # --- the EDCP command set ------------------------------------------------------------------
    def _execute(self, line: str) -> str:
        answers = []
        try:
            for unit in line.split(";"):
                answer = self._execute_unit(unit.strip())
                if answer is not None:
                    answers.append(answer)
        except CommandError:
            return ERROR_REPLY
        return ";".join(answers)

    def _execute_unit(self, unit: str) -> str | None:
        match = _UNIT.match(unit.upper())
        if not match:
            raise CommandError(f"malformed: {unit!r}")
        header, args = match["header"], (match["args"] or "").strip()
        now = time.monotonic()
        if header == "*IDN?":
            return IDENTITY
        if header == ":READ:MOD:CHAN?":
            return str(len(self.plant))
        if header == "*OPC?":
            return "1"
        if header == "*RST":
            for ch in self.plant:
                ch.switch_off(now, emergency=False)
                ch.power_on_reset()
            return None
        if header == "*CLS":
            for ch in self.plant:
                ch.events = ChannelEvent(0)
            return None
        if header.endswith("?"):
            getter = _QUERIES.get(header)
            if getter is None:
                raise CommandError(f"unknown query {header}")
            return ",".join(getter(self.plant[i]) for i in self._channel_list(args))
        match = _SETTING_ARGS.fullmatch(args)
        if not match:
            raise CommandError(f"setting without value and channel list: {unit!r}")
        for i in self._channel_list(match["channels"]):
            self._set(header, match["value"].strip(), self.plant[i], now)
        return None

    def _channel_list(self, text: str) -> list[int]:
        match = _CHANNELS.fullmatch(text.strip())
        if not match:
            raise CommandError(f"bad channel list {text!r}")
        indices = []
        for part in match["list"].split(","):
            first, _, last = part.partition("-")
            indices += range(int(first), int(last or first) + 1)
        if not indices or any(i >= len(self.plant) for i in indices):
            raise CommandError(f"channel out of range in {text!r}")
        return indices

    @staticmethod
    def _set(header: str, value: str, ch: PlantChannel, now: float) -> None:
        if header == ":VOLT":
            if value == "ON":
                ch.switch_on()
            elif value in ("OFF", "EMCY OFF"):
                ch.switch_off(now, emergency=value == "EMCY OFF")
            elif value == "EMCY CLR":
                ch.emergency = False
            else:
                volts = _number(value)
                if not 0 <= volts <= ch.defaults.voltage_limit:
                    raise CommandError(f"voltage {volts} outside 0..{ch.defaults.voltage_limit}")
                ch.voltage_set = volts
        elif header == ":CURR":
            ch.current_limit = _number(value)
        elif header == ":CONF:RAMP:VOLT:UP":
            ch.ramp_up = min(_number(value), ch.defaults.max_ramp_speed)
        elif header == ":CONF:RAMP:VOLT:DOWN":
            ch.ramp_down = min(_number(value), ch.defaults.max_ramp_speed)
        elif header == ":CONF:TRIP:TIME":
            ch.trip_time_ms = _number(value)
        elif header == ":CONF:TRIP:ACTION":
            ch.trip_action = int(_number(value))
        elif header == ":EVENT" and value == "CLEAR":
            ch.events = ChannelEvent(0)
            ch.current_trip = False
        else:
            raise CommandError(f"unknown setting {header} {value}")

    def status_text(self) -> str:
        with self._lock:
            return "; ".join(f"ch{i}: {'ON' if ch.output_on else 'off'} {ch.voltage:.1f} V set {ch.voltage_set:.1f} V "
                             f"{ch.measured_current * 1e6:.2f} uA status {int(ch.status)}" for i, ch in enumerate(self.plant))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--channels", type=int, default=2)
    parser.add_argument("--voltage-limit", type=float, default=ChannelDefaults.voltage_limit, help="[V]")
    parser.add_argument("--watchdog", type=float, default=0.0, help="host keep-alive [s]; 0 (default) = none")
    args = parser.parse_args(argv)
    sim = SimulatedSupply(args.channels, ChannelDefaults(voltage_limit=args.voltage_limit),
                          watchdog_s=args.watchdog or None).start()
    print(sim.port, flush=True)
    try:
        for line in sys.stdin:
            words = line.split()
            if not words:
                continue
            try:
                if words[0] == "quit":
                    break
                reply = "ok"
                if words[0] == "clear":
                    sim.clear_faults()
                elif words[0] == "status":
                    reply = sim.status_text()
                else:
                    sim.inject(words[0], int(words[1]) if len(words) > 1 else None)
                print(reply, flush=True)
            except ValueError as error:
                print(f"error: {error}", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        sim.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
