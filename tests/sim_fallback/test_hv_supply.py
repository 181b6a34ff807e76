"""Simulated EDCP supply on a real pty: framing and echo, error replies, reply faults, that its loop applies the
host watchdog, and the CLI. No outcome here depends on how fast the host runs: replies are read up to a marker
line's answer rather than for a time, and the watchdog is either waited for or played on the device's own clock.
Load dynamics, ramps and the watchdog's timing are tested in simulated time (test_hv_supply_sim.py)."""
import os
import select
import subprocess
import sys
import threading
from types import SimpleNamespace

import pytest
import serial
from waiting import GENEROUS_S, wait_until

from hv_driver.clock import SimulatedClock
from sim_fallback import pty_device
from sim_fallback.hv_supply import ERROR_REPLY, IDENTITY, SimulatedSupply

pytestmark = pytest.mark.integration

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MARKER, MARKER_REPLY = b"*OPC?\r\n", b"*OPC?\r\n1\r\n"  # a line, its echo and answer


@pytest.fixture
def port():
    with SimulatedSupply(channels=2, watchdog_s=None) as sim:
        with serial.serial_for_url(sim.port, timeout=GENEROUS_S) as link:
            yield sim, link


def exchange(link, line: str) -> tuple[str, str]:
    link.write(line.encode() + b"\r\n")
    return link.readline().decode().rstrip("\r\n"), link.readline().decode().rstrip("\r\n")


def sent_for(sim, link, line: str) -> bytes:
    """All the device sends back for ``line`` under an injected fault, however late: once its log shows the line
    taken (its reply, if any, is then on the wire) the faults are cleared and a marker line follows; what arrives
    before the marker's answer belongs to ``line``."""
    taken = len(sim.command_log) + 1
    link.write(line.encode() + b"\r\n")
    wait_until(lambda: len(sim.command_log) >= taken, f"{line!r} taken by the device")
    sim.clear_faults()
    link.write(MARKER)
    received = link.read_until(MARKER_REPLY)
    assert received.endswith(MARKER_REPLY), received
    return received[:-len(MARKER_REPLY)]


def test_every_line_is_echoed_then_answered(port):
    sim, link = port
    assert exchange(link, "*IDN?") == ("*IDN?", IDENTITY)
    assert exchange(link, ":VOLT 1.500000E+03,(@1);*OPC?") == (":VOLT 1.500000E+03,(@1);*OPC?", "1")
    assert sim.plant[1].voltage_set == 1500.0
    assert exchange(link, ":MEAS:VOLT? (@0-1)")[1] == "0.00000E+00V,0.00000E+00V"


@pytest.mark.parametrize("line", [":VOLT 9.9E+03,(@0);*OPC?", ":MEAS:VOLT? (@7)", ":FOO? (@0)", ":VOLT 1,(@0",
                                  ":CURR abc,(@0);*OPC?"])
def test_lines_the_device_cannot_execute_get_the_error_reply(port, line):
    sim, link = port
    assert exchange(link, line) == (line, ERROR_REPLY)
    assert sim.plant[0].voltage_set == 0.0


def test_the_watchdog_of_the_device_on_a_pty_cuts_the_outputs_without_traffic():
    """Its loop applies the watchdog: the output it switched on is cut (emergency off, which only an output that
    was on gets) once the host is silent. When, is the simulated-time test's subject."""
    with SimulatedSupply(channels=1, watchdog_s=0.05) as sim:
        with serial.serial_for_url(sim.port, timeout=GENEROUS_S) as link:
            assert exchange(link, ":VOLT ON,(@0);*OPC?") == (":VOLT ON,(@0);*OPC?", "1")
            wait_until(lambda: sim.plant[0].emergency, "emergency off by the watchdog")
    assert not sim.plant[0].output_on


def test_a_descheduled_simulator_does_not_read_its_own_delay_as_host_silence(monkeypatch):
    """Commands that waited in the pty while the simulator could not run count as traffic. The device runs on the
    test's clock; its loop is descheduled right after a wait that found no bytes, and while it is, three watchdog
    periods pass on that clock, the host writing a line every 3/4 period."""
    clock = SimulatedClock()
    descheduled, resumed = threading.Event(), threading.Event()

    def wait_then_descheduled(*args):
        ready = select.select(*args)
        if threading.current_thread() is sim._thread and not ready[0] and not resumed.is_set():
            descheduled.set()
            resumed.wait(GENEROUS_S)
        return ready

    with SimulatedSupply(channels=1, watchdog_s=0.2, clock=clock) as sim:
        with serial.serial_for_url(sim.port, timeout=GENEROUS_S) as link:
            assert exchange(link, ":VOLT ON,(@0);*OPC?")[1] == "1"
            monkeypatch.setattr(pty_device, "select", SimpleNamespace(select=wait_then_descheduled))
            assert descheduled.wait(GENEROUS_S)
            for _ in range(4):
                link.write(b"*IDN?\r\n")
                clock.advance(0.15)
            resumed.set()
            replies = [link.readline().decode().rstrip("\r\n") for _ in range(2 * 4)]
            assert replies == ["*IDN?", IDENTITY] * 4
            assert sim.plant[0].output_on and not sim.plant[0].emergency


FULL_REPLY = b"*IDN?\r\n" + IDENTITY.encode() + b"\r\n"


@pytest.mark.parametrize("fault, check", [
    ("no_reply", lambda sent: sent == b""),
    ("partial", lambda sent: sent == FULL_REPLY[:len(FULL_REPLY) // 2]),
    ("garbled", lambda sent: len(sent) == len(FULL_REPLY) and sent != FULL_REPLY and sent.endswith(b"\r\n")),
])
def test_reply_faults_and_clear(port, fault, check):
    sim, link = port
    sim.inject(fault)
    assert check(sent_for(sim, link, "*IDN?"))
    assert exchange(link, "*IDN?") == ("*IDN?", IDENTITY)  # cleared


def test_a_fault_injected_after_a_command_starts_once_that_command_is_answered(port):
    sim, link = port
    sim.inject_after("*IDN?", "no_reply")
    assert exchange(link, "*OPC?") == ("*OPC?", "1")  # another line: not yet
    assert exchange(link, "*IDN?") == ("*IDN?", IDENTITY)  # answered, then silent
    assert sent_for(sim, link, "*OPC?") == b""
    assert exchange(link, "*OPC?") == ("*OPC?", "1")


def test_unknown_fault_names_the_choices():
    with pytest.raises(ValueError, match="over_current, no_reply"):
        SimulatedSupply().inject("lightning")
    with pytest.raises(ValueError, match="over_current, no_reply"):
        SimulatedSupply().inject_after("*IDN?", "lightning")


def test_cli_prints_the_port_and_takes_fault_commands():
    cli = subprocess.Popen([sys.executable, "-m", "sim_fallback.hv_supply", "--channels", "1"], cwd=REPO,
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        path = cli.stdout.readline().strip()
        assert os.path.exists(path)
        with serial.serial_for_url(path, timeout=GENEROUS_S) as link:
            assert exchange(link, "*OPC?") == ("*OPC?", "1")
        replies = []
        for command in ("over_current 0", "status", "lightning", "clear"):
            cli.stdin.write(command + "\n")
            cli.stdin.flush()
            replies.append(cli.stdout.readline().strip())
        assert replies[0] == "ok" and replies[1].startswith("ch0: off") and replies[2].startswith("error: fault=")
        cli.stdin.write("quit\n")
        cli.stdin.flush()
        assert cli.wait(timeout=GENEROUS_S) == 0
    finally:
        cli.kill()
        cli.stdout.close()
        cli.stdin.close()
