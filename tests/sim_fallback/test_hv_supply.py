"""Simulated EDCP supply: wire behaviour on the pty, load dynamics against closed forms, CLI."""
import math
import os
import subprocess
import sys
import time

import pytest
import serial
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hv_driver.clock import SimulatedClock
from hv_driver.dialects.iseg_edcp import ChannelStatus
from sim_fallback.hv_plant import ChannelDefaults, DeaLoad, PlantChannel
from sim_fallback.hv_supply import ERROR_REPLY, SimulatedSupply, channel_status
from sim_fallback.memory_port import MemoryPort

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture
def port():
    with SimulatedSupply(channels=2, watchdog_s=None) as sim:
        with serial.serial_for_url(sim.port, timeout=1.0) as link:
            yield sim, link


def exchange(link, line: str) -> tuple[str, str]:
    link.write(line.encode() + b"\r\n")
    return link.readline().decode().rstrip("\r\n"), link.readline().decode().rstrip("\r\n")


def test_every_line_is_echoed_then_answered(port):
    sim, link = port
    assert exchange(link, "*IDN?") == ("*IDN?", sim_identity())
    assert exchange(link, ":VOLT 1.500000E+03,(@1);*OPC?") == (":VOLT 1.500000E+03,(@1);*OPC?", "1")
    assert sim.plant[1].voltage_set == 1500.0
    assert exchange(link, ":MEAS:VOLT? (@0-1)")[1] == "0.00000E+00V,0.00000E+00V"


def sim_identity():
    from sim_fallback.hv_supply import IDENTITY
    return IDENTITY


@pytest.mark.parametrize("line", [":VOLT 9.9E+03,(@0);*OPC?", ":MEAS:VOLT? (@7)", ":FOO? (@0)", ":VOLT 1,(@0",
                                  ":CURR abc,(@0);*OPC?"])
def test_lines_the_device_cannot_execute_get_the_error_reply(port, line):
    sim, link = port
    assert exchange(link, line) == (line, ERROR_REPLY)
    assert sim.plant[0].voltage_set == 0.0


def test_output_follows_the_device_ramp_and_draws_charging_current():
    load = DeaLoad(capacitance=2e-9, leakage_resistance=1e12)
    ch = PlantChannel(ChannelDefaults(ramp_speed=1000.0), load)
    ch.voltage_set = 1000.0
    assert ch.switch_on()
    ch.step(0.1, 0.1)
    assert ch.voltage == pytest.approx(100.0)
    assert ch.current == pytest.approx(2e-9 * 1000.0 + 100.0 / 1e12)  # C dV/dt + V / R_leak
    assert ChannelStatus.IS_VOLTAGE_RAMP in channel_status(ch) and ChannelStatus.IS_ON in channel_status(ch)


def test_switched_off_the_load_discharges_through_the_bleeder():
    ch = PlantChannel(load=DeaLoad(capacitance=2e-9, discharge_resistance=10e6))
    ch.voltage = 2000.0
    ch.step(0.02, 0.02)
    assert ch.voltage == pytest.approx(2000.0 * math.exp(-1.0))


@settings(max_examples=60, deadline=None)
@given(start=st.floats(1e3, 1e7), cycles=st.integers(1, 6), frequency=st.sampled_from([5.0, 20.0, 50.0]))
@example(start=102920.99090649255, cycles=4, frequency=20.0)  # a host up for 29 h: the old count ran a fifth cycle
def test_device_switching_runs_exactly_the_counted_cycles_at_any_clock_value(start, cycles, frequency):
    """The device's clock is this host's monotonic time, which can be large; the count must not depend on it."""
    ch = PlantChannel(ChannelDefaults(ramp_speed=None))
    ch.voltage_set, ch.watch_level = 200.0, 100.0
    assert ch.start_switching(start, frequency, 0.5, cycles)
    t, end = start, start + (cycles + 2) / frequency
    while t < end:
        ch.step(t + 0.01, 0.01)
        t += 0.01
    assert len(ch.rising_edges) == cycles and ch.switching is None and not ch.output_on


def switched_on_at(voltage: float, ramp: float) -> PlantChannel:
    ch = PlantChannel(ChannelDefaults(ramp_speed=ramp))
    ch.voltage_set = ch.voltage = voltage
    assert ch.switch_on()
    return ch


def test_volt_off_ramps_the_output_down_at_the_device_ramp():
    """As the iseg manual says: `:VOLT OFF` switches off with the configured ramp-down speed."""
    ch = switched_on_at(2400.0, ramp=1200.0)
    ch.switch_off(0.0, emergency=False)
    ch.step(0.5, 0.5)
    assert ch.voltage == pytest.approx(1800.0)
    assert ChannelStatus.IS_VOLTAGE_RAMP in channel_status(ch) and ChannelStatus.IS_ON not in channel_status(ch)
    ch.step(2.5, 2.0)
    assert ch.voltage == 0.0 and ChannelStatus.IS_VOLTAGE_RAMP not in channel_status(ch)
    ch.step(3.0, 0.5)
    assert ch.voltage == 0.0


def test_emergency_off_cuts_the_output_without_ramp():
    ch = switched_on_at(2400.0, ramp=1200.0)
    ch.switch_off(0.0, emergency=True)
    ch.step(0.1, 0.1)  # discharged through the bleeder, tau = 20 ms
    assert ch.voltage == pytest.approx(2400.0 * math.exp(-5.0))


