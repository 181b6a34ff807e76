"""Keithley 2290 and Peta-pico-Voltron framing against scripted (sent, reply) exchanges that fail on unused
exchanges and unread bytes: the whole open() sequence each dialect's capabilities choose, unanswered settings,
values answered back, garbage."""
import pytest

from hv_driver import ChannelConfig, LinkError, ProtocolError
from hv_driver.device import ConfigurationError, Device
from hv_driver.dialects import IsegEdcp, Keithley2290, PetaPicoVoltron
from hv_driver.link import Link

KEITHLEY, PPV = Keithley2290(), PetaPicoVoltron()
CONFIG = ChannelConfig("leg", 0, max_voltage_v=3000.0, slew_rate_v_per_s=1000.0, current_trip_a=50e-6)


def device_on(port, dialect) -> Device:
    device = Device("scripted", None, dialect, [CONFIG], reply_timeout=0.02)
    device.link = Link(port, dialect, 0.02)
    return device


def test_keithley_open_sequence_without_echo_and_unanswered_settings(scripted_port):
    port = scripted_port([
        (b"*IDN?\n", b"KEITHLEY INSTRUMENTS INC.,MODEL 2290-5,1234567,1.0\n"),
        (b"VSET 0\n", b""), (b"HVOF\n", b""),
        (b"ILIM 4.5e-05\n", b""),         # 0.9 x the host trip: the device limits first, in hardware
        (b"VLIM 3000\n", b""),            # the channel's hard maximum as the device's own limit
        (b"ILIM?\n", b"4.5000e-05\r\n"),  # a CR before the LF is tolerated
        (b"VLIM?\n", b"3000.0\n"),
        (b"*STB?\n", b"0\n"), (b"VOUT?\n", b"+0.0\n"),
    ])
    device = device_on(port, KEITHLEY)
    assert device.identify("2290").startswith("KEITHLEY")
    device.switch_all_off()
    assert device.configure()["leg"].voltage_limit == 3000.0
    voltage, report = device.found()["leg"]
    assert voltage == 0.0 and not report.output_on


def test_keithley_cut_is_output_off_then_zero_and_readback_decodes_the_status_byte(scripted_port):
    port = scripted_port([
        (b"HVOF\n", b""), (b"VSET 0\n", b""),
        (b"VOUT?\n", b"+12.5V\n"), (b"IOUT?\n", b"2.0e-03\n"), (b"*STB?\n", b"132\n"),  # HV on + current trip
    ])
    device = device_on(port, KEITHLEY)
    device.cut([CONFIG])
    reading = device.read()["leg"]
    assert (reading.voltage, reading.current) == (12.5, 2e-3)
    assert reading.report.over_current and reading.report.output_on


@pytest.mark.parametrize("dialect, operation, field, expected", [
    (IsegEdcp(), "measure_voltage", "1.2E3V", 1200.0),       # iseg: the unit always follows the digits
    (IsegEdcp(), "measure_voltage", "1.2E3", None),
    (IsegEdcp(), "measure_voltage", "1.2E3 V", None),
    (KEITHLEY, "measure_voltage", "+12.5V", 12.5),           # Keithley: the unit may follow, in either case,
    (KEITHLEY, "measure_voltage", "+12.5 v", 12.5),          # after spaces, or be left out
    (KEITHLEY, "measure_current", "2.0e-03", 2e-3),
    (KEITHLEY, "measure_current", "2.0e-03V", None),
    (PPV, "set_voltage", "600", 600.0),                      # PPV: plain decimals, no exponent, no unit
    (PPV, "set_voltage", "6e2", None),
    (KEITHLEY, "read_status", "132", 132),                   # registers are non-negative integers everywhere
    (PPV, "read_switching_mode", "-1", None),
])
def test_each_dialect_reads_numbers_by_its_own_unit_and_digit_rules(dialect, operation, field, expected):
    command = dialect.commands[operation]
    if expected is None:
        with pytest.raises(ProtocolError, match=operation):
            dialect.parse_number(field, command, operation)
    else:
        value = dialect.parse_number(field, command, operation)
        assert value == expected and type(value) is type(expected)


@pytest.mark.parametrize("reply, problem", [(b"ERR\n", "number in V"), (b"1.2.3\n", "number in V"),
                                            (b"\n", "number in V")])
def test_keithley_garbage_is_a_protocol_error(scripted_port, reply, problem):
    port = scripted_port([(b"VOUT?\n", reply)])
    with pytest.raises(ProtocolError, match=problem):
        Link(port, KEITHLEY, 0.02).query("measure_voltage")


def test_ppv_open_sequence_cr_commands_crlf_answers_values_answered_back(scripted_port):
    port = scripted_port([
        (b"QVer\r", b"slave 8\r\n"),
        (b"SVset 0\r", b"0\r\n"), (b"SSwMode 0\r", b"0\r\n"),
        (b"SSwSrc 0\r", b"0\r\n"), (b"SVMode 0\r", b"0\r\n"),  # onboard timer, regulated: as the library does
        (b"QVmax\r", b"5000\r\n"),                            # no ramp, no current trip to configure
        (b"QSwMode\r", b"0\r\n"), (b"QVnow\r", b"3\r\n"),
    ])
    device = device_on(port, PPV)
    assert device.identify("") == "slave 8"
    device.switch_all_off()
    side = device.configure()["leg"]
    assert side.voltage_limit == 5000.0 and side.ramp_rate_v_per_s is None
    voltage, report = device.found()["leg"]
    assert voltage == 3.0 and not report.output_on


