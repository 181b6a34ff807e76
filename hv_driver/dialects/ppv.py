"""Peta-pico-Voltron (PPV), EPFL LMTS's open-source HV supply for DEAs: one single-channel board ("slave") per USB
serial port, 115200 8N1.

Facts from its public Python interface library (py-hvps-interface 2.8, firmware 8), as the note gathers them:
commands are one ASCII line ending in CR, answers one line ending in CR LF, no echo. A setting answers the value
now in force (``SVset 600`` -> ``600``; ``SSwMode 1`` -> ``1``; ``SCycle 20`` -> ``20``), which the driver compares
with what it sent; ``SF`` answers the frequency actually used after quantisation, which the driver checks against
the request. ``QVer`` answers ``slave 8`` (board type, firmware); ``QVmax`` the rating [V]; ``QVnow`` the measured
output [V, integer]; ``QSwMode`` the switching mode (0 off: 0 V whatever Vset; 1 DC at Vset; 2 switching between
0 V and Vset at ``SF`` for ``SCycle`` cycles, then back to 0; 3 user waveform). At the start of a session the driver
sets the switching source to the onboard timer (``SSwSrc 0``) and the regulated voltage mode (``SVMode 0``), as the
reference library does on connect.

Capabilities: one channel per board (a rig of four legs is four boards on four ports); **no current readback,
no device ramp and no device trip**: the host ramps, and a film breakdown shows only as the voltage collapsing,
which the supervisor detects (measured far below the setpoint while it is held, or no pulse reaching the amplitude
while the board switches) and answers by switching the board off (``SSwMode 0``, ``SVset 0``) with the named
fault BREAKDOWN. No latched emergency off and no host watchdog. Device-side switching: 0.001-5000 Hz, up to 65535
counted cycles, after which the board switches off by itself; ``QCycle`` answers ``done/total``, and the driver ends
a train by that count (its own clock ends it only as a bounded fallback).

What this device cannot protect against (the host cannot see it): a current that flows without pulling the voltage
down (a leaky film, a partial short that the regulator still holds; a larger load shows only as the output lagging
the host's ramp, READBACK_MISMATCH once the lag exceeds the tolerance, and not at all on a slow ramp), and anything that happens while the host is dead or the cable is pulled (no watchdog:
the output stays as it was, and a switching board goes on until its cycle count ends; use a finite count and an
external interlock).

Left open by the note, decided by the firmware or its manual: the duty of switching mode 2 (taken as 50 %, the
library has no duty setting), the answer to a line the board cannot execute (the library reads any malformed
answer as -1; the driver treats anything but the expected value as a protocol error), and the default baud rate
of other firmware versions.
"""
import re

from .base import Capabilities, Command, CurrentSensing, DeviceSwitching, Dialect, StatusReport

MODE_OFF, MODE_DC, MODE_SWITCHING, MODE_WAVEFORM = 0, 1, 2, 3
SWITCHING_SOURCE_TIMER = 0
VOLTAGE_MODE_REGULATED = 0


class PetaPicoVoltron(Dialect):
    name = "ppv"
    capabilities = Capabilities(
        channels_per_device=1, device_ramp=False, current=CurrentSensing.NONE, emergency_off=False,
        status_operations=("read_switching_mode",),
        switching=DeviceSwitching(min_frequency_hz=0.001, max_frequency_hz=5000.0, duty=0.5, max_cycles=65535))
    command_terminator = b"\r"
    reply_terminator = b"\r\n"
    echo = False
    default_baudrate = 115200
    number_pattern = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)")  # the board writes no exponent
    commands = {
        "identify": Command("QVer", "text"),
        "set_voltage": Command("SVset {value}", "value", fmt=".0f"),
        "output_on": Command(f"SSwMode {MODE_DC}", "value"),
        "output_off": Command(f"SSwMode {MODE_OFF}", "value"),
        "start_switching": Command(f"SSwMode {MODE_SWITCHING}", "value"),
        "set_frequency": Command("SF {value}", "number", fmt=".3f"),
        "set_cycles": Command("SCycle {value}", "value", fmt=".0f"),
        "read_cycles": Command("QCycle", "text"),  # "done/total" of the counted cycles
        "set_switching_source": Command("SSwSrc {value}", "value", fmt=".0f"),
        "set_voltage_mode": Command("SVMode {value}", "value", fmt=".0f"),
        "measure_voltage": Command("QVnow", "number"),
        "read_voltage_limit": Command("QVmax", "number"),
        "read_switching_mode": Command("QSwMode", "integer"),
    }

    def session_settings(self) -> list[tuple[str, float]]:
        return [("set_switching_source", SWITCHING_SOURCE_TIMER), ("set_voltage_mode", VOLTAGE_MODE_REGULATED)]

    def identity_problem(self, identity: str) -> str | None:
        kind, _, firmware = identity.partition(" ")
        if kind != "slave" or not firmware.strip().isdigit():
            return (f"expected a single-channel board answering 'slave <firmware>' to QVer, got {identity!r} "
                    "(a 'master' board drives several channels and speaks another protocol)")
        return None

    def format_number(self, value: float) -> str:
        return format(value, ".0f")

    def status_report(self, mode: int) -> StatusReport:
        return StatusReport(output_on=mode in (MODE_DC, MODE_SWITCHING), ramping=False, over_current=False,
                            fault=None if mode in (MODE_OFF, MODE_DC, MODE_SWITCHING)
                            else f"supply in switching mode {mode} (user waveform or unknown)",
                            switching=mode == MODE_SWITCHING)
