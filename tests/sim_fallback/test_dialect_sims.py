"""The Keithley 2290 and Peta-pico-Voltron simulators through their command sets, in simulated time over an
in-memory link: the PPV against the command set of its own interface library (what it sends on connect and in use,
as the note describes it), the Keithley's unanswered settings, the boards' own switching and cycle count. On real
ptys: test_dialect_sims_pty.py."""
import pytest
from ppv_wire import ppv_exchange

from hv_driver.clock import SimulatedClock
from sim_fallback.keithley_supply import SimulatedKeithley2290
from sim_fallback.memory_port import MemoryPort
from sim_fallback.ppv_supply import SimulatedPpv

pytestmark = pytest.mark.fast


@pytest.fixture
def clock():
    return SimulatedClock()


@pytest.fixture
def ppv(clock):
    sim = SimulatedPpv(clock=clock)
    return sim, MemoryPort(sim)


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
    link = MemoryPort(sim)
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
