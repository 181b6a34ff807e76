"""Which supply answers on a serial port, found without changing anything on it.

`probe(port)` opens the port once and, dialect by dialect, at that dialect's baud rate and framing, sends its
identification query (iseg EDCP ``*IDN?`` answered after its echo, Keithley 2290 ``*IDN?``, PPV ``QVer``) until a
supply answers as that dialect would. Nothing else is sent: before each query a bare line terminator (it ends a
line another dialect's query may have left unfinished in the device), and the probe refuses to send any operation
of the command table but a text query, so no setpoint, output, mode or limit is ever touched.

What it cannot rule out (docs/hardware_quickstart.md): opening a USB serial port raises DTR, which resets an
Arduino-based board such as the PPV into its saved power-on state; bytes sent at another dialect's baud rate reach
the device as garbage (a supply answers garbage with an error, or not at all).
"""
from __future__ import annotations

from dataclasses import dataclass

import serial

from .dialects import DIALECTS, Dialect, ProtocolError
from .link import Link, LinkError

OPERATION = "identify"
DEFAULT_REPLY_TIMEOUT = 1.0  # [s] a 9600-baud supply answers in tens of ms; a board just reset by DTR takes longer


@dataclass(frozen=True)
class Attempt:
    """One dialect's query: what was sent at which rate, the answer read (None: none) and why it is not that
    dialect (None: it is)."""

    dialect: str
    baudrate: int
    query: str
    identity: str | None
    problem: str | None


@dataclass(frozen=True)
class ProbeResult:
    port: str
    attempts: tuple[Attempt, ...]

    @property
    def found(self) -> Attempt | None:
        """The attempt that identified the supply (None: no dialect answered)."""
        return next((attempt for attempt in self.attempts if attempt.problem is None), None)


def identification_query(dialect: Dialect) -> str:
    """The dialect's identification line; ValueError unless it is a text query without a value (read-only)."""
    command = dialect.commands[OPERATION]
    if command.reply != "text" or "{" in command.template:
        raise ValueError(f"dialect {dialect.name}: {OPERATION!r} is {command.template!r} ({command.reply}), "
                         "not a text query; the probe sends nothing else")
    return command.template


def probe(port: str, baudrate: int | None = None, reply_timeout: float = DEFAULT_REPLY_TIMEOUT,
          dialects: tuple[str, ...] = tuple(DIALECTS)) -> ProbeResult:
    """Ask each of ``dialects`` in turn (at ``baudrate``, or each dialect's default) who is on ``port`` (a device
    path or pyserial URL); stops at the first that answers as its dialect. LinkError if the port cannot be opened."""
    instances = [DIALECTS[name]() for name in dialects]
    queries = [identification_query(dialect) for dialect in instances]  # refused before the port is opened
    try:
        link_port = serial.serial_for_url(port, baudrate=baudrate or instances[0].default_baudrate,
                                          timeout=reply_timeout, write_timeout=reply_timeout)
    except (serial.SerialException, OSError, ValueError) as error:
        raise LinkError(f"cannot open {port!r}: {error}") from error
    attempts = []
    try:
        for dialect, query in zip(instances, queries):
            attempts.append(_ask(link_port, dialect, query, baudrate or dialect.default_baudrate, reply_timeout))
            if attempts[-1].problem is None:
                break
    finally:
        link_port.close()
    return ProbeResult(port, tuple(attempts))


def _ask(port, dialect: Dialect, query: str, baudrate: int, reply_timeout: float) -> Attempt:
    link = Link(port, dialect, reply_timeout)
    identity = None
    try:
        port.baudrate = baudrate
        port.write(dialect.command_terminator)
        link.discard_input("before the identification query")
        identity = link.query(OPERATION)
    except (LinkError, ProtocolError) as error:
        return Attempt(dialect.name, baudrate, query, identity, str(error))
    if not dialect.echo and identity == query:
        problem = "the device echoed the query: it echoes, this dialect does not"
    else:
        problem = dialect.identity_problem(identity)
    return Attempt(dialect.name, baudrate, query, identity, problem)


def report(result: ProbeResult) -> str:
    """The probe's findings as lines of text, ending with the node parameters for the supply found."""
    lines = [f"probing {result.port}: identification queries only, nothing is set"]
    for attempt in result.attempts:
        outcome = f"answered {attempt.identity!r}" if attempt.problem is None else f"no: {attempt.problem}"
        lines.append(f"  {attempt.dialect:<14} {attempt.baudrate:>6} baud  {attempt.query:<6} {outcome}")
    found = result.found
    if found is None:
        lines.append("no supply answered as any dialect: check the cable, the port, the supply's power and its baud "
                     "rate (--baudrate)")
    else:
        lines.append(f"found: {found.dialect} at {found.baudrate} baud, identity {found.identity!r}")
        lines.append(f"node parameters: backend: serial, dialect: {found.dialect}, ports: [{result.port}], "
                     f"baudrate: {found.baudrate}")
    return "\n".join(lines)
