"""iseg NHR / SHR "EDCP" dialect (SCPI-like, serial).

Framing: ASCII lines ending in CR LF; the device echoes every received character (factory
default), so each answer is preceded by the echoed command line. Settings are sent as
``<setting>;*OPC?`` so the device answers ``1`` once executed: every exchange is one echoed line
plus one answer line. Numbers go out in exponent notation (``1.200000E+03``) and come back in
exponent notation followed by their unit (``1.20000E3V``, ``5.00000E-9A``, ``ms``, ``V/s``);
several channels answer comma-separated. Channel lists are ``(@0)``, ``(@0,1)``.

Capabilities: several channels per module (``:READ:MOD:CHAN?``); a device ramp (``:CONF:RAMP:VOLT``, and
``:VOLT OFF`` ramps down at it); current readback and a delayed device trip (``:CURR`` limit, ``:CONF:TRIP:TIME``,
``:CONF:TRIP:ACTION``) set 1.5 x above the host's trip level with 100 ms delay, a slower second line behind the
host's check; a latched emergency off; no host watchdog (wire the INHIBIT input to an external interlock); no
device-side switching.
"""
from collections.abc import Sequence
from enum import IntFlag

from .base import Capabilities, Command, CurrentSensing, Dialect, StatusReport


class ChannelStatus(IntFlag):
    """Bits of ``:READ:CHAN:STATUS?`` (the channel status register)."""

    IS_POSITIVE = 1 << 0
    IS_ARC = 1 << 1
    IS_INPUT_ERROR = 1 << 2
    IS_ON = 1 << 3
    IS_VOLTAGE_RAMP = 1 << 4
    IS_EMERGENCY_OFF = 1 << 5
    IS_CONSTANT_CURRENT = 1 << 6
    IS_CONSTANT_VOLTAGE = 1 << 7
    IS_LOW_CURRENT_RANGE = 1 << 8
    IS_ARC_NUMBER_EXCEEDED = 1 << 9
    IS_CURRENT_BOUNDS = 1 << 10
    IS_VOLTAGE_BOUNDS = 1 << 11
    IS_EXTERNAL_INHIBIT = 1 << 12
    IS_CURRENT_TRIP = 1 << 13
    IS_CURRENT_LIMIT = 1 << 14
    IS_VOLTAGE_LIMIT = 1 << 15


class ChannelEvent(IntFlag):
    """Bits of ``:READ:CHAN:EVENT:STATUS?``: latched events, cleared with ``:EVENT CLEAR``."""

    EVENT_ARC = 1 << 1
    EVENT_INPUT_ERROR = 1 << 2
    EVENT_ON_TO_OFF = 1 << 3
    EVENT_END_OF_RAMP = 1 << 4
    EVENT_EMERGENCY_OFF = 1 << 5
    EVENT_CONSTANT_CURRENT = 1 << 6
    EVENT_CONSTANT_VOLTAGE = 1 << 7
    EVENT_ARC_NUMBER_EXCEEDED = 1 << 9
    EVENT_CURRENT_BOUNDS = 1 << 10
    EVENT_VOLTAGE_BOUNDS = 1 << 11
    EVENT_EXTERNAL_INHIBIT = 1 << 12
    EVENT_CURRENT_TRIP = 1 << 13
    EVENT_CURRENT_LIMIT = 1 << 14
    EVENT_VOLTAGE_LIMIT = 1 << 15


# Status bits that mean the supply itself stopped or refuses the output.
DEVICE_FAULT_BITS = (ChannelStatus.IS_INPUT_ERROR | ChannelStatus.IS_EMERGENCY_OFF
                     | ChannelStatus.IS_EXTERNAL_INHIBIT | ChannelStatus.IS_VOLTAGE_LIMIT
                     | ChannelStatus.IS_CURRENT_LIMIT | ChannelStatus.IS_ARC_NUMBER_EXCEEDED)
OVER_CURRENT_BITS = ChannelStatus.IS_CURRENT_TRIP | ChannelStatus.IS_ARC
# The same, latched as events: catches what happened between two polls.
DEVICE_FAULT_EVENTS = (ChannelEvent.EVENT_INPUT_ERROR | ChannelEvent.EVENT_EMERGENCY_OFF
                       | ChannelEvent.EVENT_EXTERNAL_INHIBIT | ChannelEvent.EVENT_VOLTAGE_LIMIT
                       | ChannelEvent.EVENT_CURRENT_LIMIT | ChannelEvent.EVENT_ARC_NUMBER_EXCEEDED)
