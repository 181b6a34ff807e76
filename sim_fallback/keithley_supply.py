"""Simulated Keithley 2290-5 on a pseudo-terminal: one output, LF-terminated lines, no echo, settings unanswered.

Commands (see hv_driver/dialects/keithley_2290.py): ``*IDN?``, ``*RST``, ``*CLS``, ``*STB?``, ``VSET <V>`` /
``VSET?``, ``VOUT?`` (signed, e.g. ``+1200.0``), ``IOUT?`` [A], ``VLIM <V>`` / ``VLIM?``, ``ILIM <A>`` / ``ILIM?``,
``HVON``, ``HVOF``, ``TCLR``. The output has no ramp: it regulates towards VSET with a short lag. ``ILIM`` acts at
once: a current above it switches the output off and latches the current-trip bit until ``TCLR`` (``HVON`` is
refused meanwhile). ``VSET`` above ``VLIM`` is held at ``VLIM``. A line it cannot execute gets no answer (the note
gives no error reply; the ISIS emulator logs it), so a query it does not know times out at the host.
"""
import re

from hv_driver.dialects.keithley_2290 import Keithley2290, StatusByte

from .hv_plant import ChannelDefaults, PlantChannel, PlantEvent
from .pty_device import PtyDevice

IDENTITY = "KEITHLEY INSTRUMENTS INC.,MODEL 2290-5 (simulated),SIM00002,1.0"
RATING = 5000.0  # [V]

_LINE = re.compile(r"^(?P<header>\*?[A-Z]+\??)(?:\s+(?P<arg>\S+))?$")


def status_byte(ch: PlantChannel) -> StatusByte:
    byte = StatusByte(0)
    for bit, active in ((StatusByte.STABLE, ch.output_on and not ch.ramping),
                        (StatusByte.CURRENT_TRIP, ch.current_trip),
                        (StatusByte.HV_ON, ch.output_on)):
        if active:
            byte |= bit
    return byte


class SimulatedKeithley2290(PtyDevice):
    """A 2290-5 with a DEA load on a pty, with the fault injection of `PtyDevice`."""

    dialect = Keithley2290
    command_terminator = reply_terminator = b"\n"
    echo = False
    # No device ramp; ILIM trips at once, switching the output off without ramp.
    default_defaults = ChannelDefaults(voltage_limit=RATING, ramp_speed=None, regulation_time_s=0.01,
                                       current_limit=5e-3, trip_time_ms=0.0, trip_action=2)

    def __init__(self, channels: int = 1, defaults: ChannelDefaults | None = None, **options):
        if channels != 1:
            raise ValueError(f"channels={channels}: a 2290 has one output")
        super().__init__(1, defaults, **options)
        self.voltage_limit = self.plant[0].defaults.voltage_limit

    def reset_device_state(self) -> None:
        self.voltage_limit = self.plant[0].defaults.voltage_limit

    def execute(self, line: str) -> str | None:
        match = _LINE.match(line.strip().upper())
        if not match:
            return None
        header, arg = match["header"], match["arg"]
        ch, now = self.plant[0], self.clock()
        queries = {"*IDN?": lambda: IDENTITY, "*STB?": lambda: str(int(status_byte(ch))),
                   "VSET?": lambda: f"{ch.voltage_set:.1f}", "VOUT?": lambda: f"{ch.measured_voltage:+.1f}",
                   "IOUT?": lambda: f"{ch.measured_current:.4e}", "VLIM?": lambda: f"{self.voltage_limit:.1f}",
                   "ILIM?": lambda: f"{ch.current_limit:.4e}"}
        if header in queries and arg is None:
            return queries[header]()
        try:
            value = None if arg is None else float(arg)
        except ValueError:
            return None
        if header == "*RST" and value is None:
            ch.switch_off(now, emergency=False, ramp=False)
            ch.power_on_reset()
            self.reset_device_state()
        elif header == "*CLS" and value is None:
            ch.events = PlantEvent(0)
        elif header == "HVON" and value is None:
            ch.switch_on()
        elif header == "HVOF" and value is None:
            ch.switch_off(now, emergency=False, ramp=False)
        elif header == "TCLR" and value is None:
            ch.current_trip = False
            ch.events = PlantEvent(0)
        elif header == "VSET" and value is not None and value >= 0:
            ch.voltage_set = min(value, self.voltage_limit)
        elif header == "VLIM" and value is not None and 0 <= value <= RATING:
            self.voltage_limit = value
            ch.voltage_set = min(ch.voltage_set, value)
        elif header == "ILIM" and value is not None and value > 0:
            ch.current_limit = value
        return None