def test_volt_off_on_the_wire_ramps_and_the_channel_count_is_reported(port):
    sim, link = port
    for line in (":CONF:RAMP:VOLT:DOWN 1.000000E+02,(@0);*OPC?", ":VOLT 2.400000E+03,(@0);*OPC?",
                 ":VOLT ON,(@0);*OPC?"):
        assert exchange(link, line)[1] == "1"
    with sim._lock:
        sim.plant[0].voltage = 2400.0
    assert exchange(link, ":VOLT OFF,(@0);*OPC?")[1] == "1"
    assert sim.plant[0].ramping_down and not sim.plant[0].output_on and sim.plant[0].voltage > 2000.0
    assert exchange(link, ":READ:MOD:CHAN?") == (":READ:MOD:CHAN?", "2")


def test_device_current_trip_switches_off_after_the_trip_time():
    ch = PlantChannel(ChannelDefaults(ramp_speed=1e6))
    ch.current_limit, ch.trip_time_ms, ch.trip_action = 1e-4, 50.0, 2
    ch.voltage_set = 1000.0
    ch.switch_on()
    ch.step(0.01, 0.01)
    ch.arcing = True
    ch.step(0.02, 0.01)
    ch.step(0.06, 0.04)
    assert ch.output_on
    ch.step(0.075, 0.015)
    assert not ch.output_on and ChannelStatus.IS_CURRENT_TRIP in channel_status(ch)
    assert not ch.switch_on()  # refused until the events are cleared


def test_watchdog_cuts_the_outputs_without_traffic_on_a_real_pty():
    with SimulatedSupply(channels=1, watchdog_s=0.05) as sim:
        with serial.serial_for_url(sim.port, timeout=1.0) as link:
            exchange(link, ":VOLT ON,(@0);*OPC?")
            assert sim.plant[0].output_on
            deadline = time.monotonic() + 2.0
            while sim.plant[0].output_on and time.monotonic() < deadline:
                time.sleep(0.01)
    assert not sim.plant[0].output_on and sim.plant[0].emergency


def test_watchdog_cuts_the_outputs_once_its_time_without_traffic_has_passed():
    """In simulated time: on while lines keep arriving, off (emergency) the moment the watchdog time has passed."""
    clock = SimulatedClock()
    sim = SimulatedSupply(channels=1, watchdog_s=0.05, clock=clock)
    link = MemoryPort(sim)
    for _ in range(10):  # traffic every 40 ms keeps it on
        link.write(b":VOLT ON,(@0);*OPC?\r\n")
        clock.advance(0.04)
        sim.poll()
        assert sim.plant[0].output_on
    clock.advance(0.0101)
    sim.poll()
    assert not sim.plant[0].output_on and sim.plant[0].emergency


def test_a_descheduled_simulator_does_not_read_its_own_delay_as_host_silence():
    """Commands that waited in the pty while the simulator could not run count as traffic."""
    with SimulatedSupply(channels=1, watchdog_s=0.2) as sim:
        with serial.serial_for_url(sim.port, timeout=2.0) as link:
            exchange(link, ":VOLT ON,(@0);*OPC?")
            with sim._lock:  # the simulator's loop stalls here, as on a starved host
                stalled, sent = time.monotonic(), 0
                while time.monotonic() - stalled < 0.6:  # three watchdog periods of host traffic
                    link.write(b"*IDN?\r\n")
                    sent += 1
                    time.sleep(0.05)
            replies = [link.readline().decode().rstrip("\r\n") for _ in range(2 * sent)]
            assert replies == ["*IDN?", sim_identity()] * sent
            assert sim.plant[0].output_on and not sim.plant[0].emergency


@pytest.mark.parametrize("fault, check", [
    ("no_reply", lambda link, echo, answer: (echo, answer) == ("", "")),
    ("partial", lambda link, echo, answer: echo == "*IDN?" and not answer.endswith("\n")),
    ("garbled", lambda link, echo, answer: (echo, answer) != ("*IDN?", sim_identity())),
])
def test_reply_faults_and_clear(port, fault, check):
    sim, link = port
    link.timeout = 0.1
    sim.inject(fault)
    link.write(b"*IDN?\r\n")
    echo, answer = (link.readline().decode("ascii", "replace").rstrip("\r\n") for _ in range(2))
    assert check(link, echo, answer)
    sim.clear_faults()
    link.reset_input_buffer()
    assert exchange(link, "*OPC?") == ("*OPC?", "1")


def test_a_fault_injected_after_a_command_starts_once_that_command_is_answered(port):
    sim, link = port
    link.timeout = 0.1
    sim.inject_after("*IDN?", "no_reply")
    assert exchange(link, "*OPC?") == ("*OPC?", "1")  # another line: not yet
    assert exchange(link, "*IDN?") == ("*IDN?", sim_identity())  # answered, then silent
    link.write(b"*OPC?\r\n")
    assert link.readline() == b""
    sim.clear_faults()
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
        with serial.serial_for_url(path, timeout=1.0) as link:
            assert exchange(link, "*OPC?") == ("*OPC?", "1")
        replies = []
        for command in ("over_current 0", "status", "lightning", "clear"):
            cli.stdin.write(command + "\n")
            cli.stdin.flush()
            replies.append(cli.stdout.readline().strip())
        assert replies[0] == "ok" and replies[1].startswith("ch0: off") and replies[2].startswith("error: fault=")
        cli.stdin.write("quit\n")
        cli.stdin.flush()
        assert cli.wait(timeout=10) == 0
    finally:
        cli.kill()
        cli.stdout.close()
        cli.stdin.close()
