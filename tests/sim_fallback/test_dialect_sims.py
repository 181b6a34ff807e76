"""The Keithley 2290 and Peta-pico-Voltron simulators on the wire: the PPV against the command set of its own
interface library (what it sends on connect and in use, as the note describes it), the Keithley's unanswered
settings, the boards' own switching and cycle count, and the rig process with several devices."""
import time

import pytest
import serial

from sim_fallback.hv_supply_process import SimulatedSupplyProcess
from sim_fallback.keithley_supply import SimulatedKeithley2290
from sim_fallback.ppv_supply import SimulatedPpv

pytestmark = pytest.mark.integration


def ppv_exchange(link, line: str) -> str:
    """As the reference library: write ``line`` + CR, read one line, drop its CR LF."""
    link.write(line.encode() + b"\r")
    answer = link.readline()
    assert answer.endswith(b"\r\n"), answer
    return answer[:-2].decode()


@pytest.fixture
def ppv():
    with SimulatedPpv() as sim:
        with serial.serial_for_url(sim.port, baudrate=115200, timeout=1.0) as link:
            yield sim, link


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


def test_ppv_dc_output_regulates_without_ramp_and_has_no_current_command(ppv):
    sim, link = ppv
    assert ppv_exchange(link, "SSwMode 1") == "1"
    assert ppv_exchange(link, "SVset 600") == "600"
    assert ppv_exchange(link, "SVset 9000") == "5000"  # held at the rating, and answered so
    assert ppv_exchange(link, "SVset 600") == "600"
    time.sleep(0.1)
    assert abs(int(ppv_exchange(link, "QVnow")) - 600) <= 1
    assert ppv_exchange(link, "QVset") == "600"
    assert ppv_exchange(link, "QI") == "?"  # no current readback
    assert ppv_exchange(link, "SSwMode 0") == "0"
    time.sleep(0.2)
    assert int(ppv_exchange(link, "QVnow")) < 10


def test_ppv_switches_by_itself_for_the_counted_cycles_then_switches_off(ppv):
    sim, link = ppv
    assert ppv_exchange(link, "SVset 600") == "600"
    assert ppv_exchange(link, "SF 5") == "5.000"
    assert ppv_exchange(link, "SCycle 3") == "3"
    sim.watch(0, 300.0)
    assert ppv_exchange(link, "SSwMode 2") == "2"
    time.sleep(0.3)
    assert ppv_exchange(link, "QSwMode") == "2" and ppv_exchange(link, "QCycle").endswith("/3")
    time.sleep(0.5)
    assert ppv_exchange(link, "QSwMode") == "0" and ppv_exchange(link, "QCycle") == "0/3"
    edges = sim.edges(0)
    assert len(edges) == 3 and max(abs(b - a - 0.2) for a, b in zip(edges, edges[1:])) < 1e-3


def test_keithley_settings_are_not_answered_and_queries_are():
    with SimulatedKeithley2290() as sim:
        with serial.serial_for_url(sim.port, timeout=0.3) as link:
            for line in (b"VLIM 3000\n", b"ILIM 0.001\n", b"VSET 1200\n", b"HVON\n", b"FOO 1\n"):
                link.write(line)
            assert link.read(1) == b""  # nothing came back, not even for the line it cannot execute
            link.write(b"*IDN?\n")
            assert link.readline().startswith(b"KEITHLEY INSTRUMENTS INC.,MODEL 2290-5")
            time.sleep(0.1)
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
            time.sleep(0.4)
        assert len(rig.edges(0, device=1)) == 4 and rig.edges(0, device=0) == []
        rig.inject("over_current", 0, device=1)
        with pytest.raises(ValueError, match="device=5: between 0 and 1"):
            rig.inject("over_current", 0, device=5)
