"""Simulated Peta-pico-Voltron board ("slave", firmware 8) on a pseudo-terminal: one output, commands end in CR,
answers in CR LF, no echo, every setting answered with the value now in force.

It answers the command set of the board's reference interface library as the note describes it: ``QVer``,
``QName``, ``QVmax``, ``QJack``, ``QPowJack``, ``QI2C``/``SI2C``, ``SVset``/``QVset``, ``QVnow``,
``SSwMode``/``QSwMode``, ``SF``/``QF``, ``SCycle``/``QCycle``, ``SSwSrc``/``QSwSrc``, ``SVMode``/``QVMode``,
``SPWM``/``QPWM``, ``QMem``, ``Save``, ``SLatchMode``/``QLatchMode``, the strobe commands
``SStMode``/``QStMode``, ``SStPos``/``QStPos``, ``SStDur``/``QStDur``, ``SStSw``. No current readback, no ramp
(the output regulates towards Vset with a lag that grows with the load), no trip: an arc collapses the voltage and
nothing else shows it. Switching mode 2 runs on the board's own clock (50 % duty) and falls back to mode 0 after
``SCycle`` cycles. A line it cannot execute is answered ``?`` (the note gives no error answer).
"""
import re

from hv_driver.dialects.ppv import MODE_DC, MODE_OFF, MODE_SWITCHING, PetaPicoVoltron

from .hv_plant import ChannelDefaults
from .pty_device import PtyDevice

FIRMWARE = 8
RATING = 5000.0  # [V] QVmax of the simulated board
ERROR_REPLY = "?"
MIN_FREQUENCY, MAX_FREQUENCY = 0.001, 5000.0  # [Hz]
MAX_CYCLES = 65535
DUTY = 0.5

_LINE = re.compile(r"^(?P<command>[SQ][A-Za-z0-9]+|Save)(?:\s+(?P<arg>\S+))?$")
# Settings kept as plain integers: command -> (attribute, lowest, highest).
_INTEGER_SETTINGS = {"SSwSrc": ("switching_source", 0, 2), "SVMode": ("voltage_mode", 0, 2),
                     "SPWM": ("pwm", 0, 1023), "SI2C": ("i2c", 0, 127), "SLatchMode": ("latch", 0, 1),
                     "SStMode": ("strobe_mode", 0, 3), "SStPos": ("strobe_position", 0, 255),
                     "SStDur": ("strobe_duration", 0, 255), "SStSw": ("strobe_sweep", 0, 65535)}


class SimulatedPpv(PtyDevice):
    """One PPV board with a DEA load on a pty, with the fault injection of `PtyDevice`."""

    dialect = PetaPicoVoltron
    command_terminator = b"\r"
    reply_terminator = b"\r\n"
    echo = False
    default_defaults = ChannelDefaults(voltage_limit=RATING, ramp_speed=None, regulation_time_s=0.005,
                                       current_limit=1.0, trip_action=0)

    def __init__(self, channels: int = 1, defaults: ChannelDefaults | None = None, name: str = "PPV-SIM",
                 off_first: bool = False, clock_error: float = 0.0, **options):
        if channels != 1:
            raise ValueError(f"channels={channels}: a PPV board has one output")
        super().__init__(1, defaults, **options)
        self.name = name
        self.off_first = off_first  # each switched period begins with its off half (the firmware leaves it open)
        self.clock_error = clock_error  # the board's timer runs this fraction fast (< 0: slow) against true time
        self.reset_device_state()

    def reset_device_state(self) -> None:
        self.mode, self.frequency, self.cycles = MODE_OFF, 1.0, 0
        self.switching_source = self.voltage_mode = self.pwm = self.i2c = self.latch = 0
        self.strobe_mode = self.strobe_position = self.strobe_duration = 0
        self.strobe_sweep = 5000
        self.saved = None

    @property
    def switching_mode(self) -> int:
        if self.mode == MODE_SWITCHING and self.plant[0].switching is None:
            self.mode = MODE_OFF  # the counted cycles are over (or the output was cut): back to off
        return self.mode

    def _cycle_text(self) -> str:
        """``done/total``: the cycles switched so far (of the last train once it ended: all of them after its count)."""
        ch = self.plant[0]
        done = ch.cycles_switched if ch.switching is None else min(ch.switching.completed(self.clock()), self.cycles)
        return f"{done}/{self.cycles}"

    def _memory(self) -> str:
        ch = self.plant[0]
        return (f"{ch.voltage_set:.0f},{self.frequency:.3f},{self.switching_source},{self.switching_mode},"
                f"{self.voltage_mode},0.0,0.0,0.0,0.0,1.0,0.0,{self.cycles},{self.latch}")

    def execute(self, line: str) -> str:
        match = _LINE.match(line.strip())
        if not match:
            return ERROR_REPLY
        command, arg = match["command"], match["arg"]
        ch, now = self.plant[0], self.clock()
        queries = {"QVer": lambda: f"slave {FIRMWARE}", "QName": lambda: self.name, "QVmax": lambda: f"{RATING:.0f}",
                   "QJack": lambda: "1", "QPowJack": lambda: "1", "QVset": lambda: f"{ch.voltage_set:.0f}",
                   "QVnow": lambda: f"{max(0.0, ch.measured_voltage):.0f}", "QSwMode": lambda: str(self.switching_mode),
                   "QF": lambda: f"{self.frequency:.3f}", "QCycle": self._cycle_text, "QMem": self._memory,
                   "QSwSrc": lambda: str(self.switching_source), "QVMode": lambda: str(self.voltage_mode),
                   "QPWM": lambda: str(self.pwm), "QI2C": lambda: str(self.i2c), "QLatchMode": lambda: str(self.latch),
                   "QStMode": lambda: str(self.strobe_mode), "QStPos": lambda: str(self.strobe_position),
                   "QStDur": lambda: str(self.strobe_duration)}
        if command in queries and arg is None:
            return queries[command]()
        if command == "Save" and arg is None:
            self.saved = self._memory()
            return "1"
        try:
            value = float(arg)
        except (TypeError, ValueError):
            return ERROR_REPLY
        if command == "SVset":
            ch.voltage_set = min(max(0.0, round(value)), RATING)
            return f"{ch.voltage_set:.0f}"
        if command == "SSwMode" and value in (MODE_OFF, MODE_DC, MODE_SWITCHING):
            return str(self._set_mode(int(value), now))
        if command == "SF":
            self.frequency = round(min(max(value, MIN_FREQUENCY), MAX_FREQUENCY), 3)
            return f"{self.frequency:.3f}"
        if command == "SCycle" and 0 <= value <= MAX_CYCLES and value == int(value):
            self.cycles = int(value)
            if ch.switching is not None:  # the counter restarts
                ch.start_switching(now, self.frequency * (1.0 + self.clock_error), DUTY, self.cycles, self.off_first)
            return str(self.cycles)
        if command in _INTEGER_SETTINGS and value == int(value):
            attribute, low, high = _INTEGER_SETTINGS[command]
            if low <= value <= high:
                setattr(self, attribute, int(value))
                return str(int(value))
        return ERROR_REPLY

    def _set_mode(self, mode: int, now: float) -> int:
        ch = self.plant[0]
        if mode == MODE_OFF:
            ch.switch_off(now, emergency=False, ramp=False)
        elif mode == MODE_DC:
            ch.switching = None
            ch.switch_on()
        else:
            ch.start_switching(now, self.frequency * (1.0 + self.clock_error), DUTY, self.cycles, self.off_first)
        self.mode = mode
        return mode
