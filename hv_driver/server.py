"""The HV supervisor process: owns the supplies' ports, the safety supervisor and the control loop (an `HvSupply`),
and serves one client, the ROS node, over a local channel (`hv_driver.ipc`). No ROS in this process, so neither a
dead node nor the node's interpreter under load can hold the loop.

Node lost: when the client's end closes (its process died: SIGKILL, OOM, abort) or its keep-alive stops for longer
than ``keepalive_timeout_s``, the client's control session ends and every channel latches NODE_LOST; energised
outputs ramp to 0 V at their slew limit. Nothing is energised again until a node connects, a client claims control
and the faults are reset. A supervisor without a node for ``orphan_timeout_s`` switches every output off, closes
the ports and exits.

Silence is judged only on a channel read to its end: keep-alives and heartbeats count from their sending stamps, the
keep-alive's lapse is declared only when nothing waits unread, and the loop has the channel read before it judges the
controlling client's heartbeat (`HvSupply.listen`). So a stall of this process, while the node's messages wait in the
channel, is neither the node's silence nor its client's, and a dead node or client is not heard later for it.

    python -m hv_driver.server --socket PATH < spec.json    # prints "ready <pid>" or "error: <why>"
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import os
import select
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from . import ipc
from .ipc import MAX_WAIT_S, NODE_KEEPALIVE_TIMEOUT_S, spec_digest
from .config import ChannelConfig
from .dialects import dialect
from .driver import HvSupply, PulseHandle, RampHandle
from .errors import HvError
from .realtime import DEFAULT_PRIORITY, make_realtime

log = logging.getLogger("hv_supervisor")

ORPHAN_TIMEOUT_S = 30.0
MAX_HANDLES = 1024
WORKERS = 16
THREAD_STACK_BYTES = 512 * 1024  # memory may be locked: keep each thread's stack small

# The supply's methods a client may call, and the attributes of a ramp or pulse handle it may read or call.
SUPPLY_METHODS = frozenset({"enable", "disable", "ramp_to", "pulse", "claim_control", "release_control",
                            "heartbeat", "set_safe_voltage", "estop", "reset_faults", "reset_device", "snapshot",
                            "wait_outputs_off", "wait_cycles", "drain_events"})
HANDLE_ATTRIBUTES = frozenset({"done", "message", "succeeded", "wait", "cancel", "cycles_done", "frequency",
                               "short_pulses"})
ENDING_METHODS = frozenset({"close", "abort"})
_NOTHING_WAITING, _CLOSED = object(), object()  # what reading the channel found instead of a message


def supply_from_spec(spec: dict, ports: list | None = None) -> HvSupply:
    """An `HvSupply` as ``spec`` describes it (the node's parameters, JSON): ports, baudrate, channels (each the
    fields of a `ChannelConfig`), dialect, loop_rate_hz, link_timeout_s, heartbeat_timeout_s, expected_identity.
    ``ports`` (device paths, URLs or port objects) replaces the spec's (a simulated rig's)."""
    channels = [ChannelConfig(**fields) for fields in spec["channels"]]
    return HvSupply(ports or spec["ports"], spec.get("baudrate"), channels, dialect=dialect(spec["dialect"]),
                    loop_rate_hz=spec["loop_rate_hz"], link_timeout_s=spec["link_timeout_s"],
                    heartbeat_timeout_s=spec["heartbeat_timeout_s"],
                    expected_identity=spec.get("expected_identity", ""), handle_signals=False)


def _plain(value):
    """A result as JSON: snapshots as their fields, handles by reference."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    return value


