"""The Dialect interface: what a supply can do (its `Capabilities`) and how the driver's operations become
lines on the wire and back.

A dialect is a capability declaration, a command table (operation name -> `Command`), the framing (echo,
terminators, acknowledgement) and the decoding of the supply's status. The driver speaks only in the operation
names below and chooses what to send from the capabilities; everything device-specific lives in the dialect
module. The table must hold every operation the declared capabilities need (checked when the class is defined).
"""
import re
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum

from ..errors import HvError

# Operations every supply has.
BASE_OPERATIONS = ("identify", "set_voltage", "output_on", "output_off", "measure_voltage", "read_voltage_limit")
# Operations a table may hold; the driver uses them when present: set_voltage_limit (a device-side voltage limit
# set to the channel's hard maximum), reset (device defaults), clear_events (clears latched device trips/events).
OPTIONAL_OPERATIONS = ("set_voltage_limit", "reset", "clear_events")


# A decimal number as the supplies write it (a dialect may narrow it with `Dialect.number_pattern`).
DECIMAL_NUMBER = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?")


class ProtocolError(HvError, ConnectionError):
    """A reply that does not fit the dialect: garbage, wrong echo, wrong count or unit."""


class CurrentSensing(Enum):
    """What a supply knows about its output current."""

    DEVICE_TRIP = "device_trip"  # current readback, and a device-side trip/limit the driver sets as well
    HOST_CHECK = "host_check"    # current readback only: the host's trip is the only one
    NONE = "none"                # no current readback: a breakdown shows only as the voltage collapsing


@dataclass(frozen=True)
class DeviceSwitching:
    """The supply switches its output between 0 V and the set voltage by itself (square edges of its own)."""

    min_frequency_hz: float
    max_frequency_hz: float
    duty: float        # on-fraction of its square wave (fixed)
    max_cycles: int    # it counts cycles and switches the output off after that many


@dataclass(frozen=True)
class Capabilities:
    """What one supply (one port) can do; the driver and supervisor choose from these declarations.

    channels_per_device: outputs behind one port; None: the device reports its count (``read_channel_count``).
    device_ramp: the device ramps its output at a rate the driver sets (``set_ramp_up``/``set_ramp_down``/
        ``read_ramp``), also when switched off; False: the output follows each setpoint at once and the host ramps.
    current: see `CurrentSensing`; DEVICE_TRIP needs ``measure_current`` and `Dialect.device_trip_settings`,
        HOST_CHECK ``measure_current``.
    device_current_margin: the device-side trip/limit as a multiple of the host's trip level (DEVICE_TRIP only).
    emergency_off: a latched device emergency off (``emergency_off``/``emergency_clear``); False: the driver cuts an
        output by switching it off and setting 0 V.
    device_watchdog_s: the device switches its outputs off by itself after this long without traffic (None: never:
        a dead host or a pulled cable leaves the output as it was).
    switching: device-side switching (``set_frequency``, ``set_cycles``, ``start_switching``, ``read_cycles``), None
        without; a train is armed with the output off (``output_off`` must give 0 V whatever the set voltage) and
        started with one line, so its first edge is the device's own; it ends by the device's own count, read back
        with ``read_cycles`` (`Dialect.cycle_count`).
    status_operations: operations read every cycle whose answers `Dialect.status_report` decodes.
    """

    channels_per_device: int | None
    device_ramp: bool
    current: CurrentSensing
    emergency_off: bool
    status_operations: tuple[str, ...]
    device_current_margin: float | None = None
    device_watchdog_s: float | None = None
    switching: DeviceSwitching | None = None

    def required_operations(self) -> tuple[str, ...]:
        needed = list(BASE_OPERATIONS) + list(self.status_operations)
        if self.channels_per_device is None:
            needed.append("read_channel_count")
        if self.device_ramp:
            needed += ["set_ramp_up", "set_ramp_down", "read_ramp"]
        if self.current is not CurrentSensing.NONE:
            needed.append("measure_current")
        if self.emergency_off:
            needed += ["emergency_off", "emergency_clear"]
        if self.switching is not None:
            needed += ["set_frequency", "set_cycles", "start_switching", "read_cycles"]
        return tuple(needed)


@dataclass(frozen=True)
class Command:
    """One row of a command table.

    template: the line sent, with ``{value}`` and ``{channels}`` fields.
    reply: "ack" (a setting; the dialect makes the device acknowledge it), "none" (a setting the device does not
        answer), "value" (a setting the device answers with the value now in force, which must equal the value
        sent), "text", "number" (one number per channel, with ``unit`` appended by the device) or "integer"
        (registers, modes).
    unit: unit suffix the device appends to numbers ("V", "A", "V/s", "ms").
    fmt: format spec of ``{value}`` ("" = the dialect's number format), e.g. ".0f" for an integer code.
    """

    template: str
    reply: str
    unit: str = ""
    fmt: str = ""


@dataclass(frozen=True)
class StatusReport:
    """The parts of a channel's status the supervisor needs."""

    output_on: bool
    ramping: bool
    over_current: bool
    fault: str | None        # device-side fault (interlock, emergency off, limit), None if none
    switching: bool = False  # the device is switching its output by itself (device-side switching)


