"""The local channel between the HV supervisor process and its one client (the ROS node): messages over a Unix
domain socket of kind SOCK_SEQPACKET (one send, one message; the kernel keeps the boundaries), each a JSON object
of bounded size.

Requests: ``{"id": n, "method": name, "args": [...], "kwargs": {...}, "sent": t}``, answered by ``{"id": n,
"result": value}`` or ``{"id": n, "error": {"type": class name, "message": text}}``; ``{"method": "keepalive",
"sent": t}`` is the client's sign of life and is not answered. ``sent`` is the client's CLOCK_MONOTONIC when it sent
the message (comparable with the supervisor's on one host): a keep-alive or heartbeat counts from then, however long
it waited in the channel. The errors the driver raises on purpose cross the channel as themselves
(`raise_remote_error`), so a caller of the remote supply catches the same classes as one of `HvSupply`.
"""
from __future__ import annotations

import hashlib
import json
import math
import socket

from .control import ControlError
from .device import ConfigurationError
from .dialects import ProtocolError
from .errors import HvError, SettingError, StateError
from .link import LinkError
from .pulse import PulseLimitError
from .supervisor import FaultLatchedError, LimitError

MAX_MESSAGE_BYTES = 256 * 1024  # a snapshot of a many-channel rig is a few kB; anything larger is not ours
KEEPALIVE = "keepalive"
SENT = "sent"
# The node's keep-alive thread beats every KEEPALIVE_PERIOD_S; NODE_KEEPALIVE_TIMEOUT_S of silence is ten beats
# missed, which a node process that runs at all does not miss (its death shows at once, as the closed channel).
KEEPALIVE_PERIOD_S = 0.1
NODE_KEEPALIVE_TIMEOUT_S = 1.0
MAX_WAIT_S = 60.0  # one blocking request waits at most this long; the client asks again for longer waits

# Every error class a request may raise on the supervisor's side, by name (ValueError: a malformed request).
REMOTE_ERRORS: dict[str, type[Exception]] = {cls.__name__: cls for cls in (
    HvError, SettingError, LimitError, StateError, FaultLatchedError, ControlError, ConfigurationError, LinkError,
    ProtocolError, PulseLimitError, ValueError)}


class ChannelClosed(ConnectionError):
    """The other end of the channel closed it (its process ended) or the channel broke."""


def spec_digest(spec: dict) -> str:
    """Identifies a supervisor's settings: a node takes over only a supervisor of its own settings."""
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


def socket_pair() -> tuple[socket.socket, socket.socket]:
    return socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)


def send(sock: socket.socket, message: dict) -> None:
    data = json.dumps(message, separators=(",", ":")).encode()
    if len(data) > MAX_MESSAGE_BYTES:
        raise ValueError(f"message of {len(data)} bytes: at most {MAX_MESSAGE_BYTES}")
    try:
        sock.sendall(data)
    except OSError as error:
        raise ChannelClosed(f"channel broken: {error}") from error


def receive(sock: socket.socket) -> dict:
    """The next message; ChannelClosed at the end of the channel, ValueError for one that is not a bounded JSON
    object. socket.timeout (TimeoutError) passes through when the socket has a timeout, BlockingIOError when it
    does not block and nothing waits."""
    try:
        data = sock.recv(MAX_MESSAGE_BYTES + 1)
    except (TimeoutError, BlockingIOError):
        raise
    except OSError as error:
        raise ChannelClosed(f"channel broken: {error}") from error
    if not data:
        raise ChannelClosed("the other end closed the channel")
    if len(data) > MAX_MESSAGE_BYTES:
        raise ValueError(f"message over {MAX_MESSAGE_BYTES} bytes")
    message = json.loads(data)
    if not isinstance(message, dict):
        raise ValueError(f"message is a JSON {type(message).__name__}, not an object")
    return message


def sent_at(message: dict, now: float) -> float:
    """When the client sent ``message`` (its ``sent`` stamp, at most ``now``; ``now`` without one); ValueError for a
    stamp that is not a finite number."""
    sent = message.get(SENT)
    if sent is None:
        return now
    if not (isinstance(sent, (int, float)) and math.isfinite(sent)):
        raise ValueError(f"sent={sent!r}: a finite time stamp [s]")
    return min(float(sent), now)


def error_reply(request_id, error: Exception) -> dict:
    name = type(error).__name__
    return {"id": request_id, "error": {"type": name if name in REMOTE_ERRORS else "HvError", "message": str(error)}}


def remote_error(error: dict) -> Exception:
    """The exception an error reply describes, of its own class where it is one of REMOTE_ERRORS."""
    return REMOTE_ERRORS.get(error.get("type"), HvError)(error.get("message", "unknown error"))


def raise_remote_error(error: dict) -> None:
    raise remote_error(error)
