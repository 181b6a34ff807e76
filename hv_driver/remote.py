"""The client side of the HV supervisor process: `RemoteSupply` has `HvSupply`'s API and forwards every call over
the local channel (`hv_driver.ipc`) to the process that owns the supplies (`hv_driver.server`), beating a
keep-alive meanwhile.

Supervisor lost: when that process ends or its channel breaks, every later call raises `SupervisorLostError`
(an `HvError`: a node refuses every client with it), and `snapshot()` reports the last known state with
SUPERVISOR_LOST latched on every channel. What then still holds is the supplies' own means only: their device-side
current trip, ramp and voltage limits, a device watchdog where the supply has one, and the hardware interlock.
"""
from __future__ import annotations

import dataclasses
import itertools
import json
import logging
import os
import socket
import subprocess
import threading
import time
from collections.abc import Callable

from . import ipc
from .driver import ChannelSnapshot, SupplySnapshot
from .errors import HvError
from .events import SupervisorEvent
from .faults import Fault, fault_names
from .ipc import KEEPALIVE_PERIOD_S, MAX_WAIT_S, spec_digest

log = logging.getLogger(__name__)

START_TIMEOUT_S = 30.0   # for the process to open the supplies and listen (interpreter start-up on a loaded host)
CALL_TIMEOUT_S = 10.0    # for the answer to a request that does not wait by itself
HELLO_TIMEOUT_S = 5.0


def supervisor_lost_text(reason: str) -> str:
    return (f"HV supervisor process lost ({reason}): only the supplies' own means still hold (device current trip "
            f"and limits, a device watchdog where the supply has one, the interlock)")


class SupervisorLostError(HvError, ConnectionError):
    """The supervisor process ended or its channel broke (``reason``); the message names the fault, as hv/state
    shows it, and says what still holds."""

    def __init__(self, reason: str):
        super().__init__(f"{fault_names(Fault.SUPERVISOR_LOST)}: {supervisor_lost_text(reason)}")


class RemoteRampHandle:
    """`RampHandle` of the supervisor process: ``wait``, ``done``, ``message``, ``succeeded``, ``cancel``."""

    def __init__(self, supply: RemoteSupply, reference: dict):
        self._supply, self._id = supply, reference["handle"]
        self.channel, self.target = reference["channel"], reference["target"]

    def _get(self, attribute: str, *args, timeout: float = CALL_TIMEOUT_S):
        return self._supply._request("handle", [self._id, attribute, *args], timeout=timeout)

    done = property(lambda self: self._get("done"))
    message = property(lambda self: self._get("message"))
    succeeded = property(lambda self: self._get("succeeded"))

    def wait(self, timeout: float | None = None) -> bool:
        return self._supply._wait(lambda step: self._get("wait", step, timeout=step + CALL_TIMEOUT_S), timeout)

    def cancel(self) -> RemoteRampHandle | None:
        reference = self._get("cancel")
        return None if reference is None else RemoteRampHandle(self._supply, reference)


class RemotePulseHandle(RemoteRampHandle):
    """`PulseHandle` of the supervisor process; adds ``cycles_done``, ``frequency``, ``short_pulses``,
    ``generated_by``."""

    def __init__(self, supply: RemoteSupply, reference: dict):
        self._supply, self._id = supply, reference["handle"]
        self.channels, self.generated_by = reference["channels"], reference["generated_by"]

    cycles_done = property(lambda self: self._get("cycles_done"))
    frequency = property(lambda self: self._get("frequency"))
    short_pulses = property(lambda self: self._get("short_pulses"))

    def cancel(self) -> None:
        self._get("cancel")


def _snapshot_from(fields: dict) -> SupplySnapshot:
    channels = tuple(ChannelSnapshot(**{**c, "faults": Fault(c["faults"])}) for c in fields["channels"])
    return SupplySnapshot(**{**fields, "channels": channels})