class Dialect(ABC):
    """Wire dialect and capabilities of one family of supplies."""

    name: str
    capabilities: Capabilities
    command_terminator: bytes  # ends every line sent
    reply_terminator: bytes    # ends every line received
    echo: bool                 # the device echoes every character of the command line
    default_baudrate: int
    commands: Mapping[str, Command]
    number_pattern: re.Pattern = DECIMAL_NUMBER  # how the device writes a number (without its unit)

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        missing = [op for op in cls.capabilities.required_operations() if op not in cls.commands]
        if missing:
            raise TypeError(f"dialect {cls.__name__} lacks operations {missing} (needed by its capabilities)")

    def encode(self, operation: str, channels: Sequence[int] = (), value: float | None = None) -> str:
        """Command line (without terminator) for ``operation``."""
        command = self.commands[operation]
        fields = {"channels": self.format_channels(channels)}
        if "{value}" in command.template:
            if value is None:
                raise ValueError(f"operation {operation!r} needs a value")
            fields["value"] = format(value, command.fmt) if command.fmt else self.format_number(value)
        line = command.template.format(**fields)
        return self.acknowledged(line) if command.reply == "ack" else line

    def expects_reply(self, operation: str) -> bool:
        return self.commands[operation].reply != "none"

    def decode(self, operation: str, reply: str, count: int = 1, line: str = ""):
        """Parse the reply line of ``operation`` (sent as ``line``): str, list[float], list[int] or None (ack)."""
        command = self.commands[operation]
        if command.reply == "ack":
            if reply != self.ack_reply:
                raise ProtocolError(f"{operation}: expected acknowledgement {self.ack_reply!r}, got {reply!r}")
            return None
        if command.reply == "text":
            if not reply or not reply.isprintable():
                raise ProtocolError(f"{operation}: unreadable text reply {reply!r}")
            return reply
        if command.reply == "value":  # the value now in force, as sent (the line's last word)
            sent = line.rsplit(" ", 1)[-1]
            if self.parse_number(reply, command, operation) != self.parse_number(sent, command, operation):
                raise ProtocolError(f"{operation}: sent {line!r}, the device answered {reply!r}")
            return None
        fields = reply.split(",")
        if len(fields) != count:
            raise ProtocolError(f"{operation}: expected {count} value(s), got {reply!r}")
        return [self.parse_number(field, command, operation) for field in fields]

    def session_settings(self) -> list[tuple[str, float]]:
        """(operation, value) sent at the start of every session, after the outputs are off (modes the driver
        relies on)."""
        return []

    def identity_problem(self, identity: str) -> str | None:
        """Why a device answering ``identity`` is not one this dialect drives (None: it is)."""
        return None

    def cycle_count(self, reply: str) -> tuple[int, int]:
        """The answer of ``read_cycles``: (cycles switched so far, cycles counted in all), written ``done/total``."""
        done, slash, total = reply.partition("/")
        if not (slash and done.strip().isdigit() and total.strip().isdigit()):
            raise ProtocolError(f"read_cycles: expected 'done/total', got {reply!r}")
        return int(done), int(total)

    def device_trip_settings(self, current_a: float) -> list[tuple[str, float, str | None]]:
        """(set operation, value, read-back operation or None) that make the device cut or limit an output drawing
        more than ``current_a`` [A] (capability DEVICE_TRIP)."""
        return []

    @property
    def ack_reply(self) -> str:
        """Reply line that acknowledges a setting (dialects with "ack" settings)."""
        raise NotImplementedError

    def acknowledged(self, line: str) -> str:
        """A setting line extended so the device answers `ack_reply` once it has executed it."""
        raise NotImplementedError

    def format_channels(self, channels: Sequence[int]) -> str:
        """The channel list of a line ("" for a single-channel device)."""
        return ""

    @abstractmethod
    def format_number(self, value: float) -> str: ...

    def parse_number(self, field: str, command: Command, operation: str) -> float | int:
        """One number of a reply (or of a sent line, to compare with a "value" reply): an int for "integer"
        replies, else a float written as `number_pattern` with the unit rule of `without_unit`."""
        text = field.strip()
        if command.reply == "integer":
            if not text.isdigit():
                raise ProtocolError(f"{operation}: expected an integer, got {field!r}")
            return int(text)
        number = self.without_unit(text, command.unit)
        if number is None or not self.number_pattern.fullmatch(number):
            unit = f" in {command.unit}" if command.unit else ""
            raise ProtocolError(f"{operation}: expected a number{unit}, got {field!r}")
        return float(number)

    def without_unit(self, text: str, unit: str) -> str | None:
        """``text`` without the unit the device appends (None: the unit is missing). By default the device
        appends it always, right after the digits."""
        return text[: len(text) - len(unit)] if text.endswith(unit) else None

    @abstractmethod
    def status_report(self, *values: int) -> StatusReport:
        """Decode the answers of the capabilities' ``status_operations`` for one channel."""
