"""The same fault matrix for every dialect: HvSupply against each simulated supply, two channels (one two-channel
iseg module; two single-channel Keithley units; two PPV boards, i.e. two ports behind one driver), linked in memory on
one simulated clock. Every injected fault ends with the outputs off and the fault each device's capabilities let the
driver name. The same ramps on real ptys in real time: test_driver_pty.py."""
import dataclasses

import pytest

from dialect_rig import FAST_LIMITS, REAL_TIME_CURRENT_TRIP_A, Rig

from hv_driver import ChannelConfig, Fault, FaultLatchedError
from hv_driver.clock import SimulatedClock
from hv_driver.dialects import DIALECTS
from hv_driver.dialects.keithley_2290 import Keithley2290
from hv_driver.supervisor import DEFAULT_PERIOD_S, ChannelSupervisor
from sim_fallback.hv_plant import PlantChannel
from sim_fallback.keithley_supply import SimulatedKeithley2290

pytestmark = pytest.mark.fast

# fault -> dialect -> expected fault
MATRIX = {
    "over_current": {"iseg-edcp": Fault.OVER_CURRENT, "keithley-2290": Fault.OVER_CURRENT, "ppv": Fault.BREAKDOWN},
    "no_reply": dict.fromkeys(DIALECTS, Fault.LINK),
    "garbled": dict.fromkeys(DIALECTS, Fault.LINK),
    "partial": dict.fromkeys(DIALECTS, Fault.LINK),
    "disconnect": dict.fromkeys(DIALECTS, Fault.LINK),
    "device_reset": dict.fromkeys(DIALECTS, Fault.DEVICE),
    "readback_drift": dict.fromkeys(DIALECTS, Fault.READBACK_MISMATCH),
    # Ten times the capacitance draws ten times the charging current: above the trip where current is read; the
    # PPV cannot see the current, only its output lagging the host's ramp by more than the tolerance.
    "load_change": {"iseg-edcp": Fault.OVER_CURRENT, "keithley-2290": Fault.OVER_CURRENT,
                    "ppv": Fault.READBACK_MISMATCH},
}


@pytest.fixture(params=list(DIALECTS))
def rig(request):
    made = Rig(request.param, FAST_LIMITS, link_timeout_s=0.5, clock=SimulatedClock())
    yield request.param, made
    made.close()


def test_every_dialect_identifies_configures_and_ramps_both_channels(rig):
    _, made = rig
    made.check_ramps_both_channels(lambda predicate: made.supply.wait_for(predicate, 3.0))


def keithley_charging_peak(late_cycle: int, trip: float) -> tuple[float, bool]:
    """Unit b of the two-Keithley rig, its ramp to 2400 V played on the plant alone with its unit trip at ``trip``:
    its setpoint reaches it 1 ms into each cycle, after unit a's exchange; in ``late_cycle`` that exchange stalls for
    1.9 periods, so b gets the cycle's step late and, the loop running on at once, the next one (1.9 periods' slew)
    right after it. Returns the peak charging current [A] and whether the unit tripped."""
    config, exchange, stall = ChannelConfig("b", 0, **FAST_LIMITS), 0.001, 1.9 * DEFAULT_PERIOD_S
    host = ChannelSupervisor(config, 0.0, DEFAULT_PERIOD_S)
    host.enable()
    host.ramp_to(0.0, 2400.0)
    plant = PlantChannel(defaults=dataclasses.replace(SimulatedKeithley2290.default_defaults, current_limit=trip))
    plant.switch_on()
    arrivals, now = [], 0.0
    for cycle in range(round(0.8 / DEFAULT_PERIOD_S)):  # the whole 0.56 s ramp
        arrivals.append((now + (stall if cycle == late_cycle else exchange), host.step(now).setpoint))
        now += stall + exchange if cycle == late_cycle else DEFAULT_PERIOD_S
    t, dt, peak = 0.0, 1e-4, 0.0
    for arrival, setpoint in sorted(arrivals):
        while t + dt < arrival:
            t += dt
            plant.step(t, dt)
            peak = max(peak, plant.current)
        plant.voltage_set = setpoint
    return peak, plant.current_trip


def test_the_keithley_trip_holds_two_setpoint_steps_bunched_by_a_late_exchange():
    """The rig's trip leaves room for the worst bunching the loop's schedule allows, wherever in the ramp it falls
    (the cycles from 0.2 s to 0.4 s span its fastest part)."""
    trip = Keithley2290.capabilities.device_current_margin * FAST_LIMITS["current_trip_a"]
    peaks = {cycle: keithley_charging_peak(cycle, trip)
             for cycle in range(round(0.2 / DEFAULT_PERIOD_S), round(0.4 / DEFAULT_PERIOD_S))}
    tripped = {cycle: f"{peak * 1e6:.1f} uA" for cycle, (peak, trip_latched) in peaks.items() if trip_latched}
    assert not tripped, f"unit trip {trip * 1e6:.1f} uA exceeded with the late exchange in cycles {tripped}"


