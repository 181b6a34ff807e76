"""Timing of the whole loop, driver and simulated supplies on one simulated clock (deterministic, no sleeps): a
ramp's minimum-jerk end time and its slew, a silent supply's LINK trip within the link timeout's bound on every
dialect, a breakdown caught within its readbacks, a fault read back from one supply cut before the next supply's
exchanges, a heartbeat costing no extra cycle, a client heard through a channel across a stall, smooth pulse edges on
their time grid, and (property) a deaf supply's cut confirmed whatever the silence lasts."""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dialect_rig import Rig

from hv_driver import ChannelConfig, Fault, HvSupply
from hv_driver.clock import SimulatedClock
from hv_driver.dialects import DIALECTS
from hv_driver.ramp import MIN_JERK_PEAK_RATE
from hv_driver.supervisor import COLLAPSE_READBACKS, DEFAULT_PERIOD_S, IMMEDIATE_FAULTS
from sim_fallback.hv_supply import SimulatedSupply
from sim_fallback.memory_port import MemoryPort

pytestmark = pytest.mark.fast

LIMITS = dict(max_voltage_v=3000.0, slew_rate_v_per_s=8000.0, mismatch_tolerance_v=150.0, mismatch_time_s=0.2,
              current_trip_a=100e-6)
LINK_TIMEOUT_S = 0.5
REPLY_TIMEOUT_S = LINK_TIMEOUT_S / 4  # the driver's default
PERIOD = DEFAULT_PERIOD_S
EPSILON = 1e-9  # rounding of sums of simulated periods


def rig_for(name: str, **options) -> Rig:
    rig = Rig(name, LIMITS, link_timeout_s=LINK_TIMEOUT_S, clock=SimulatedClock(), **options)
    for channel in "ab":
        rig.supply.enable(channel)
    return rig


@pytest.fixture(params=list(DIALECTS))
def rig(request):
    made = rig_for(request.param)
    yield request.param, made
    made.close()


def test_a_ramp_ends_at_its_minimum_jerk_time_and_never_outruns_the_slew_limit(rig):
    name, made = rig
    start = made.clock()
    handle = made.supply.ramp_to("a", 2400.0, token=made.token)
    setpoints = [(start, 0.0)]
    while not handle.done:
        made.supply.step()
        setpoints.append((made.clock(), made.supply.snapshot().channel("a").setpoint))
    assert handle.succeeded, handle.message
    duration = MIN_JERK_PEAK_RATE * 2400.0 / LIMITS["slew_rate_v_per_s"]
    # Done once the end is sent and read back within the tolerance: at the ramp's end, or the cycle after.
    assert duration - EPSILON <= made.clock() - start <= duration + 2 * PERIOD + EPSILON
    times, volts = np.array(setpoints).T
    rates = np.diff(volts) / np.maximum(np.diff(times), EPSILON)
    assert rates.max() <= LIMITS["slew_rate_v_per_s"] * (1 + 1e-9)


@pytest.mark.parametrize("fault", ["no_reply", "deaf"])
def test_a_silent_supply_trips_link_within_the_link_timeouts_bound(rig, fault):
    """The first failed exchange, the link timeout from it, and the failing cycle that finds it passed (a resync and
    a reply timeout): no later than link_timeout_s + 3 reply timeouts after the silence began."""
    name, made = rig
    made.ramp(1000.0)
    made.inject(fault, "a")
    silent_since = made.clock()
    while Fault.LINK not in made.supply.snapshot().channel("a").faults:
        made.supply.step()
    tripped = made.clock() - silent_since
    assert LINK_TIMEOUT_S < tripped <= LINK_TIMEOUT_S + 3 * REPLY_TIMEOUT_S + PERIOD + EPSILON


