"""Simulated iseg NHR-style HV supply speaking the EDCP dialect on a pseudo-terminal.

In process: ``sim = SimulatedSupply(channels=2).start()``; open ``sim.port`` with pyserial;
``sim.inject("over_current", channel=0)``; ``sim.clear_faults()``; ``sim.stop()``.
CLI (every simulated dialect): ``python -m sim_fallback.rig`` (this module's ``python -m sim_fallback.hv_supply``
runs it for the iseg dialect).
"""
import re
import sys

from hv_driver.dialects.iseg_edcp import ChannelEvent, ChannelStatus, IsegEdcp

from .hv_plant import ChannelDefaults, PlantChannel, PlantEvent
from .pty_device import FAULTS, PtyDevice

__all__ = ["ERROR_REPLY", "FAULTS", "IDENTITY", "SimulatedSupply"]

IDENTITY = "iseg Spezialelektronik GmbH,NHR 42 50r (simulated),SIM00001,1.00"
ERROR_REPLY = "?"  # answer to a line the simulated device cannot execute
INSTRUCTION_SET = "EDCP"
FIRMWARE_NAME, FIRMWARE_RELEASE = "E08F05", "1.00"
NOMINAL_CURRENT = 2e-3  # [A] the module's rating; its hardware current limit (potentiometer) at full scale
# SCPI keywords may be sent in long or short form (the short form is their upper-case part): long -> short.
_SHORT_FORMS = {"STATUS": "STAT", "EVENT": "EV", "CHANNEL": "CHAN", "VOLTAGE": "VOLT", "CURRENT": "CURR",
                "MEASURE": "MEAS", "CONFIGURE": "CONF", "BOUNDS": "BOU", "ACTION": "ACT", "INHIBIT": "INH",
                "NOMINAL": "NOM", "LIMIT": "LIM", "MODULE": "MOD", "FIRMWARE": "FIRM", "RELEASE": "REL",
                "EMERGENCY": "EMCY", "OUTPUT": "OUTP"}

_UNIT = re.compile(r"^(?P<header>[*:A-Z]+\??)(?:\s+(?P<args>.*))?$")
_CHANNELS = re.compile(r"\(@(?P<list>[0-9,\-]+)\)")
_SETTING_ARGS = re.compile(r"(?P<value>.*),(?P<channels>\(@[0-9,\-]+\))")
# Plant events as the iseg event register shows them.
_EVENT_BITS = {PlantEvent.ARC: ChannelEvent.EVENT_ARC, PlantEvent.ON_TO_OFF: ChannelEvent.EVENT_ON_TO_OFF,
               PlantEvent.EMERGENCY_OFF: ChannelEvent.EVENT_EMERGENCY_OFF,
               PlantEvent.CURRENT_TRIP: ChannelEvent.EVENT_CURRENT_TRIP,
               PlantEvent.EXTERNAL_INHIBIT: ChannelEvent.EVENT_EXTERNAL_INHIBIT}


class CommandError(ValueError):
    """The line cannot be executed (unknown header, bad argument, channel out of range)."""


def _number(field: str) -> float:
    try:
        return float(field)
    except ValueError:
        raise CommandError(f"not a number: {field!r}") from None


def _reading(value: float, unit: str) -> str:
    return f"{value:.5E}{unit}"


def channel_status(ch: PlantChannel) -> ChannelStatus:
    """The iseg channel status register of a plant channel."""
    status = ChannelStatus.IS_POSITIVE
    for flag, active in ((ChannelStatus.IS_ON, ch.output_on),
                         (ChannelStatus.IS_VOLTAGE_RAMP, ch.ramping),
                         (ChannelStatus.IS_CONSTANT_VOLTAGE, ch.output_on and not ch.ramping),
                         (ChannelStatus.IS_EMERGENCY_OFF, ch.emergency),
                         (ChannelStatus.IS_ARC, ch.arcing),
                         (ChannelStatus.IS_CURRENT_TRIP, ch.current_trip)):
        if active:
            status |= flag
    return status


def channel_events(ch: PlantChannel) -> ChannelEvent:
    return ChannelEvent(sum(bit for event, bit in _EVENT_BITS.items() if event in ch.events))


def short_header(header: str) -> str:
    """The header with every keyword in its SCPI short form (``:READ:CHAN:EVENT:STATUS?`` ->
    ``:READ:CHAN:EV:STAT?``), so both forms reach the same command."""
    query = header.endswith("?")
    words = header.rstrip("?").split(":")
    return ":".join(_SHORT_FORMS.get(word, word) for word in words) + ("?" if query else "")


