"""The simulated supply in its own process: reachable on its pty, faults injected over its stdin."""
import pytest
import serial

from sim_fallback.hv_supply_process import SimulatedSupplyProcess

pytestmark = pytest.mark.integration


def query(port: serial.Serial, command: str) -> str:
    port.write(command.encode() + b"\r\n")
    echo = port.readline().decode().strip()
    assert echo == command  # the EDCP supply echoes every command line
    return port.readline().decode().strip()


def test_process_serves_the_dialect_and_takes_faults():
    with SimulatedSupplyProcess(channels=2) as sim, serial.serial_for_url(sim.port, timeout=5.0) as port:
        assert "simulated" in query(port, "*IDN?")
        sim.inject("over_current", 0)
        sim.clear_faults()
        with pytest.raises(ValueError, match="fault='melt'"):
            sim.inject("melt")
        with pytest.raises(ValueError, match="channel=5"):
            sim.inject("over_current", 5)
    assert sim._process is None


def test_commands_after_stop_are_refused():
    sim = SimulatedSupplyProcess(channels=1).start()
    sim.stop()
    with pytest.raises(RuntimeError, match="not running"):
        sim.inject("no_reply")