def test_a_breakdown_on_the_ppv_is_caught_within_its_readbacks():
    made = rig_for("ppv")
    try:
        made.ramp(1200.0)
        made.supply.run_for(0.1)  # held
        made.inject("over_current", "a")
        arced = made.clock()
        while Fault.BREAKDOWN not in made.supply.snapshot().channel("a").faults:
            made.supply.step()
        # The voltage collapses within 2 ms (10 ms cycles): the next COLLAPSE_READBACKS readbacks are far below.
        assert made.clock() - arced <= COLLAPSE_READBACKS * PERIOD + EPSILON
        made.supply.step()
        assert not made.plant("a").output_on
    finally:
        made.close()


@pytest.mark.parametrize("name", [n for n, d in DIALECTS.items() if d.capabilities.channels_per_device == 1])
def test_a_fault_read_back_from_one_supply_is_cut_before_the_next_supplys_exchanges(name):
    """Two single-channel supplies on two ports, each line 1 ms on the wire: the arc one readback shows is cut in the
    same cycle, before the loop serves the other supply (not in the next cycle, after it)."""
    made = rig_for(name, exchange_s=0.001)
    try:
        made.ramp(1000.0)
        made.supply.run_for(0.1)  # held
        first, second = made.sims
        arced = made.clock()
        made.inject("over_current", "a")
        while not made.supply.snapshot().channel("a").faults & IMMEDIATE_FAULTS:
            made.supply.step()
        made.supply.run_for(0.05)
        cut_line = DIALECTS[name].commands["output_off"].template
        cut = next(t for t, line in first.command_log if t > arced and line == cut_line)
        shown = max(t for t, line in first.command_log if t < cut)  # the last readback before the cut showed it
        assert not [line for t, line in second.command_log if shown < t < cut]
    finally:
        made.close()


def test_a_heartbeat_changes_no_command_and_costs_the_loop_no_extra_cycle():
    made = rig_for("iseg-edcp")
    try:
        made.ramp(1000.0)
        sim, _ = made.where["a"]
        start = made.clock()
        for k in range(10):  # ten heartbeats in one second, each between two cycles
            made.clock.call_at(start + (k + 0.5) * 0.1 + PERIOD / 2, lambda: made.supply.heartbeat(made.token))
        made.supply.run_for(1.0)
        cycles = [t for t, line in sim.command_log if t >= start and line.startswith(":MEAS:VOLT?")]
        assert abs(len(cycles) - round(1.0 / PERIOD)) <= 1, len(cycles)
    finally:
        made.close()


def test_the_loop_takes_in_what_waits_in_its_clients_channel_before_it_judges_a_silence():
    """A supply heard through a channel (`HvSupply.listen`, as the supervisor process hears its node): its process
    stalls 1.5 s, three heartbeat timeouts, while the client's beats wait in the channel; taken in with their sending
    stamps before the judgement, they keep the client. Then the client dies: it lapses one timeout after its last
    beat was sent."""
    clock = SimulatedClock()
    sim = SimulatedSupply(channels=2, clock=clock)
    supply = HvSupply(MemoryPort(sim), channels=[ChannelConfig("a", 0, **LIMITS)], heartbeat_timeout_s=0.5,
                      handle_signals=False, clock=clock).open()
    try:
        token = supply.claim_control("test")
        supply.enable("a")
        assert supply.ramp_to("a", 1000.0, token=token).wait(5.0)
        supply.heartbeat(token)
        waiting = []  # sending stamps of the beats in the channel

        def take_in(patience):
            while waiting:
                supply.heartbeat(token, sent=waiting.pop(0))
        supply.listen(take_in)
        stalled = clock()
        waiting += [stalled + 0.1 * k for k in range(1, 15)]
        clock.advance(1.5)  # the stall: no cycle ran
        supply.step()
        assert supply.snapshot().controller == "test" and not supply.snapshot().channel("a").faults
        last_sent = stalled + 1.4
        assert supply.wait_for(lambda: supply.snapshot().controller == "", 5.0)
        assert 0.5 < clock() - last_sent <= 0.5 + 2 * PERIOD + EPSILON
        assert supply.snapshot().channel("a").faults == Fault.HEARTBEAT
    finally:
        supply.abort()


