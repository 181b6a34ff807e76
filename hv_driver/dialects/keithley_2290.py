"""Keithley 2290-5 / 2290-10 high-voltage supply (RS-232): one output per unit.

Framing: ASCII lines ending in LF both ways, no echo (the ISIS EPICS StreamDevice protocol file for the 2290
uses ``Terminator = "\\n"``). Settings (``VSET``, ``VLIM``, ``ILIM``, ``HVON``, ``HVOF``, ``TCLR``, ``*RST``) are not
answered; queries answer one number (``VOUT?`` carries its sign, e.g. ``+1200.0``), read as a float; a trailing unit
letter is tolerated. ``*STB?`` answers the status byte (bits from the ISIS protocol file: 0 stable, 1 voltage trip,
2 current trip, 3 current limit, 4 message available, 5 event summary, 6 service request, 7 HV on).

Capabilities: one channel per unit (several units are several channels, one port each); no settable ramp, so the
host ramps in its loop; current readback and a device current limit (``ILIM``) that the driver sets at 0.9 x the
host's trip level and reads back: it acts in hardware, at once, so an arc is held below the host's trip level and
shows as the current-limit or current-trip bit, which the driver latches as OVER_CURRENT; the host's own check at
the trip level backs it up. A device voltage limit (``VLIM``) is set to the channel's hard maximum and read back.
No latched emergency off: the driver cuts an output with ``HVOF`` then ``VSET 0``; a fault latches on the host only.
No host watchdog. No device-side switching.

Left open by the note, decided by the manual: currents are taken in A (the note's ``ILIM <A>``; the ISIS EPICS
database labels its current records uA while its own tests write amp-sized values); the factory baud rate is
taken as 9600; ``ITRP`` (a separate trip level in the ISIS file) is not used; whether ``HVON`` is refused while
the rear-panel HV enable is off (the ISIS emulator's behaviour) shows here as the output not coming on, a
DEVICE fault.
"""
from enum import IntFlag

from .base import Capabilities, Command, CurrentSensing, Dialect, StatusReport


class StatusByte(IntFlag):
    """Bits of ``*STB?``."""

    STABLE = 1 << 0
    VOLTAGE_TRIP = 1 << 1
    CURRENT_TRIP = 1 << 2
    CURRENT_LIMIT = 1 << 3
    MESSAGE_AVAILABLE = 1 << 4
    EVENT_SUMMARY = 1 << 5
    SERVICE_REQUEST = 1 << 6
    HV_ON = 1 << 7


class Keithley2290(Dialect):
    name = "keithley-2290"
    capabilities = Capabilities(channels_per_device=1, device_ramp=False, current=CurrentSensing.DEVICE_TRIP,
                                emergency_off=False, status_operations=("read_status",), device_current_margin=0.9)
    command_terminator = reply_terminator = b"\n"
    echo = False
    default_baudrate = 9600
    commands = {
        "identify": Command("*IDN?", "text"),
        "reset": Command("*RST", "none"),
        "set_voltage": Command("VSET {value}", "none"),
        "output_on": Command("HVON", "none"),
        "output_off": Command("HVOF", "none"),
        "clear_events": Command("TCLR", "none"),
        "measure_voltage": Command("VOUT?", "number", "V"),
        "measure_current": Command("IOUT?", "number", "A"),
        "read_status": Command("*STB?", "integer"),
        "set_voltage_limit": Command("VLIM {value}", "none"),
        "read_voltage_limit": Command("VLIM?", "number", "V"),
        "set_current_limit": Command("ILIM {value}", "none"),
        "read_current_limit": Command("ILIM?", "number", "A"),
    }

    def device_trip_settings(self, current_a: float) -> list[tuple[str, float, str | None]]:
        return [("set_current_limit", current_a, "read_current_limit")]

    def format_number(self, value: float) -> str:
        return format(value, ".6g")

    def without_unit(self, text: str, unit: str) -> str:
        """The unit may follow the number, in either case and after spaces, or be left out."""
        if unit and text.upper().endswith(unit.upper()):
            return text[: -len(unit)].rstrip()
        return text

    def status_report(self, status: int) -> StatusReport:
        byte = StatusByte(status & 0xFF)
        return StatusReport(output_on=StatusByte.HV_ON in byte, ramping=False,
                            over_current=bool(byte & (StatusByte.CURRENT_TRIP | StatusByte.CURRENT_LIMIT)),
                            fault="supply reports voltage_trip" if StatusByte.VOLTAGE_TRIP in byte else None)
