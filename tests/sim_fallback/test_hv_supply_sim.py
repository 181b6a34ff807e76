"""Simulated EDCP supply in simulated time: load dynamics against closed forms, the device ramp and trip, and the
host watchdog and ramps through the command set over an in-memory link on the test's clock (the pty side:
test_hv_supply.py)."""
import math

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hv_driver.clock import SimulatedClock
from hv_driver.dialects.iseg_edcp import ChannelStatus
from sim_fallback.hv_plant import ChannelDefaults, DeaLoad, PlantChannel
from sim_fallback.hv_supply import SimulatedSupply, channel_status
from sim_fallback.memory_port import MemoryPort

pytestmark = pytest.mark.fast


def exchange(link, line: str) -> tuple[str, str]:
    link.write(line.encode() + b"\r\n")
    return link.readline().decode().rstrip("\r\n"), link.readline().decode().rstrip("\r\n")


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


def test_volt_off_through_the_command_set_ramps_at_the_configured_speed_and_the_channel_count_is_reported():
    clock = SimulatedClock()
    sim = SimulatedSupply(channels=2, clock=clock)
    link = MemoryPort(sim)
    for line in (":CONF:RAMP:VOLT:DOWN 1.000000E+02,(@0);*OPC?", ":VOLT 2.400000E+03,(@0);*OPC?",
                 ":VOLT ON,(@0);*OPC?"):
        assert exchange(link, line)[1] == "1"
    sim.plant[0].voltage = 2400.0  # charged
    assert exchange(link, ":VOLT OFF,(@0);*OPC?")[1] == "1"
    assert sim.plant[0].ramping_down and not sim.plant[0].output_on and not sim.plant[0].emergency
    clock.advance(4.0)
    sim.poll()
    assert sim.plant[0].voltage == pytest.approx(2000.0) and sim.plant[0].ramping_down  # 100 V/s, not a cut
    clock.advance(20.0)
    sim.poll()
    assert sim.plant[0].voltage == 0.0 and not sim.plant[0].ramping_down
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