def test_smooth_pulse_edges_cross_half_the_amplitude_on_their_grid_at_half_the_edge_time():
    made = rig_for("iseg-edcp")
    try:
        made.watch("a", 300.0)
        handle = made.supply.pulse(["a"], 600.0, 2.0, duty=0.5, cycles=4, token=made.token)
        assert handle.wait(10.0) and handle.succeeded, handle.message
        train = handle.trains["a"]
        edges = made.edges("a")
        due = train.start + np.arange(4) * train.period + train.edge_duration / 2  # min-jerk: half-way at half time
        assert len(edges) == 4
        # The device follows each streamed setpoint at its ramp (1.2 x the slew limit) within a cycle.
        assert np.all((edges >= due - PERIOD) & (edges <= due + 2 * PERIOD)), edges - due
    finally:
        made.close()


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.sampled_from(list(DIALECTS)), silence_s=st.floats(0.05, 2.0), cycles_before=st.integers(0, 20))
def test_whatever_a_supplys_deafness_lasts_its_output_is_never_claimed_off_and_the_cut_is_confirmed(
        name, silence_s, cycles_before):
    made = rig_for(name)
    try:
        made.ramp(600.0)
        made.supply.run_for(cycles_before * PERIOD)
        sim, _ = made.where["a"]
        made.inject("deaf", "a")
        made.supply.estop()  # the cut goes out into the silence
        made.clock.call_at(made.clock() + silence_s, sim.clear_faults)
        end = made.clock() + silence_s + 0.5
        while made.clock() < end:
            made.supply.step()
            snap = made.supply.snapshot().channel("a")
            assert snap.output_enabled or not made.plant("a").output_on
        assert not made.plant("a").output_on and not made.supply.snapshot().channel("a").output_enabled
    finally:
        made.close()


# An iseg at its factory 9600 baud echoes each line: a query and its answer take about 40 ms on the wire, so a cycle
# of readbacks takes far longer than the loop's nominal period. The loop's timing must follow the line it has.
SLOW_LINE_EXCHANGE_S = 0.04


@pytest.mark.parametrize("name", list(DIALECTS))
def test_on_a_line_slower_than_the_loop_rate_a_ramp_keeps_its_time_and_a_drift_trips_on_time(name):
    limits = {**LIMITS, "slew_rate_v_per_s": 1000.0}  # the shipped slew limit: steps of a slow cycle stay gentle
    made = Rig(name, limits, link_timeout_s=LINK_TIMEOUT_S, clock=SimulatedClock(), exchange_s=SLOW_LINE_EXCHANGE_S)
    made.supply.enable("a")
    try:
        start = made.clock()
        handle = made.supply.ramp_to("a", 2400.0, token=made.token)
        cycles = [start]
        while not handle.done:
            made.supply.step()
            cycles.append(made.clock())
        assert handle.succeeded, handle.message
        cycle = float(np.median(np.diff(cycles)))
        assert cycle > 4 * PERIOD  # the line, not the loop rate, sets the pace here
        duration = MIN_JERK_PEAK_RATE * 2400.0 / limits["slew_rate_v_per_s"]
        assert made.clock() - start <= duration + 3 * cycle + EPSILON

        made.inject("readback_drift", "a")
        drifting = made.clock()
        while Fault.READBACK_MISMATCH not in made.supply.snapshot().channel("a").faults:
            made.supply.step()
            assert made.clock() - drifting < 60.0
        # Out of the band once the drift passes the tolerance, then the mismatch time, found by the next readback.
        bound = LIMITS["mismatch_tolerance_v"] / 500.0 + LIMITS["mismatch_time_s"] + 2 * cycle
        assert made.clock() - drifting <= bound + EPSILON
    finally:
        made.close()
