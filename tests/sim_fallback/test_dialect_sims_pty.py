"""The Peta-pico-Voltron simulator on real ptys: one board served in a thread, and the rig process with several
boards, each on its own port (their command sets in simulated time: test_dialect_sims.py)."""
import pytest
import serial
from ppv_wire import ppv_exchange
from waiting import GENEROUS_S, wait_until

from sim_fallback.hv_supply_process import SimulatedSupplyProcess
from sim_fallback.ppv_supply import SimulatedPpv

pytestmark = pytest.mark.integration


def test_ppv_answers_on_a_real_pty():
    with SimulatedPpv() as sim:
        with serial.serial_for_url(sim.port, baudrate=115200, timeout=GENEROUS_S) as link:
            assert ppv_exchange(link, "QVer") == "slave 8" and ppv_exchange(link, "SVset 600") == "600"


def test_a_rig_process_serves_several_boards_each_on_its_own_port():
    with SimulatedSupplyProcess(dialect="ppv", devices=2) as rig:
        assert len(rig.ports) == 2 and rig.ports[0] != rig.ports[1]
        rig.watch(0, 100.0, device=1)
        with serial.serial_for_url(rig.ports[1], timeout=GENEROUS_S) as link:
            for line in ("SVset 200", "SF 20", "SCycle 4", "SSwMode 2"):
                ppv_exchange(link, line)
            wait_until(lambda: ppv_exchange(link, "QSwMode") == "0", "the end of the board's own count")
            assert ppv_exchange(link, "QCycle") == "4/4"
        assert len(rig.edges(0, device=1)) == 4 and rig.edges(0, device=0) == []
        rig.inject("over_current", 0, device=1)
        with pytest.raises(ValueError, match="device=5: between 0 and 1"):
            rig.inject("over_current", 0, device=5)