def _with_supervisor_lost(snapshot: SupplySnapshot, reason: str) -> SupplySnapshot:
    text = supervisor_lost_text(reason)
    channels = tuple(dataclasses.replace(
        c, faults=c.faults | Fault.SUPERVISOR_LOST,
        fault_text="; ".join(t for t in (c.fault_text, f"{fault_names(Fault.SUPERVISOR_LOST)}: {text}") if t))
        for c in snapshot.channels)
    return dataclasses.replace(snapshot, channels=channels, link_error=text)


class RemoteSupply:
    """`HvSupply`'s API, served by a supervisor process started from ``command`` (e.g. ``[python, -m,
    hv_driver.server]``) with ``spec`` (see `hv_driver.server.supply_from_spec`) on its standard input, listening at
    ``socket_path``. A supervisor already listening there with the same spec (one whose node died) is taken over
    instead, latched faults and all; one with another spec is refused.

    on_lost: called once, with the reason, when the supervisor process is lost.
    """

    FORWARDED = ("enable", "disable", "claim_control", "release_control", "heartbeat", "set_safe_voltage", "estop",
                 "reset_faults", "reset_device", "inject_fault", "clear_faults")

    def __init__(self, command: list[str], spec: dict, socket_path: str,
                 on_lost: Callable[[str], None] | None = None):
        self.command, self.spec, self.socket_path = list(command), dict(spec), socket_path
        self.port_name = ", ".join(spec.get("ports", []))
        self.device_id = ""
        self.pid: int | None = None
        self._on_lost = on_lost
        self._process: subprocess.Popen | None = None
        self._sock: socket.socket | None = None
        self._ids = itertools.count(1)
        self._pending: dict[int, list] = {}   # id -> [event, reply]
        self._forwarded: dict[int, Callable[[Exception], None]] = {}  # id -> what to call if it is refused
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._lost: str | None = None
        self._closing = False
        self._last_snapshot: SupplySnapshot | None = None
        self._stop = threading.Event()
        self._beater: threading.Thread | None = None
        for name in self.FORWARDED:
            setattr(self, name, self._forward(name))

    def _forward(self, method: str):
        def call(*args, **kwargs):
            return self._request(method, list(args), kwargs)
        call.__name__ = method
        return call

    # --- lifecycle -------------------------------------------------------------------------------
    def open(self) -> RemoteSupply:
        """Take over a supervisor with this spec at socket_path, or start one; then beat the keep-alive."""
        hello = self._connect_existing()
        if hello is None:
            hello = self._start()
        self.pid, self.device_id = hello["pid"], hello["device_id"]
        threading.Thread(target=self._receive, name="hv-supervisor-replies", daemon=True).start()
        self._beater = threading.Thread(target=self._beat, name="hv-supervisor-keepalive", daemon=True)
        self._beater.start()
        return self

    def _connect_existing(self) -> dict | None:
        if not os.path.exists(self.socket_path):
            return None
        try:
            sock = self._connect()
        except OSError:  # a supervisor that died left its socket file
            os.unlink(self.socket_path)
            return None
        hello = self._hello(sock)
        if hello["digest"] != spec_digest(self.spec):
            sock.close()
            raise HvError(f"a supervisor process with other settings (pid {hello['pid']}) serves {self.socket_path}; "
                          f"it switches its outputs off and exits {self.spec.get('orphan_timeout_s', 30):g} s after "
                          f"its node was lost, or stop it")
        log.warning("took over the HV supervisor process %d at %s (its node was lost)", hello["pid"], self.socket_path)
        self._sock = sock
        return hello

    def _start(self) -> dict:
        os.makedirs(os.path.dirname(self.socket_path) or ".", exist_ok=True)
        # Its own session: a terminal's signals (Ctrl-C, hang-up) reach the node, which closes the supply; a node
        # that dies leaves this process to ramp its outputs down.
        self._process = subprocess.Popen([*self.command, "--socket", self.socket_path], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, text=True, start_new_session=True)
        self._process.stdin.write(json.dumps(self.spec))
        self._process.stdin.close()
        line = self._read_announcement()
        if not line.startswith("ready"):
            self._process.wait(timeout=10.0)
            raise HvError(line.removeprefix("error: ") if line else
                          f"the HV supervisor process ended (status {self._process.returncode}) without a word")
        self._sock = self._connect()
        return self._hello(self._sock)

    def _read_announcement(self) -> str:
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.append(self._process.stdout.readline()), daemon=True)
        reader.start()
        reader.join(START_TIMEOUT_S)
        if not lines:
            self._process.kill()
            self._process.wait()
            raise HvError(f"the HV supervisor process did not start within {START_TIMEOUT_S:g} s")
        return lines[0].strip()

    def _connect(self) -> socket.socket:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            sock.connect(self.socket_path)
        except OSError:
            sock.close()
            raise
        return sock

    @staticmethod
    def _hello(sock: socket.socket) -> dict:
        sock.settimeout(HELLO_TIMEOUT_S)
        try:
            ipc.send(sock, {"id": 0, "method": "hello"})
            reply = ipc.receive(sock)
        except (TimeoutError, ipc.ChannelClosed) as error:
            sock.close()
            raise HvError(f"the HV supervisor process does not answer ({error}); another node may hold it") from None
        sock.settimeout(None)
        if "error" in reply:
            ipc.raise_remote_error(reply["error"])
        return reply["result"]

    def close(self, ramp_down_timeout: float = 5.0) -> None:
        """Ramp every output to 0 V, switch it off, and end the supervisor process."""
        self._end("close", [ramp_down_timeout])

    def abort(self) -> None:
        """Every output off at once, and end the supervisor process."""
        self._end("abort", [])

    def __enter__(self) -> RemoteSupply:
        return self.open()

    def __exit__(self, exc_type, exc, tb):
        self.abort() if exc_type is not None else self.close()
        return False

    def _end(self, method: str, args: list) -> None:
        if self._sock is None:
            return
        self._closing = True
        self._stop.set()  # no keep-alive after the last request
        if self._beater is not None:
            self._beater.join()
        try:
            if self._lost is None:
                self._request(method, args, timeout=MAX_WAIT_S)
        except HvError as error:
            log.error("%s of the HV supervisor process: %s", method, error)
        finally:
            self._sock.close()
            self._sock = None
            if self._process is not None:
                try:
                    self._process.wait(timeout=10.0)
                except subprocess.TimeoutExpired:
                    self._process.kill()
                    self._process.wait()

    # --- the channel -----------------------------------------------------------------------------
    def _beat(self) -> None:
        while not self._stop.wait(KEEPALIVE_PERIOD_S) and self._lost is None:
            try:
                self._send({"method": ipc.KEEPALIVE})
            except ipc.ChannelClosed:
                return  # the reader sees it too and reports it

    def _send(self, message: dict) -> None:
        """Send ``message`` stamped with its sending time (CLOCK_MONOTONIC, comparable with the supervisor's on one
        host; stamped under the lock, so the stamps rise in the channel's order)."""
        with self._send_lock:
            sock = self._sock
            if sock is None:
                raise ipc.ChannelClosed("closed")
            ipc.send(sock, {**message, ipc.SENT: time.monotonic()})

    def _receive(self) -> None:
        sock = self._sock
        while True:
            try:
                reply = ipc.receive(sock)
            except (ipc.ChannelClosed, ValueError, OSError) as error:
                self._lose(str(error))
                return
            with self._lock:
                waiter = self._pending.pop(reply.get("id"), None)
                refused = self._forwarded.pop(reply.get("id"), None)
            if refused is not None and "error" in reply:
                refused(ipc.remote_error(reply["error"]))
            if waiter is not None:
                waiter[1] = reply
                waiter[0].set()

    def _lose(self, reason: str) -> None:
        with self._lock:
            if self._lost is not None:
                return
            status = self._process.poll() if self._process is not None else None
            self._lost = reason if status is None else f"exited with status {status}"
            waiters, self._pending, self._forwarded = list(self._pending.values()), {}, {}
        for waiter in waiters:
            waiter[0].set()
        if not self._closing:
            log.critical(supervisor_lost_text(self._lost))
            if self._on_lost is not None:
                self._on_lost(self._lost)

    @property
    def lost(self) -> str | None:
        """Why the supervisor process was lost; None while it serves."""
        return self._lost

    def _request(self, method: str, args: list, kwargs: dict | None = None, timeout: float = CALL_TIMEOUT_S):
        if self._lost is not None:
            raise SupervisorLostError(self._lost)
        request_id = next(self._ids)
        waiter = [threading.Event(), None]
        with self._lock:
            self._pending[request_id] = waiter
        try:
            self._send({"id": request_id, "method": method, "args": args, "kwargs": kwargs or {}})
        except ipc.ChannelClosed as error:
            self._lose(str(error))
        if not waiter[0].wait(timeout):
            with self._lock:
                self._pending.pop(request_id, None)
            raise SupervisorLostError(f"no answer to {method!r} within {timeout:g} s")
        if waiter[1] is None:
            raise SupervisorLostError(self._lost or "channel closed")
        if "error" in waiter[1]:
            ipc.raise_remote_error(waiter[1]["error"])
        return waiter[1]["result"]

    def forward_heartbeat(self, token: str, on_refused: Callable[[Exception], None]) -> None:
        """Send a heartbeat without waiting for its answer: the node forwards its client's beats the moment they
        arrive, stamped then, also while the supervisor stalls (a stalled supervisor holds none of the node's
        threads). ``on_refused(error)`` is called from the reply thread if the supervisor refuses it (ControlError:
        another client's, a copied one); SupervisorLostError at once once the supervisor is lost."""
        if self._lost is not None:
            raise SupervisorLostError(self._lost)
        request_id = next(self._ids)
        with self._lock:
            self._forwarded[request_id] = on_refused
        try:
            self._send({"id": request_id, "method": "heartbeat", "args": [token], "kwargs": {}})
        except ipc.ChannelClosed as error:
            with self._lock:
                self._forwarded.pop(request_id, None)
            self._lose(str(error))
            raise SupervisorLostError(self._lost or str(error)) from None

    def _wait(self, ask: Callable[[float], bool], timeout: float | None) -> bool:
        """A wait of any length as waits of at most MAX_WAIT_S each."""
        remaining = timeout
        while True:
            step = MAX_WAIT_S if remaining is None else min(MAX_WAIT_S, max(0.0, remaining))
            if ask(step):
                return True
            if remaining is not None:
                remaining -= step
                if remaining <= 0:
                    return False

    # --- HvSupply's API --------------------------------------------------------------------------
    def ramp_to(self, channel: str, target_v: float, slew_rate_v_per_s: float | None = None, **kwargs):
        return RemoteRampHandle(self, self._request("ramp_to", [channel, target_v, slew_rate_v_per_s], kwargs))

    def pulse(self, channels, *args, **kwargs):
        return RemotePulseHandle(self, self._request("pulse", [list(channels), *args], kwargs))

    def snapshot(self) -> SupplySnapshot:
        """The supervisor's state; after its loss the last one known, SUPERVISOR_LOST latched on every channel."""
        if self._lost is None:
            try:
                self._last_snapshot = _snapshot_from(self._request("snapshot", []))
                return self._last_snapshot
            except SupervisorLostError:
                pass
        if self._last_snapshot is None:
            raise SupervisorLostError(self._lost or "never answered")
        return _with_supervisor_lost(self._last_snapshot, self._lost or "no answer")

    def drain_events(self) -> list[SupervisorEvent]:
        """The supervisor's events since the last drain; none once it is lost (``on_lost`` reports that)."""
        try:
            return [SupervisorEvent(*fields) for fields in self._request("drain_events", [])]
        except SupervisorLostError:
            return []

    def wait_outputs_off(self, timeout: float | None = None) -> bool:
        return self._wait(lambda step: self._request("wait_outputs_off", [], {"timeout": step},
                                                     timeout=step + CALL_TIMEOUT_S), timeout)

    def wait_cycles(self, count: int = 1, timeout: float | None = None) -> bool:
        return self._request("wait_cycles", [count], {"timeout": timeout},
                             timeout=(MAX_WAIT_S if timeout is None else timeout) + CALL_TIMEOUT_S)
