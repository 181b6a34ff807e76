"""iseg EDCP dialect and line framing against scripted exchanges, garbage, partial lines, wrong echoes."""
from dataclasses import replace

import pytest
import serial

from hv_driver import IsegEdcp, LinkError, ProtocolError
from hv_driver.dialects import Command, Dialect, Keithley2290
from hv_driver.dialects.iseg_edcp import ChannelEvent, ChannelStatus
from hv_driver.clock import SimulatedClock
from hv_driver.link import Link

pytestmark = pytest.mark.fast

EDCP = IsegEdcp()


def link_for(port, reply_timeout=0.02):
    return Link(port, EDCP, reply_timeout)


def echoed(line: str, *answers: str) -> bytes:
    return (line + "\r\n" + "".join(a + "\r\n" for a in answers)).encode()


def test_settings_are_formatted_in_exponent_notation_and_acknowledged():
    assert EDCP.encode("set_voltage", [0], 1200.0) == ":VOLT 1.200000E+03,(@0);*OPC?"
    assert EDCP.encode("output_on", [1]) == ":VOLT ON,(@1);*OPC?"
    assert EDCP.encode("emergency_off", [0, 1]) == ":VOLT EMCY OFF,(@0,1);*OPC?"
    assert EDCP.encode("measure_current", [0, 1]) == ":MEAS:CURR? (@0,1)"
    with pytest.raises(ValueError, match="needs a value"):
        EDCP.encode("set_voltage", [0])


@pytest.mark.parametrize("reply, expected", [
    ("1.20000E+03V", [1200.0]), ("1.2E3V", [1200.0]), ("-5.00000E-09V", [-5e-9]), ("0V", [0.0]),
])
def test_numbers_with_unit_are_parsed(reply, expected):
    assert EDCP.decode("measure_voltage", reply) == expected


def test_several_channels_answer_comma_separated():
    assert EDCP.decode("measure_current", "1.0E-6A,2.5E-9A", 2) == [1e-6, 2.5e-9]
    assert EDCP.decode("read_status", "137,1", 2) == [137, 1]


@pytest.mark.parametrize("operation, reply, count, problem", [
    ("measure_voltage", "1.2E3", 1, "number in V"),           # unit missing
    ("measure_voltage", "1.2E3A", 1, "number in V"),          # wrong unit
    ("measure_voltage", "V", 1, "number in V"),
    ("measure_voltage", "1.2E3V", 2, "expected 2 value"),     # one channel missing
    ("measure_current", "1e-6A,,2e-6A", 2, "expected 2 value"),
    ("read_status", "13x", 1, "integer"),
    ("read_status", "-1", 1, "integer"),
    ("set_voltage", "?", 1, "acknowledgement"),
    ("set_voltage", "", 1, "acknowledgement"),
    ("identify", "", 1, "unreadable"),
    ("identify", "iseg\x07", 1, "unreadable"),
])
def test_garbage_replies_are_rejected_naming_the_operation(operation, reply, count, problem):
    with pytest.raises(ProtocolError, match=problem) as error:
        EDCP.decode(operation, reply, count)
    assert operation in str(error.value)


def test_status_and_event_registers_map_to_output_and_fault_flags():
    running = ChannelStatus.IS_POSITIVE | ChannelStatus.IS_ON | ChannelStatus.IS_VOLTAGE_RAMP
    on = EDCP.status_report(int(running), int(ChannelEvent.EVENT_END_OF_RAMP | ChannelEvent.EVENT_ON_TO_OFF))
    assert on.output_on and on.ramping and not on.over_current and on.fault is None
    tripped = EDCP.status_report(int(ChannelStatus.IS_CURRENT_TRIP), 0)
    assert tripped.over_current and not tripped.output_on
    arc_between_polls = EDCP.status_report(int(running), int(ChannelEvent.EVENT_ARC))
    assert arc_between_polls.over_current and arc_between_polls.output_on
    inhibited = EDCP.status_report(int(ChannelStatus.IS_EXTERNAL_INHIBIT | ChannelStatus.IS_EMERGENCY_OFF),
                                   int(ChannelEvent.EVENT_VOLTAGE_LIMIT))
    assert inhibited.fault == "supply reports is_emergency_off, is_external_inhibit, event_voltage_limit"