# Per-channel queries (short-form headers): header -> answer of one channel (channels answer comma-separated).
_QUERIES = {
    ":MEAS:VOLT?": lambda ch: _reading(ch.measured_voltage, "V"),
    ":MEAS:CURR?": lambda ch: _reading(ch.measured_current, "A"),
    ":READ:CHAN:STAT?": lambda ch: str(int(channel_status(ch))),
    ":READ:CHAN:EV:STAT?": lambda ch: str(int(channel_events(ch))),
    ":READ:VOLT?": lambda ch: _reading(ch.voltage_set, "V"),  # the setpoint
    ":READ:VOLT:LIM?": lambda ch: _reading(ch.defaults.voltage_limit, "V"),
    ":READ:VOLT:NOM?": lambda ch: _reading(ch.defaults.voltage_limit, "V"),
    ":READ:VOLT:ON?": lambda ch: str(int(ch.output_on)),
    ":READ:VOLT:EMCY?": lambda ch: str(int(ch.emergency)),
    ":READ:RAMP:VOLT?": lambda ch: _reading(ch.ramp_up, "V/s"),
    ":CONF:RAMP:VOLT:UP?": lambda ch: _reading(ch.ramp_up, "V/s"),
    ":CONF:RAMP:VOLT:DOWN?": lambda ch: _reading(ch.ramp_down, "V/s"),
    ":READ:CURR?": lambda ch: _reading(ch.current_limit, "A"),  # the current setpoint (trip level)
    ":READ:CURR:NOM?": lambda ch: _reading(NOMINAL_CURRENT, "A"),
    ":READ:CURR:LIM?": lambda ch: _reading(NOMINAL_CURRENT, "A"),
    ":READ:VOLT:BOU?": lambda ch: _reading(ch.voltage_bounds, "V"),
    ":READ:CURR:BOU?": lambda ch: _reading(ch.current_bounds, "A"),
    ":CONF:TRIP:TIME?": lambda ch: _reading(ch.trip_time_ms, "ms"),
    ":CONF:TRIP:ACT?": lambda ch: str(ch.trip_action),
}
# Module queries without a channel list.
_MODULE_QUERIES = {"*IDN?": IDENTITY, "*OPC?": "1", "*INSTR?": INSTRUCTION_SET, ":READ:FIRM:NAME?": FIRMWARE_NAME,
                   ":READ:FIRM:REL?": FIRMWARE_RELEASE}


class SimulatedSupply(PtyDevice):
    """A multi-channel EDCP supply with DEA loads on a pty, with fault injection (see `PtyDevice`): it echoes every
    line, answers settings sent with ``;*OPC?`` (a setting alone is answered by its echo only), numbers with units,
    channel lists, SCPI keywords in long or short form; ``?`` for a line it cannot execute. It has no host watchdog
    unless ``watchdog_s`` is given, as on an iseg module."""

    dialect = IsegEdcp
    command_terminator = reply_terminator = b"\r\n"
    echo = True

    def __init__(self, channels: int = 2, defaults: ChannelDefaults | None = None, **options):
        super().__init__(channels, defaults, **options)
        self.locked_out = False  # *LLO: the front panel is locked

    # --- the EDCP command set ------------------------------------------------------------------
    def execute(self, line: str) -> str:
        answers = []
        try:
            for unit in line.split(";"):
                answer = self._execute_unit(unit.strip())
                if answer is not None:
                    answers.append(answer)
        except CommandError:
            return ERROR_REPLY
        return ";".join(answers) if answers else None  # a setting alone: the echo is the whole answer

    def _execute_unit(self, unit: str) -> str | None:
        match = _UNIT.match(unit.upper())
        if not match:
            raise CommandError(f"malformed: {unit!r}")
        header, args = short_header(match["header"]), (match["args"] or "").strip()
        now = self.clock()
        if header in _MODULE_QUERIES:
            return _MODULE_QUERIES[header]
        if header == ":READ:MOD:CHAN?":
            return str(len(self.plant))
        if header in ("*LLO", "*GTL"):  # front-panel lockout / back to local control
            self.locked_out = header == "*LLO"
            return None
        if header == "*RST":
            for ch in self.plant:
                ch.switch_off(now, emergency=False)
                ch.power_on_reset()
            return None
        if header == "*CLS":
            for ch in self.plant:
                ch.events = PlantEvent(0)
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
        elif header == ":VOLT:BOU":
            ch.voltage_bounds = _number(value)
        elif header == ":CURR:BOU":
            ch.current_bounds = _number(value)
        elif header in (":CONF:RAMP:VOLT", ":CONF:RAMP:VOLT:UP", ":CONF:RAMP:VOLT:DOWN"):  # without UP/DOWN: both
            speed = min(_number(value), ch.defaults.max_ramp_speed)
            if not header.endswith("DOWN"):
                ch.ramp_up = speed
            if not header.endswith("UP"):
                ch.ramp_down = speed
        elif header == ":CONF:TRIP:TIME":
            ch.trip_time_ms = _number(value)
        elif header == ":CONF:TRIP:ACT":
            ch.trip_action = int(_number(value))
        elif header == ":EV" and value == "CLEAR":
            ch.events = PlantEvent(0)
            ch.current_trip = False
        else:
            raise CommandError(f"unknown setting {header} {value}")



if __name__ == "__main__":
    from .rig import main
    sys.exit(main(["--dialect", "iseg-edcp", *sys.argv[1:]]))
