"""`hv_driver.probe`: the supply on a port identified by each dialect's identification query, and nothing else
ever sent. What was written is read back from pyserial's spy:// recording of the port and from the lines the
simulated supply received; its outputs are compared before and after."""
import os
import re
import tty

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hv_driver import DIALECTS, LinkError
from hv_driver.dialects import Command, IsegEdcp
from hv_driver.probe import probe, report
from sim_fallback.hv_supply import IDENTITY as ISEG_IDENTITY
from sim_fallback.hv_supply import SimulatedSupply
from sim_fallback.keithley_supply import IDENTITY as KEITHLEY_IDENTITY
from sim_fallback.keithley_supply import SimulatedKeithley2290
from sim_fallback.ppv_supply import FIRMWARE, SimulatedPpv

QUERIES = {"*IDN?", "QVer"}  # the identification queries of the three dialects
SUPPLIES = [(SimulatedSupply, "iseg-edcp", ISEG_IDENTITY), (SimulatedKeithley2290, "keithley-2290", KEITHLEY_IDENTITY),
            (SimulatedPpv, "ppv", f"slave {FIRMWARE}")]


def written_lines(spy_log) -> list[str]:
    """The lines a spy:// port wrote (its TX hex dump, joined and split at CR/LF), empty ones included."""
    sent = b"".join(bytes.fromhex(match) for match in re.findall(r"^\S+ TX\s+[0-9A-F]{4}  ((?:[0-9A-F]{2} )+)",
                                                                 spy_log.read_text(), re.M))
    return re.split(r"\r\n|\r|\n", sent.decode("ascii"))


def outputs(sim) -> list[tuple[float, bool]]:
    return [(channel.voltage_set, channel.output_on) for channel in sim.plant]


@pytest.mark.parametrize("supply, name, identity", SUPPLIES, ids=[name for _, name, _ in SUPPLIES])
def test_each_simulated_supply_is_identified_by_its_own_query_and_nothing_else_is_written(supply, name, identity,
                                                                                          tmp_path):
    spy = tmp_path / "spy.txt"
    with supply() as sim:
        sim.plant[0].voltage_set = 1234.0  # a setpoint left by an earlier session stays as it was
        before = outputs(sim)
        result = probe(f"spy://{sim.port}?file={spy}")
        received = [line.strip() for _, line in sim.command_log]
        assert outputs(sim) == before
    assert result.found is not None, report(result)
    assert (result.found.dialect, result.found.identity) == (name, identity)
    assert result.found.baudrate == DIALECTS[name].default_baudrate
    assert set(written_lines(spy)) <= QUERIES | {""}, written_lines(spy)
    assert set(received) <= QUERIES | {""}, received
    tried = [attempt.dialect for attempt in result.attempts]
    assert tried == list(DIALECTS)[:tried.index(name) + 1]  # in order, stopping at the one that answered
    text = report(result)
    assert f"found: {name}" in text and f"dialect: {name}" in text and "nothing is set" in text


def test_a_port_that_echoes_everything_back_is_no_supply(tmp_path):
    # A loopback plug: the iseg query's echo comes back but no answer, the Keithley query comes back as if it were
    # the identity, and the PPV's comes back without the CR LF that ends a PPV answer.
    result = probe("loop://", reply_timeout=0.2)
    assert result.found is None
    problems = {attempt.dialect: attempt.problem for attempt in result.attempts}
    assert list(problems) == list(DIALECTS)
    assert "no reply" in problems["iseg-edcp"]
    assert "echoed the query" in problems["keithley-2290"] and "partial reply b'QVer\\r'" in problems["ppv"]
    assert "no supply answered" in report(result)


def test_a_silent_port_is_tried_with_every_dialect_and_reported_as_no_supply():
    controller, device = os.openpty()
    tty.setraw(device)
    try:
        result = probe(os.ttyname(device), reply_timeout=0.2)
    finally:
        os.close(controller)
        os.close(device)
    assert result.found is None
    assert [(a.dialect, a.baudrate) for a in result.attempts] == [(n, d.default_baudrate) for n, d in DIALECTS.items()]
    assert all("no reply" in attempt.problem for attempt in result.attempts)


def test_a_port_that_cannot_be_opened_is_a_link_error_naming_it():
    with pytest.raises(LinkError, match="cannot open '/dev/no-such-port'"):
        probe("/dev/no-such-port")


def test_the_probe_refuses_a_dialect_whose_identification_is_not_a_text_query(monkeypatch):
    class Setting(IsegEdcp):
        name = "setting"
        commands = {**IsegEdcp.commands, "identify": Command(":VOLT {value},{channels}", "ack")}

    monkeypatch.setitem(DIALECTS, "setting", Setting)
    with pytest.raises(ValueError, match="not a text query; the probe sends nothing else"):
        probe("/dev/no-such-port", dialects=("setting",))  # refused before the port is opened


class ScriptedPort:
    """A pyserial-like port that answers every write with the next scripted chunk of bytes."""

    def __init__(self, replies):
        self.replies, self.written, self.pending, self.baudrate = list(replies), bytearray(), bytearray(), 9600

    def write(self, data):
        self.written += data
        if self.replies:
            self.pending += self.replies.pop(0)
        return len(data)

    @property
    def in_waiting(self):
        return len(self.pending)

    def read(self, size=1):
        chunk, self.pending[:] = bytes(self.pending[:size]), self.pending[size:]
        return chunk

    def reset_input_buffer(self):
        self.pending.clear()

    def close(self):
        pass


REPLY = st.one_of(st.binary(max_size=40), st.sampled_from([b"*IDN?\r\n", b"1\r\n", b"?\r\n", b"slave 8\r\n",
                                                           b"-1\r\n", b"KEITHLEY\n", b"*IDN?\r\nx\r\n"]))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(replies=st.lists(REPLY, max_size=8))
def test_whatever_a_device_answers_only_identification_queries_are_written(monkeypatch, replies):
    port = ScriptedPort(replies)
    monkeypatch.setattr("hv_driver.probe.serial.serial_for_url", lambda *args, **kwargs: port)
    result = probe("scripted", reply_timeout=0.01)
    lines = re.split(rb"\r\n|\r|\n", bytes(port.written))
    assert set(lines) <= {b"", b"*IDN?", b"QVer"}
    assert 1 <= len(result.attempts) <= len(DIALECTS)
    assert all(attempt.problem for attempt in result.attempts[:-1])  # it stops at the first that answered