def test_ppv_reads_no_current_and_a_setpoint_answered_otherwise_is_refused(scripted_port):
    port = scripted_port([
        (b"QVnow\r", b"598\r\n"), (b"QSwMode\r", b"2\r\n"),
        (b"SVset 600\r", b"599\r\n"),
    ])
    device = device_on(port, PPV)
    reading = device.read()["leg"]
    assert reading.current is None and reading.report.switching and reading.report.output_on
    with pytest.raises(ProtocolError, match=r"sent 'SVset 600', the device answered '599'"):
        device.query("set_voltage", [0], 600.0)


def test_ppv_refuses_a_multi_channel_master_board(scripted_port):
    port = scripted_port([(b"QVer\r", b"master 8\r\n")])
    with pytest.raises(ConfigurationError, match="single-channel board"):
        device_on(port, PPV).identify("")


def test_ppv_silence_after_a_command_is_a_link_error(scripted_port):
    port = scripted_port([(b"QVnow\r", b"59")])
    with pytest.raises(LinkError, match=r"partial reply b'59'"):
        Link(port, PPV, 0.02).query("measure_voltage")
    port.buffer.clear()


# The silence case, scripted: the cut goes out while the device reads nothing, then its readback still shows the
# output on at 600 V; later it reports the output off. dialect -> (cut lines and what a deaf device answers to
# them, the readback while on, the readback once off).
SILENT_CUT = {
    "keithley-2290": (Keithley2290(), [(b"HVOF\n", b""), (b"VSET 0\n", b"")],
                      [(b"VOUT?\n", b"+600.0\n"), (b"IOUT?\n", b"1.0e-08\n"), (b"*STB?\n", b"129\n")],
                      [(b"VOUT?\n", b"+0.0\n"), (b"IOUT?\n", b"0.0e+00\n"), (b"*STB?\n", b"0\n")]),
    "ppv": (PetaPicoVoltron(), [(b"SSwMode 0\r", b"")],
            [(b"QVnow\r", b"600\r\n"), (b"QSwMode\r", b"1\r\n")],
            [(b"QVnow\r", b"0\r\n"), (b"QSwMode\r", b"0\r\n")]),
    "iseg-edcp": (IsegEdcp(), [(b":VOLT EMCY OFF,(@0);*OPC?\r\n", b"")],
                  [(b":MEAS:VOLT? (@0)\r\n", b":MEAS:VOLT? (@0)\r\n6.00000E2V\r\n"),
                   (b":MEAS:CURR? (@0)\r\n", b":MEAS:CURR? (@0)\r\n1.00000E-8A\r\n"),
                   (b":READ:CHAN:STATUS? (@0)\r\n", b":READ:CHAN:STATUS? (@0)\r\n137\r\n"),  # IS_ON
                   (b":READ:CHAN:EVENT:STATUS? (@0)\r\n", b":READ:CHAN:EVENT:STATUS? (@0)\r\n0\r\n")],
                  [(b":MEAS:VOLT? (@0)\r\n", b":MEAS:VOLT? (@0)\r\n0.00000E0V\r\n"),
                   (b":MEAS:CURR? (@0)\r\n", b":MEAS:CURR? (@0)\r\n0.00000E0A\r\n"),
                   (b":READ:CHAN:STATUS? (@0)\r\n", b":READ:CHAN:STATUS? (@0)\r\n1\r\n"),  # off
                   (b":READ:CHAN:EVENT:STATUS? (@0)\r\n", b":READ:CHAN:EVENT:STATUS? (@0)\r\n0\r\n")]),
}


@pytest.mark.parametrize("name", list(SILENT_CUT))
def test_a_cut_into_silence_counts_only_once_the_device_reports_the_output_off(scripted_port, name):
    dialect, cut, still_on, off = SILENT_CUT[name]
    port = scripted_port(cut + still_on + off)
    device = device_on(port, dialect)
    try:
        device.cut([CONFIG])
    except LinkError:  # a setting's answer never came (iseg, PPV)
        assert name != "keithley-2290"  # only the 2290 takes a cut into silence without an error
    assert device.sent["leg"].emergency and not device.sent["leg"].cut_confirmed
    reading = device.read()["leg"]
    assert reading.voltage == 600.0 and reading.report.output_on
    assert device.confirm_cut(CONFIG, reading)  # on after the cut: CUT_UNCONFIRMED for the driver, cut again
    assert device.unconfirmed_cuts({"leg"}) == [CONFIG]
    assert not device.confirm_cut(CONFIG, device.read()["leg"])  # reported off: confirmed
    assert device.unconfirmed_cuts({"leg"}) == []


def test_a_cut_behind_a_failed_exchange_is_written_at_once_without_waiting_for_the_line_to_fall_quiet(
        scripted_port):
    port = scripted_port([(b"VOUT?\n", b""), (b"HVOF\n", b""), (b"VSET 0\n", b"")])
    device = device_on(port, KEITHLEY)
    with pytest.raises(LinkError):
        device.query("measure_voltage", [0])
    device.cut([CONFIG])
    assert port.flushed == 0  # no resynchronisation (which would wait a reply timeout of quiet) before the cut
    assert device.link.stale  # the next exchange resynchronises, discarding whatever the cut's lines drew
