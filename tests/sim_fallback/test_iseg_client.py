"""The simulated iseg supply against an independent client: the PyPI package iseg-nhr 0.2.0, written against the
NHR. Every operation of it the simulator supports, through the client's own serial transport (which sends
``cmd\\r\\n``, expects the echo, reads one more line for a query and only the echo for a setting). Its emergency
off sends ``EMCY_OFF`` with an underscore, a bug of that client: emergency off is tested with the documented
spelling ``:VOLT EMCY OFF``."""
import pytest
from iseg_nhr import NHR
from iseg_nhr.register import ChannelEventRegister, ChannelStatusRegister
from iseg_nhr.transport import SerialTransport
from waiting import GENEROUS_S, wait_until

from sim_fallback.hv_supply import FIRMWARE_NAME, FIRMWARE_RELEASE, IDENTITY, NOMINAL_CURRENT, SimulatedSupply

pytestmark = pytest.mark.integration


@pytest.fixture
def sim():
    with SimulatedSupply(channels=4) as device:
        yield device


@pytest.fixture
def nhr(sim):
    with NHR(sim.port, timeout=GENEROUS_S) as client:  # asks :READ:MOD:CHAN? at construction
        yield client


def test_module_identity_and_common_commands(nhr, sim):
    assert nhr.number_channels == 4
    assert nhr.identity == IDENTITY
    assert nhr.instruction_set == "EDCP"
    assert (nhr.firmware_version, nhr.firmware_release) == (FIRMWARE_NAME, FIRMWARE_RELEASE)
    assert nhr.operation_complete
    nhr.lockout()
    assert sim.locked_out
    nhr.local()
    assert not sim.locked_out
    nhr.status_clear()


def test_setpoint_ramp_and_output(nhr, sim):
    channel = nhr.channel1
    channel.voltage.ramp.speed = 500.0  # :CONF:RAMP:VOLT, both directions
    assert channel.voltage.ramp.speed_up == channel.voltage.ramp.speed_down == 500.0
    assert channel.voltage.ramp.speed == 500.0
    channel.voltage.ramp.speed_down = 250.0
    assert (channel.voltage.ramp.speed_up, channel.voltage.ramp.speed_down) == (500.0, 250.0)
    channel.voltage.setpoint = 100.0
    assert channel.voltage.setpoint == 100.0  # :READ:VOLT? is the setpoint
    assert not channel.on_state
    channel.on()
    assert channel.on_state and ChannelStatusRegister.IsOn in channel.status_register
    wait_until(lambda: abs(channel.voltage.measured - 100.0) < 1.0, "the output at 100 V")
    assert sim.plant[1].voltage == pytest.approx(100.0, abs=1.0) and sim.plant[0].voltage == 0.0
    assert nhr.voltages[1] == pytest.approx(100.0, abs=1.0)
    channel.off()  # :VOLT OFF ramps down at the configured ramp-down speed
    assert not channel.on_state
    wait_until(lambda: channel.voltage.measured < 1.0, "the output ramped down")


def test_limits_and_nominal_values(nhr):
    channel = nhr.channel0
    assert channel.voltage.limit == channel.voltage.maximum == 5000.0
    assert channel.current.limit == channel.current.maximum == NOMINAL_CURRENT
    assert channel.current.measured == pytest.approx(0.0, abs=1e-9)
    channel.voltage.bounds = 10.0
    channel.current.bounds = 1e-6
    assert (channel.voltage.bounds, channel.current.bounds) == (10.0, 1e-6)


def test_emergency_off_and_clear_with_the_documented_spelling(nhr, sim):
    channel = nhr.channel2
    channel.voltage.setpoint = 200.0
    channel.on()
    wait_until(lambda: channel.voltage.measured > 150.0, "the output above 150 V")
    channel._write(":VOLT EMCY OFF")
    assert channel.emergency and not channel.on_state
    assert ChannelStatusRegister.IsEmergencyOff in channel.status_register
    assert ChannelEventRegister.EmergencyOff in channel.event_register
    channel._write(":VOLT EMCY CLR")
    assert not channel.emergency
    channel.event_clear()  # :EV CLEAR
    assert channel.event_register == ()
    channel.on()
    channel.emergency_off()  # the client's EMCY_OFF is not the dialect: answered "?" (the client reads only the echo)
    assert channel.on_state and not channel.emergency


def test_a_setting_leaves_no_extra_line_for_a_client_that_does_not_flush(sim):
    transport = SerialTransport(sim.port, timeout=GENEROUS_S, clear_input_before_write=False)
    try:
        for _ in range(3):
            assert transport.query(":VOLT 50,(@0)") == ":VOLT 50,(@0)"  # the echo is the whole answer
            assert transport.query(":READ:VOLT? (@0)") == ":READ:VOLT? (@0)"
            assert transport.read() == "5.00000E+01V"
    finally:
        transport.close()


def test_long_and_short_keyword_forms_reach_the_same_command(sim):
    transport = SerialTransport(sim.port, timeout=GENEROUS_S)
    try:
        for long, short in ((":READ:CHAN:STATUS? (@0)", ":READ:CHAN:STAT? (@0)"),
                            (":READ:CHAN:EVENT:STATUS? (@0)", ":READ:CHAN:EV:STAT? (@0)")):
            answers = []
            for line in (long, short):
                assert transport.query(line) == line
                answers.append(transport.read())
            assert answers[0] == answers[1] and answers[0].isdigit()
        assert transport.query(":EVENT CLEAR,(@0)") == ":EVENT CLEAR,(@0)"
        assert transport.query(":EV CLEAR,(@0)") == ":EV CLEAR,(@0)"
    finally:
        transport.close()