OVER_CURRENT_EVENTS = ChannelEvent.EVENT_CURRENT_TRIP | ChannelEvent.EVENT_ARC

# TRIP:ACTION codes: 0 flag only, 1 off with ramp, 2 off without ramp, 3 module off, 4 no delayed trip.
TRIP_ACTION_OFF_WITHOUT_RAMP = 2
# Delay of the device's own current trip: it acts only if the host's check (every control cycle) did not.
DEVICE_TRIP_TIME_MS = 100.0


class IsegEdcp(Dialect):
    name = "iseg-edcp"
    capabilities = Capabilities(channels_per_device=None, device_ramp=True, current=CurrentSensing.DEVICE_TRIP,
                                emergency_off=True, status_operations=("read_status", "read_event_status"),
                                device_current_margin=1.5)
    command_terminator = reply_terminator = b"\r\n"
    echo = True
    default_baudrate = 9600
    commands = {
        "identify": Command("*IDN?", "text"),
        "read_channel_count": Command(":READ:MOD:CHAN?", "integer"),
        "reset": Command("*RST", "ack"),
        "set_voltage": Command(":VOLT {value},{channels}", "ack"),
        "output_on": Command(":VOLT ON,{channels}", "ack"),
        "output_off": Command(":VOLT OFF,{channels}", "ack"),
        "emergency_off": Command(":VOLT EMCY OFF,{channels}", "ack"),
        "emergency_clear": Command(":VOLT EMCY CLR,{channels}", "ack"),
        "clear_events": Command(":EVENT CLEAR,{channels}", "ack"),
        "measure_voltage": Command(":MEAS:VOLT? {channels}", "number", "V"),
        "measure_current": Command(":MEAS:CURR? {channels}", "number", "A"),
        "read_status": Command(":READ:CHAN:STATUS? {channels}", "integer"),
        "read_event_status": Command(":READ:CHAN:EVENT:STATUS? {channels}", "integer"),
        "read_voltage_limit": Command(":READ:VOLT:LIM? {channels}", "number", "V"),
        "set_ramp_up": Command(":CONF:RAMP:VOLT:UP {value},{channels}", "ack"),
        "set_ramp_down": Command(":CONF:RAMP:VOLT:DOWN {value},{channels}", "ack"),
        "read_ramp": Command(":READ:RAMP:VOLT? {channels}", "number", "V/s"),
        "set_current_limit": Command(":CURR {value},{channels}", "ack"),
        "read_current_limit": Command(":READ:CURR? {channels}", "number", "A"),
        "set_trip_time": Command(":CONF:TRIP:TIME {value},{channels}", "ack"),
        "read_trip_time": Command(":CONF:TRIP:TIME? {channels}", "number", "ms"),
        "set_trip_action": Command(":CONF:TRIP:ACTION {value},{channels}", "ack", fmt=".0f"),
    }
    ack_reply = "1"

    def acknowledged(self, line: str) -> str:
        return f"{line};*OPC?"

    def device_trip_settings(self, current_a: float) -> list[tuple[str, float, str | None]]:
        """Current limit, then a trip after DEVICE_TRIP_TIME_MS that switches the output off without ramp."""
        return [("set_current_limit", current_a, "read_current_limit"),
                ("set_trip_time", DEVICE_TRIP_TIME_MS, "read_trip_time"),
                ("set_trip_action", TRIP_ACTION_OFF_WITHOUT_RAMP, None)]

    def format_number(self, value: float) -> str:
        return f"{value:.6E}"

    def format_channels(self, channels: Sequence[int]) -> str:
        return "(@" + ",".join(str(int(c)) for c in channels) + ")"

    def status_report(self, status: int, events: int) -> StatusReport:
        state = ChannelStatus(status & sum(ChannelStatus))
        latched = ChannelEvent(events & sum(ChannelEvent))
        device = [b.name.lower() for b in ChannelStatus if b in state & DEVICE_FAULT_BITS]
        device += [b.name.lower() for b in ChannelEvent if b in latched & DEVICE_FAULT_EVENTS]
        return StatusReport(
            output_on=ChannelStatus.IS_ON in state,
            ramping=ChannelStatus.IS_VOLTAGE_RAMP in state,
            over_current=bool(state & OVER_CURRENT_BITS or latched & OVER_CURRENT_EVENTS),
            fault="supply reports " + ", ".join(device) if device else None,
        )
