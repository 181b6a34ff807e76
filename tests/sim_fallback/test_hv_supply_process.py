"""The simulated supply in its own process: reachable on its pty, faults injected over its stdin, and at
real-time priority where the host grants it, as a device with its own processor is never slowed by the host."""
import os

import pytest
import serial

from sim_fallback.hv_supply_process import SimulatedSupplyProcess
from sim_fallback.rig import SIMULATED_DEVICE_PRIORITY

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


def host_grants_realtime() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(SIMULATED_DEVICE_PRIORITY))
    except OSError:
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


def test_the_rig_runs_at_real_time_priority_below_the_supervisor_where_the_host_grants_it():
    """Under two busy loops a rig at normal priority answered late and the supervisor latched LINK."""
    granted = host_grants_realtime()
    with SimulatedSupplyProcess(channels=1) as sim, serial.serial_for_url(sim.port, timeout=5.0) as port:
        assert "simulated" in query(port, "*IDN?")  # its threads are running
        policy = os.sched_getscheduler(sim.pid)
        assert policy == (os.SCHED_FIFO if granted else os.SCHED_OTHER)
        if granted:
            assert os.sched_getparam(sim.pid).sched_priority == SIMULATED_DEVICE_PRIORITY
            # the main thread and the device's serving thread (a library's idle pool made at import may not be)
            threads = [int(t) for t in os.listdir(f"/proc/{sim.pid}/task")]
            assert sum(os.sched_getscheduler(t) == os.SCHED_FIFO for t in threads) >= 2