def test_a_dialect_must_define_every_operation_its_capabilities_need():
    with pytest.raises(TypeError, match=r"lacks operations \['set_ramp_up', 'set_ramp_down', 'read_ramp'\]"):
        class NoRampCommands(Dialect):  # noqa: F841 (declares a device ramp but has no commands for it)
            capabilities = replace(IsegEdcp.capabilities)
            commands = {op: c for op, c in IsegEdcp.commands.items() if "ramp" not in op}
    host_ramped = replace(IsegEdcp.capabilities, device_ramp=False)

    class HostRamped(Dialect):  # the same table without ramp commands is fine once the host ramps
        capabilities = host_ramped
        commands = {op: c for op, c in IsegEdcp.commands.items() if "ramp" not in op}
    assert "read_ramp" not in HostRamped.capabilities.required_operations()


def test_scripted_exchanges_with_echo(scripted_port):
    port = scripted_port([
        (b"*IDN?\r\n", echoed("*IDN?", "iseg Spezialelektronik GmbH,NHR 42 50r,1,1.0")),
        (b":VOLT 2.400000E+03,(@1);*OPC?\r\n", echoed(":VOLT 2.400000E+03,(@1);*OPC?", "1")),
        (b":MEAS:VOLT? (@0,1)\r\n", echoed(":MEAS:VOLT? (@0,1)", "0.00000E+00V,2.39990E+03V")),
    ])
    link = link_for(port)
    assert link.query("identify").startswith("iseg")
    assert link.query("set_voltage", [1], 2400.0) is None
    assert link.query("measure_voltage", [0, 1]) == [0.0, 2399.9]


def test_reply_split_over_reads_is_reassembled(scripted_port):
    class Trickle:  # delivers one byte per read
        def __init__(self, port):
            self.port = port
            self.write, self.reset_input_buffer = port.write, port.reset_input_buffer
        in_waiting = 0

        def read(self, size):
            return self.port.read(1)
    port = scripted_port([(b"*IDN?\r\n", echoed("*IDN?", "iseg,NHR,1,1.0"))])
    assert Link(Trickle(port), EDCP, 0.5).query("identify") == "iseg,NHR,1,1.0"


def test_a_reply_that_arrived_while_the_host_was_descheduled_past_the_deadline_is_read(scripted_port):
    port = scripted_port([(b"*IDN?\r\n", echoed("*IDN?", "iseg,NHR,1,1.0"))])
    link = link_for(port, reply_timeout=0.02)

    class Descheduled(SimulatedClock):  # the deadline is set at 100.0; every later look is 0.5 s on
        looks = 0

        def __call__(self):
            self.looks += 1
            return 100.0 if self.looks == 1 else 100.5
    link.clock = Descheduled()
    assert link.query("identify") == "iseg,NHR,1,1.0"


def test_wrong_echo_is_a_protocol_error_and_the_stale_input_is_discarded(scripted_port):
    port = scripted_port([
        (b":MEAS:CURR? (@0)\r\n", echoed(":MEAS:VOLT? (@0)", "1.0E-6A") + b"late garbage\r\n"),
        (b":MEAS:CURR? (@0)\r\n", echoed(":MEAS:CURR? (@0)", "2.0E-6A")),
    ])
    link = link_for(port)
    with pytest.raises(ProtocolError, match="wrong echo"):
        link.query("measure_current", [0])
    assert link.query("measure_current", [0]) == [2e-6]
    assert port.flushed == 1


def test_partial_reply_times_out_as_a_link_error(scripted_port):
    port = scripted_port([(b":MEAS:VOLT? (@0)\r\n", b":MEAS:VOLT? (@0)\r\n1.2E")])
    with pytest.raises(LinkError, match=r"partial reply b'1.2E'"):
        link_for(port).query("measure_voltage", [0])
    port.buffer.clear()


def test_missing_reply_is_a_link_error(scripted_port):
    port = scripted_port([(b"*IDN?\r\n", b"")])
    with pytest.raises(LinkError, match="no reply"):
        link_for(port).query("identify")