class SupervisorServer:
    """Serves ``supply`` (opened) to one client at a time on a listening SOCK_SEQPACKET socket at ``path``.

    extra_methods: further requests by name (e.g. a simulated rig's fault injection).
    """

    def __init__(self, supply: HvSupply, path: str, digest: str, *,
                 keepalive_timeout_s: float = NODE_KEEPALIVE_TIMEOUT_S, orphan_timeout_s: float = ORPHAN_TIMEOUT_S,
                 extra_methods: dict[str, Callable] | None = None):
        self.supply, self.path, self.digest = supply, path, digest
        self.keepalive_timeout_s, self.orphan_timeout_s = keepalive_timeout_s, orphan_timeout_s
        self._extra = dict(extra_methods or {})
        self._handles: dict[int, RampHandle | PulseHandle] = {}
        self._next_handle = 0
        self._send_lock = threading.Lock()
        self._ended = threading.Event()
        # Held from reading a message until it is taken in (a heartbeat applied, a request handed on); notified after.
        self._taken = threading.Condition()
        self._connection: socket.socket | None = None
        self._last_keepalive = 0.0
        self._taken_up_to = -math.inf  # the sending stamp of the last message taken in
        self._messages_taken = 0
        self._node_silent = False  # NODE_LOST latched for the silence of the connected node's keep-alive
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self._listener.bind(path)
        self._listener.listen(1)
        supply.listen(self._wait_taken_in)

    # --- serving ---------------------------------------------------------------------------------
    def serve(self) -> None:
        """Until a client closes the supply, or no client came for orphan_timeout_s after the last one was lost."""
        with ThreadPoolExecutor(WORKERS, thread_name_prefix="hv-request") as pool:
            try:
                while not self._ended.is_set():
                    self._listener.settimeout(self.orphan_timeout_s)
                    try:
                        connection, _ = self._listener.accept()
                    except TimeoutError:
                        log.warning("no node for %g s: every output off, ports closed, exiting",
                                    self.orphan_timeout_s)
                        self.supply.close()
                        break
                    with connection:
                        self._serve_connection(connection, pool)
            finally:
                self._listener.close()
                if os.path.exists(self.path):
                    os.unlink(self.path)

    def _serve_connection(self, connection: socket.socket, pool: ThreadPoolExecutor) -> None:
        """Until the node's end closes (node lost) or it closes the supply. Only the keep-alive counts as the node's
        sign of life (requests may come from a thread that outlived the rest); when it stops, NODE_LOST latches once,
        and a node that resumes sees the faults latched and must reset them."""
        log.info("node connected")
        connection.setblocking(False)
        with self._taken:
            self._connection, self._last_keepalive, self._node_silent = connection, time.monotonic(), False
        try:
            while not self._ended.is_set():
                with self._taken:
                    message = self._take_in(connection, pool)
                    overdue = time.monotonic() - self._last_keepalive - self.keepalive_timeout_s
                    if message is _NOTHING_WAITING and overdue > 0 and not self._node_silent:
                        self._node_silent = True  # nothing unread: the keep-alive really stopped
                        self._node_lost(f"HV driver node lost: no keep-alive for more than "
                                        f"{self.keepalive_timeout_s:g} s")
                    silent = self._node_silent
                if message is _CLOSED:
                    if not self._ended.is_set():
                        self._node_lost("HV driver node lost: its channel to the supervisor closed (the node's "
                                        "process ended)")
                    return
                if message is _NOTHING_WAITING:
                    select.select([connection], [], [], None if silent else max(-overdue, 0.0))
                elif isinstance(message, dict):  # close or abort: the loop stops; answer from this thread, then end
                    self._send_reply(connection, self._answer(message))
                    self._ended.set()
                    _drain(connection)
                    return
        finally:
            with self._taken:
                self._connection = None
                self._taken.notify_all()

    def _take_in(self, connection: socket.socket, pool: ThreadPoolExecutor):
        """Read one message (``self._taken`` held) and take it in: a keep-alive or heartbeat at once, from its
        sending stamp; a request handed to ``pool``. Returns _NOTHING_WAITING, _CLOSED, a close or abort request (for
        the caller) or None."""
        try:
            message = ipc.receive(connection)
        except BlockingIOError:
            return _NOTHING_WAITING
        except ipc.ChannelClosed:
            return _CLOSED
        except ValueError as error:  # not ours: refuse the message, keep serving
            self._messages_taken += 1
            log.error("malformed request refused: %s", error)
            return None
        finally:
            self._taken.notify_all()
        self._messages_taken += 1
        try:
            sent = ipc.sent_at(message, time.monotonic())
        except ValueError as error:
            log.error("malformed message refused: %s", error)
            if "id" in message:
                pool.submit(self._send_reply, connection, ipc.error_reply(message["id"], error))
            return None
        self._taken_up_to = max(self._taken_up_to, sent)
        method = message.get("method")
        if method in ENDING_METHODS:
            return message
        if method == ipc.KEEPALIVE:
            self._last_keepalive, self._node_silent = sent, False
        elif method == "heartbeat":  # taken in here, before the loop may judge the client's silence
            pool.submit(self._send_reply, connection, self._answer(message))
        else:
            pool.submit(lambda: self._send_reply(connection, self._answer(message)))
        return None

    def _wait_taken_in(self, patience: float) -> None:
        """`HvSupply.listen`: return once what the node sent before now has been taken in (or nothing waits
        unread), or once the reading thread has taken in nothing for ``patience`` [s]: a reader that is stuck must
        not hold the loop."""
        now = time.monotonic()
        with self._taken:
            while (self._connection is not None and self._taken_up_to < now
                   and select.select([self._connection], [], [], 0)[0]):
                before = self._messages_taken
                self._taken.wait(patience)
                if self._messages_taken == before:
                    return

    def _node_lost(self, reason: str) -> None:
        log.error("%s: every energised output ramps to 0 V (NODE_LOST)", reason)
        self.supply.node_lost(reason)

    def _answer(self, message: dict) -> dict:
        """The reply to a request: its result, or the error it raised."""
        request_id = message.get("id")
        try:
            return {"id": request_id, "result": self._call(message)}
        except (HvError, ValueError, TypeError, KeyError) as error:
            return ipc.error_reply(request_id, error if isinstance(error, (HvError, ValueError)) else
                                   ValueError(f"malformed request {message.get('method')!r}: {error}"))
        except Exception as error:  # a defect here must not end the loop's process: report it
            log.exception("request %r failed", message.get("method"))
            return ipc.error_reply(request_id, HvError(f"supervisor error: {error!r}"))

    def _send_reply(self, connection: socket.socket, reply: dict) -> None:
        with self._send_lock:
            try:
                ipc.send(connection, reply)
            except (ipc.ChannelClosed, ValueError) as error:
                log.warning("reply to request %r not sent: %s", reply.get("id"), error)

    # --- requests --------------------------------------------------------------------------------
    def _call(self, message: dict):
        method, args, kwargs = message.get("method"), message.get("args", []), message.get("kwargs", {})
        if not (isinstance(args, list) and isinstance(kwargs, dict)):
            raise ValueError("args must be a list and kwargs an object")
        if method == "hello":
            return {"pid": os.getpid(), "digest": self.digest, "device_id": self.supply.device_id}
        if method == "close":
            return self.supply.close(*args, **kwargs)
        if method == "abort":
            return self.supply.abort()
        if method == "handle":
            return self._handle(*args)
        if method in self._extra:
            return self._extra[method](*args, **kwargs)
        if method not in SUPPLY_METHODS:
            raise ValueError(f"method={method!r}: unknown")
        if method in ("wait_outputs_off", "wait_cycles"):
            kwargs["timeout"] = self._bounded_wait(kwargs.get("timeout"))
        if method == "heartbeat":
            kwargs["sent"] = ipc.sent_at(message, time.monotonic())
        result = getattr(self.supply, method)(*args, **kwargs)
        if isinstance(result, RampHandle):
            return {"handle": self._keep(result), "channel": result.channel, "target": result.target}
        if isinstance(result, PulseHandle):
            return {"handle": self._keep(result), "channels": list(result.trains), "generated_by": result.generated_by}
        return _plain(result)

    @staticmethod
    def _bounded_wait(timeout) -> float:
        if timeout is None:
            return MAX_WAIT_S
        if not (isinstance(timeout, (int, float)) and not math.isnan(timeout)):
            raise ValueError(f"timeout={timeout!r}: a number of seconds")
        return min(max(0.0, float(timeout)), MAX_WAIT_S)

    def _keep(self, handle) -> int:
        self._next_handle += 1
        self._handles[self._next_handle] = handle
        while len(self._handles) > MAX_HANDLES:
            del self._handles[next(iter(self._handles))]
        return self._next_handle

    def _handle(self, handle_id, attribute, *args):
        handle = self._handles.get(handle_id)
        if handle is None or attribute not in HANDLE_ATTRIBUTES or not hasattr(handle, attribute):
            raise ValueError(f"handle {handle_id!r}.{attribute!s}: unknown")
        if attribute == "wait":
            return handle.wait(self._bounded_wait(args[0] if args else None))
        if attribute == "cancel":
            down = handle.cancel()
            return {"handle": self._keep(down), "channel": down.channel, "target": down.target} if down else None
        return getattr(handle, attribute)