def keithley_step_peak(trip: float, step_v: float) -> tuple[float, bool]:
    """A Keithley unit's output switched on at 0 V and given a setpoint of ``step_v`` [V] at once, its unit trip at
    ``trip`` [A]: the peak charging current [A] and whether the unit tripped."""
    plant = PlantChannel(defaults=dataclasses.replace(SimulatedKeithley2290.default_defaults, current_limit=trip))
    plant.switch_on()
    plant.voltage_set = step_v
    t, dt, peak = 0.0, 1e-5, 0.0
    while t < 0.1:  # ten time constants
        t += dt
        plant.step(t, dt)
        peak = max(peak, plant.current)
    return peak, plant.current_trip


def test_the_real_time_trip_holds_the_largest_setpoint_step_a_keithley_can_get():
    """test_driver_pty.py ramps in real time on a host that may be loaded. Whatever the host's timing, the output
    lags a setpoint by 10 ms into 2 nF, so no gap between them (at most max_voltage_v) draws the real-time trip; the
    simulated-time trip is exceeded by such a step, which only a host's timing could make."""
    margin, step_v = Keithley2290.capabilities.device_current_margin, FAST_LIMITS["max_voltage_v"]
    peak, tripped = keithley_step_peak(margin * REAL_TIME_CURRENT_TRIP_A, step_v)
    assert not tripped, f"the {step_v:g} V step drew {peak * 1e6:.0f} uA"
    assert keithley_step_peak(margin * FAST_LIMITS["current_trip_a"], step_v)[1]


@pytest.mark.parametrize("fault", list(MATRIX))
def test_fault_matrix(rig, fault):
    name, made = rig
    expected = MATRIX[fault][name]
    channel = "b" if fault in ("over_current", "readback_drift", "load_change") else None
    if fault == "load_change":
        made.inject(fault, channel)
        for name_ in "ab":
            made.supply.enable(name_)
        # A long ramp: the PPV shows the larger load only as its output lagging the ramp (slew x time constant);
        # the lag must last past mismatch_time_s of observed loop time also when the loop runs late.
        made.supply.ramp_to("b", 2900.0, token=made.token).wait(5.0)
    else:
        made.ramp(1500.0)
        made.inject(fault, channel)
    tripped = [channel] if channel else ["a", "b"]
    reachable = fault != "disconnect"  # a pulled cable: no device here has a watchdog, its output stays

    def tripped_and_off():
        snap = made.supply.snapshot()
        return all(expected in snap.channel(c).faults for c in tripped) and all(
            not (reachable and made.plant(c).output_on) for c in tripped)
    assert made.supply.wait_for(tripped_and_off, 5.0), made.supply.snapshot()
    made.supply.wait_cycles(1)  # the readback that confirms the cut (sent in the cycle that read the fault)
    snap = made.supply.snapshot()
    for c in tripped:  # claimed off only once a reading confirmed the cut (none over a failing link)
        assert (snap.channel(c).setpoint, snap.channel(c).output_enabled) == (0.0, expected is Fault.LINK)
        assert expected.name.lower() in snap.channel(c).fault_text
    with pytest.raises(FaultLatchedError):
        made.supply.enable(tripped[0])
    if channel and fault != "load_change":  # the other channel (another supply on single-channel dialects) is untouched
        assert not snap.channel("a").faults and made.plant("a").output_on


def test_a_supply_that_stops_answering_trips_only_its_own_channels():
    made = Rig("ppv", FAST_LIMITS, link_timeout_s=0.5, clock=SimulatedClock())
    try:
        made.ramp(800.0)
        made.sims[1].inject("no_reply")
        assert made.supply.wait_for(lambda: Fault.LINK in made.supply.snapshot().channel("b").faults, 2.0)
        snap = made.supply.snapshot()
        assert Fault.LINK in snap.channel("b").faults and not snap.channel("a").faults
        assert made.plant("a").output_on and made.plant("a").voltage == pytest.approx(800.0, abs=5.0)
    finally:
        made.close()


def test_a_reset_clears_a_breakdown_and_the_board_comes_back_at_0_v():
    made = Rig("ppv", FAST_LIMITS, link_timeout_s=0.5, clock=SimulatedClock())
    try:
        made.ramp(1200.0)
        made.inject("over_current", "a")
        assert made.supply.wait_for(lambda: Fault.BREAKDOWN in made.supply.snapshot().channel("a").faults, 1.0)
        made.sims[0].clear_faults()
        assert made.supply.reset_faults() == ["a"]
        made.supply.enable("a")
        made.supply.wait_cycles(5)
        assert made.plant("a").output_on and made.plant("a").voltage_set == 0.0
        assert made.supply.ramp_to("a", 600.0, token=made.token).wait(5.0)
        made.supply.wait_cycles(10)
        assert not made.supply.snapshot().channel("a").faults
    finally:
        made.close()