def test_missing_answer_after_echo_is_a_link_error(scripted_port):
    port = scripted_port([(b"*IDN?\r\n", b"*IDN?\r\n")])
    with pytest.raises(LinkError, match="no reply"):
        link_for(port).query("identify")


def test_non_ascii_and_endless_lines_are_protocol_errors(scripted_port):
    port = scripted_port([
        (b"*IDN?\r\n", b"*IDN?\r\n\xff\xfe\r\n"),
        (b"*IDN?\r\n", b"x" * 400),
    ])
    link = link_for(port)
    with pytest.raises(ProtocolError, match="non-ASCII"):
        link.query("identify")
    with pytest.raises(ProtocolError, match="without terminator"):
        link.query("identify")
    port.buffer.clear()


def test_port_failure_is_a_link_error(scripted_port):
    port = scripted_port([(b"*IDN?\r\n", serial.SerialException("device disconnected"))])
    with pytest.raises(LinkError, match="device disconnected"):
        link_for(port).query("identify")


class LatePort:
    """A port whose device answers a write marked late only after the host gave up on it and flushed its
    input (as a device descheduled past the reply timeout would), the others at once; ``noisy``: the line
    never falls quiet after that flush. Runs on ``clock`` (simulated): each read takes READ_S on the wire."""

    READ_S = 0.001

    def __init__(self, exchanges, clock: SimulatedClock, noisy=False):
        self.exchanges = list(exchanges)  # (sent, reply, late)
        self.clock = clock
        self.held = bytearray()
        self.buffer = bytearray()
        self.flushed = False
        self.noisy = noisy

    def write(self, data: bytes) -> int:
        sent, reply, late = self.exchanges.pop(0)
        assert data == sent, f"wrote {data!r}, script expects {sent!r}"
        (self.held if late else self.buffer).extend(reply)
        return len(data)

    @property
    def in_waiting(self) -> int:
        if self.flushed:
            self.buffer[:0], self.held = self.held, bytearray()  # the late answer comes before anything newer
            if self.noisy:
                self.buffer += b"noise\n"
        return len(self.buffer)

    def read(self, size: int = 1) -> bytes:
        self.clock.advance(self.READ_S)
        chunk = bytes(self.buffer[:size])
        del self.buffer[:size]
        return chunk

    def reset_input_buffer(self) -> None:
        self.buffer.clear()
        self.flushed = True


@pytest.mark.parametrize("dialect, first, second, late_answer, answer", [
    (Keithley2290(), b"VOUT?\n", b"IOUT?\n", b"+2400.0\n", b"2.0e-06\n"),
    (EDCP, b":MEAS:VOLT? (@0)\r\n", b":MEAS:CURR? (@0)\r\n", echoed(":MEAS:VOLT? (@0)", "2.4E+03V"),
     echoed(":MEAS:CURR? (@0)", "2.0E-6A")),
])
def test_an_answer_that_comes_after_the_timeout_is_not_taken_for_the_next_commands(dialect, first, second,
                                                                                     late_answer, answer):
    """The late answer to a voltage query arrives after the host gave up and moved on: without
    resynchronising, a device without echo had its 2400 V read as 2400 A (and one with echo failed on the
    echo, a false link fault)."""
    clock = SimulatedClock()
    port = LatePort([(first, late_answer, True), (second, answer, False)], clock)
    link = Link(port, dialect, 0.02, clock)
    with pytest.raises(LinkError, match="no reply"):
        link.query("measure_voltage", [0])
    assert link.query("measure_current", [0]) == [2e-6]
    assert not port.held and not port.buffer


def test_a_device_that_keeps_sending_after_a_failure_is_a_link_error():
    clock = SimulatedClock()
    port = LatePort([(b"VOUT?\n", b"", True)], clock, noisy=True)
    link = Link(port, Keithley2290(), 0.02, clock)
    with pytest.raises(LinkError, match="no reply"):
        link.query("measure_voltage", [0])
    with pytest.raises(LinkError, match="kept sending"):
        link.query("measure_current", [0])