def _drain(connection: socket.socket) -> None:
    """Read what the client sent after its last request: a socket closed with unread messages resets the peer's
    end, which could lose the reply just sent."""
    connection.setblocking(False)
    try:
        while connection.recv(ipc.MAX_MESSAGE_BYTES + 1):
            pass
    except OSError:
        pass


# --- process ---------------------------------------------------------------------------------------
def announce(line: str) -> None:
    """A line for the node that started this process (its standard output)."""
    print(line, flush=True)


def serve_spec(spec: dict, path: str, ports: list | None = None,
               extra_methods: dict[str, Callable] | None = None, announce: Callable[[str], None] = announce) -> int:
    """Real-time scheduling where permitted, the supply opened from ``spec``, then serving at ``path``; announces
    "ready <pid>" or "error: <why>" (on stdout for the node that started this process). Exit status."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a terminal's Ctrl-C reaches the node, which closes the supply
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    threading.stack_size(THREAD_STACK_BYTES)
    make_realtime(int(spec.get("realtime_priority", DEFAULT_PRIORITY)))
    try:
        supply = supply_from_spec(spec, ports).open()
    except KeyError as error:
        announce(f"error: spec: {error} missing")
        return 1
    except (HvError, ValueError, TypeError) as error:
        announce(f"error: {error}")
        return 1
    signal.signal(signal.SIGTERM, lambda *_: supply.abort() or sys.exit(128 + signal.SIGTERM))
    try:
        server = SupervisorServer(supply, path, spec_digest(spec),
                                  keepalive_timeout_s=spec.get("keepalive_timeout_s", NODE_KEEPALIVE_TIMEOUT_S),
                                  orphan_timeout_s=spec.get("orphan_timeout_s", ORPHAN_TIMEOUT_S),
                                  extra_methods=extra_methods)
    except OSError as error:
        supply.abort()
        announce(f"error: cannot listen at {path}: {error}")
        return 1
    announce(f"ready {os.getpid()}")
    try:
        server.serve()
    finally:
        supply.abort()  # outputs already off after close; after a crash here: off at once
    return 0


def read_spec(stream, limit: int = ipc.MAX_MESSAGE_BYTES) -> dict:
    text = stream.read(limit + 1)
    if len(text) > limit:
        raise ValueError(f"spec over {limit} bytes")
    spec = json.loads(text)
    if not isinstance(spec, dict):
        raise ValueError("spec must be a JSON object")
    return spec


def process_main(prog: str, description: str, argv=None, serve=None) -> int:
    """The supervisor process's command line: ``--socket PATH``, the spec as JSON on standard input, logs on
    standard error. ``serve(spec, path)`` serves it (default: `serve_spec` on the spec's own ports)."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("--socket", required=True, help="path of the Unix socket to serve the node on")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="[hv_supervisor] %(levelname)s %(message)s")
    try:
        spec = read_spec(sys.stdin)
    except ValueError as error:
        announce(f"error: spec: {error}")
        return 2
    return (serve or serve_spec)(spec, args.socket)


def main(argv=None) -> int:
    return process_main("python -m hv_driver.server", __doc__.split("\n\n")[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
