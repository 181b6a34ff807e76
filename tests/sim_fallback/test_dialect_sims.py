"""The Keithley 2290 and Peta-pico-Voltron simulators on the wire: the PPV against the command set of its own
interface library (what it sends on connect and in use, as the note describes it), the Keithley's unanswered
settings, the boards' own switching and cycle count (in simulated time, over an in-memory link), and the rig process
with several devices (real ptys, real time)."""
import time

import pytest
import serial

from hv_driver.clock import SimulatedClock
from sim_fallback.hv_supply_process import SimulatedSupplyProcess
from sim_fallback.keithley_supply import SimulatedKeithley2290
from sim_fallback.memory_port import MemoryPort
from sim_fallback.ppv_supply import SimulatedPpv


class Wire:
    """The host's end of an in-memory link to a simulator on a simulated clock: write lines, read answer lines."""

    def __init__(self, sim):
        self.port = MemoryPort(sim)

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def read(self, size: int) -> bytes:
        return self.port.read(size)

    def readline(self) -> bytes:
        line = b""
        while not line.endswith(b"\n") and (chunk := self.port.read(1)):
            line += chunk
        return line


def ppv_exchange(link, line: str) -> str:
    """As the reference library: write ``line`` + CR, read one line, drop its CR LF."""
    link.write(line.encode() + b"\r")
    answer = link.readline()
    assert answer.endswith(b"\r\n"), answer
    return answer[:-2].decode()


@pytest.fixture
def clock():
    return SimulatedClock()


@pytest.fixture
def ppv(clock):
    sim = SimulatedPpv(clock=clock)
    return sim, Wire(sim)


def test_ppv_answers_the_reference_librarys_connect_sequence(ppv):
    sim, link = ppv
    queries = {"QPowJack": "1", "QVer": "slave 8", "QJack": "1", "QName": "PPV-SIM", "QVmax": "5000", "QI2C": "0",
               "QF": "1.000", "QLatchMode": "0", "QStMode": "0", "QStPos": "0", "QStDur": "0"}
    for query, expected in queries.items():
        assert ppv_exchange(link, query) == expected, query
    # On connect over USB the library sets Vset 0, DC mode, timer source, regulated mode, 0 cycles; each setting
    # answers the value now in force.
    for setting, expected in (("SStSw 5000", "5000"), ("SVset 0", "0"), ("SSwMode 1", "1"), ("SSwSrc 0", "0"),
                              ("SVMode 0", "0"), ("SCycle 0", "0")):
        assert ppv_exchange(link, setting) == expected, setting
    assert len(ppv_exchange(link, "QMem").split(",")) == 13
    assert ppv_exchange(link, "Save") == "1"


def test_ppv_answers_on_a_real_pty():
    """Integration: the simulated board serving a real pty in real time."""
    with SimulatedPpv() as sim:
        with serial.serial_for_url(sim.port, baudrate=115200, timeout=1.0) as link:
            assert ppv_exchange(link, "QVer") == "slave 8" and ppv_exchange(link, "SVset 600") == "600"


def test_ppv_dc_output_regulates_without_ramp_and_has_no_current_command(ppv, clock):
    sim, link = ppv
    assert ppv_exchange(link, "SSwMode 1") == "1"
    assert ppv_exchange(link, "SVset 600") == "600"
    assert ppv_exchange(link, "SVset 9000") == "5000"  # held at the rating, and answered so
    assert ppv_exchange(link, "SVset 600") == "600"
    clock.advance(0.1)  # 20 of its 5 ms regulation time constants
    assert abs(int(ppv_exchange(link, "QVnow")) - 600) <= 1
    assert ppv_exchange(link, "QVset") == "600"
    assert ppv_exchange(link, "QI") == "?"  # no current readback
    assert ppv_exchange(link, "SSwMode 0") == "0"
    clock.advance(0.2)  # ten 20 ms discharge time constants
    assert int(ppv_exchange(link, "QVnow")) < 10


def test_ppv_switches_by_itself_for_the_counted_cycles_then_switches_off(ppv, clock):
    sim, link = ppv
    assert ppv_exchange(link, "SVset 600") == "600"
    assert ppv_exchange(link, "SF 5") == "5.000"
    assert ppv_exchange(link, "SCycle 3") == "3"
    sim.watch(0, 300.0)
    assert ppv_exchange(link, "SSwMode 2") == "2"
    clock.advance(0.3)
    assert ppv_exchange(link, "QSwMode") == "2" and ppv_exchange(link, "QCycle") == "1/3"
    clock.advance(0.5)
    # Its count is over: back to off, and the count answers all cycles done.
    assert ppv_exchange(link, "QSwMode") == "0" and ppv_exchange(link, "QCycle") == "3/3"
    edges = sim.edges(0)
    assert len(edges) == 3 and max(abs(b - a - 0.2) for a, b in zip(edges, edges[1:])) < 1e-9


def test_keithley_settings_are_not_answered_and_queries_are(clock):
    sim = SimulatedKeithley2290(clock=clock)
    link = Wire(sim)
    for line in (b"VLIM 3000\n", b"ILIM 0.001\n", b"VSET 1200\n", b"HVON\n", b"FOO 1\n"):
        link.write(line)
    assert link.read(1) == b""  # nothing came back, not even for the line it cannot execute
    link.write(b"*IDN?\n")
    assert link.readline().startswith(b"KEITHLEY INSTRUMENTS INC.,MODEL 2290-5")
    clock.advance(0.1)  # ten of its 10 ms regulation time constants
    link.write(b"VOUT?\n*STB?\nILIM?\n")
    assert float(link.readline()) == pytest.approx(1200.0, abs=1.0)
    assert int(link.readline()) & 0x80  # HV on
    assert float(link.readline()) == pytest.approx(1e-3)


def test_a_rig_process_serves_several_boards_each_on_its_own_port():
    with SimulatedSupplyProcess(dialect="ppv", devices=2) as rig:
        assert len(rig.ports) == 2 and rig.ports[0] != rig.ports[1]
        rig.watch(0, 100.0, device=1)
        with serial.serial_for_url(rig.ports[1], timeout=1.0) as link:
            for line in ("SVset 200", "SF 20", "SCycle 4", "SSwMode 2"):
                ppv_exchange(link, line)
            deadline = time.monotonic() + 10.0  # a generous deadline for the board's own count to end
            while ppv_exchange(link, "QSwMode") != "0" and time.monotonic() < deadline:
                time.sleep(0.02)
            assert ppv_exchange(link, "QCycle") == "4/4"
        assert len(rig.edges(0, device=1)) == 4 and rig.edges(0, device=0) == []
        rig.inject("over_current", 0, device=1)
        with pytest.raises(ValueError, match="device=5: between 0 and 1"):
            rig.inject("over_current", 0, device=5)
