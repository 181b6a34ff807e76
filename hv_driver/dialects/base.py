"""The Dialect interface: how the driver's operations become lines on the wire and back.

A dialect is a command table (operation name -> `Command`) plus number/channel formatting and
the decoding of the supply's status register. The driver only speaks in the operation names
listed in `OPERATIONS`; everything device-specific lives in the dialect module.
"""
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from ..errors import HvError

# Operations the driver uses; every dialect's table must define all of them.
OPERATIONS = (
    "identify", "read_channel_count", "reset", "set_voltage", "output_on", "output_off", "emergency_off",
    "emergency_clear", "clear_events", "measure_voltage", "measure_current", "read_status",
    "read_event_status", "read_voltage_limit", "set_ramp_up", "set_ramp_down", "read_ramp",
    "set_current_limit", "read_current_limit", "set_trip_time", "read_trip_time", "set_trip_action",
)


class ProtocolError(HvError, ConnectionError):
    """A reply that does not fit the dialect: garbage, wrong echo, wrong count or unit."""


@dataclass(frozen=True)
class Command:
    """One row of a command table.

    template: the line sent, with ``{value}`` and ``{channels}`` fields.
    reply: "ack" (a setting; the dialect makes the device acknowledge it), "text", "number"
        (one number per channel, with ``unit`` appended by the device) or "integer" (registers).
    unit: unit suffix the device appends to numbers ("V", "A", "V/s", "ms").
    integer: the value is a code sent as a plain integer, not a number in the dialect's format.
    """

    template: str
    reply: str
    unit: str = ""
    integer: bool = False


@dataclass(frozen=True)
class StatusReport:
    """The parts of a channel status register the supervisor needs."""

    output_on: bool
    ramping: bool
    over_current: bool
    fault: str | None  # device-side fault (interlock, emergency off, limit), None if none


class Dialect(ABC):
    """Wire dialect of one family of supplies."""

    name: str
    terminator: bytes
    echo: bool               # the device echoes every character of the command line
    default_baudrate: int
    commands: Mapping[str, Command]

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        missing = [op for op in OPERATIONS if op not in cls.commands]
        if missing:
            raise TypeError(f"dialect {cls.__name__} lacks operations {missing}")

    def encode(self, operation: str, channels: Sequence[int] = (), value: float | None = None) -> str:
        """Command line (without terminator) for ``operation``."""
        command = self.commands[operation]
        fields = {"channels": self.format_channels(channels)}
        if "{value}" in command.template:
            if value is None:
                raise ValueError(f"operation {operation!r} needs a value")
            fields["value"] = str(int(value)) if command.integer else self.format_number(value)
        line = command.template.format(**fields)
        return self.acknowledged(line) if command.reply == "ack" else line

    def decode(self, operation: str, reply: str, count: int = 1):
        """Parse the reply line of ``operation``: str, list[float], list[int] or None (ack)."""
        command = self.commands[operation]
        if command.reply == "ack":
            if reply != self.ack_reply:
                raise ProtocolError(f"{operation}: expected acknowledgement {self.ack_reply!r}, got {reply!r}")
            return None
        if command.reply == "text":
            if not reply or not reply.isprintable():
                raise ProtocolError(f"{operation}: unreadable text reply {reply!r}")
            return reply
        fields = reply.split(",")
        if len(fields) != count:
            raise ProtocolError(f"{operation}: expected {count} value(s), got {reply!r}")
        return [self.parse_number(field, command, operation) for field in fields]

    @property
    @abstractmethod
    def ack_reply(self) -> str:
        """Reply line that acknowledges a setting."""

    @abstractmethod
    def acknowledged(self, line: str) -> str:
        """A setting line extended so the device answers `ack_reply` once it has executed it."""

    @abstractmethod
    def format_number(self, value: float) -> str: ...

    @abstractmethod
    def format_channels(self, channels: Sequence[int]) -> str: ...

    @abstractmethod
    def parse_number(self, field: str, command: Command, operation: str) -> float | int: ...

    @abstractmethod
    def status_report(self, status: int, events: int) -> StatusReport:
        """Decode a channel's status register and its latched event register."""
