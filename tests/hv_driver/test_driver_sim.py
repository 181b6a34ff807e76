"""HvSupply against the simulated supply: ramps, every injected fault, e-stop, exit paths, the heartbeat watchdog
and the control claim, resets and outputs that ramp down at the device ramp. The driver's loop and the simulated
module run on one simulated clock, linked in memory (deterministic: timing is asserted in simulated time). The same
supply on a real pty in real time: test_driver_pty.py."""
import logging
import math

import pytest
from dialect_rig import all_off, ramp_both

from hv_driver import (ChannelConfig, ConfigurationError, ControlError, Fault, FaultLatchedError, HvSupply, LimitError,
                       LinkError)
from hv_driver.supervisor import DEFAULT_PERIOD_S
from sim_fallback.hv_plant import ChannelDefaults, PlantEvent
from sim_fallback.hv_supply import SimulatedSupply
from sim_fallback.memory_port import MemoryPort

pytestmark = pytest.mark.fast


def simulated(sim, clock, configs, **options) -> HvSupply:
    """An HvSupply for ``sim`` on the test's simulated clock (not opened)."""
    return HvSupply(MemoryPort(sim), channels=configs, handle_signals=False, clock=clock, **options)


def test_open_identifies_and_configures_the_device_side_limits(sim, supply):
    assert supply.snapshot().device_id.startswith("iseg Spezialelektronik GmbH")
    for ch in sim.plant:  # second line of defence set and read back
        assert ch.ramp_up == ch.ramp_down == pytest.approx(8000.0 * 1.2)
        assert ch.current_limit == pytest.approx(75e-6) and ch.trip_action == 2
    assert supply.snapshot().channel("front").ceiling == 3000.0


def test_open_sends_the_documented_sequence(sim, supply):
    supply.wait_cycles(2)
    lines = [line for _, line in sim.command_log]
    per_channel = [[f":CONF:RAMP:VOLT:UP 9.600000E+03,(@{n});*OPC?", f":CONF:RAMP:VOLT:DOWN 9.600000E+03,(@{n});*OPC?",
                    f":CURR 7.500000E-05,(@{n});*OPC?", f":CONF:TRIP:TIME 1.000000E+02,(@{n});*OPC?",
                    f":CONF:TRIP:ACTION 2,(@{n});*OPC?", f":READ:RAMP:VOLT? (@{n})", f":READ:CURR? (@{n})",
                    f":CONF:TRIP:TIME? (@{n})", f":READ:VOLT:LIM? (@{n})"] for n in (0, 1)]
    expected = (["*IDN?", ":READ:MOD:CHAN?", ":VOLT 0.000000E+00,(@0,1);*OPC?", ":VOLT OFF,(@0,1);*OPC?"]
                + per_channel[0] + per_channel[1]
                + [":READ:CHAN:STATUS? (@0,1)", ":READ:CHAN:EVENT:STATUS? (@0,1)", ":MEAS:VOLT? (@0,1)",
                   ":MEAS:VOLT? (@0,1)", ":MEAS:CURR? (@0,1)", ":READ:CHAN:STATUS? (@0,1)",
                   ":READ:CHAN:EVENT:STATUS? (@0,1)"])
    assert lines[:len(expected)] == expected


def test_ramp_to_2400_and_back_follows_on_both_channels(sim, supply, token):
    ramp_both(supply, token, 2400.0)
    assert all(ch.output_on and ch.voltage_set == 2400.0 for ch in sim.plant)  # sent before "done"
    # The device ramp (1.2 x the slew limit) ends within a few cycles.
    assert supply.wait_for(lambda: all(abs(ch.voltage - 2400.0) <= 1.0 and abs(snap.measured_voltage - 2400.0) <= 1.0
                                       for ch, snap in zip(sim.plant, supply.snapshot().channels)), 0.1)
    assert not any(snap.faults for snap in supply.snapshot().channels)
    handles = [supply.ramp_to(name, 0.0, token=token) for name in ("front", "back")]
    assert all(h.wait(5.0) and h.succeeded for h in handles)
    assert all(ch.voltage_set == 0.0 for ch in sim.plant)


def test_request_above_the_ceiling_is_refused_naming_the_limit(supply, token):
    supply.enable("front")
    supply.set_safe_voltage(2000.0)
    with pytest.raises(LimitError, match="assembly safe voltage of 2000 V"):
        supply.ramp_to("front", 2400.0, token=token)
    assert supply.snapshot().channel("front").target == 0.0


def test_cancel_ramps_back_to_zero(sim, supply, token):
    supply.enable("front")
    handle = supply.ramp_to("front", 2400.0, slew_rate_v_per_s=2000.0, token=token)
    supply.wait_cycles(20)
    down = handle.cancel()
    assert handle.wait(5.0) and handle.message == "superseded by a later request"
    assert down.wait(5.0) and down.succeeded and handle.cancel() is None
    assert supply.snapshot().channel("front").setpoint == 0.0 and sim.plant[0].voltage_set == 0.0


# fault name -> (channel injected, expected fault, channels expected to trip)
FAULT_CASES = {
    "over_current": (0, Fault.OVER_CURRENT, ["front"]),
    "no_reply": (None, Fault.LINK, ["front", "back"]),
    "garbled": (None, Fault.LINK, ["front", "back"]),
    "partial": (None, Fault.LINK, ["front", "back"]),
    "disconnect": (None, Fault.LINK, ["front", "back"]),
    "device_reset": (None, Fault.DEVICE, ["front", "back"]),
    "readback_drift": (1, Fault.READBACK_MISMATCH, ["back"]),
}


@pytest.mark.parametrize("fault", list(FAULT_CASES))
def test_every_injected_fault_ends_with_outputs_off_and_the_named_fault(fault, sim, supply, token, clock):
    channel, expected, tripped = FAULT_CASES[fault]
    ramp_both(supply, token, 1500.0)
    sim.inject(fault, channel)

    # A pulled cable leaves the device unreachable: like an iseg module (no host watchdog), the simulator
    # then holds its output; the driver's side must still latch and zero everything.
    device_reachable = fault != "disconnect"

    def tripped_and_off():
        snap = supply.snapshot()
        return all(expected in snap.channel(n).faults for n in tripped) and all(
            not (device_reachable and sim.plant[snap.channel(n).index].output_on) for n in tripped)
    injected = clock()
    assert supply.wait_for(tripped_and_off, 3.0), supply.snapshot()
    # Within the fault's own bound: the link timeout after the first failed exchange (a reply timeout, a quarter
    # of it) and the failing cycle that finds it passed (a resync and a reply timeout); the readback's mismatch
    # time after the drift (500 V/s) leaves the 150 V tolerance; else a cycle or two.
    bound = {Fault.LINK: 0.5 + 3 * 0.125, Fault.READBACK_MISMATCH: 150.0 / 500.0 + 0.2}.get(expected, 0.0)
    assert clock() - injected <= bound + 2 * DEFAULT_PERIOD_S + 1e-9
    supply.wait_cycles(1)  # the readback that confirms the cut (sent in the cycle that read the fault)
    snap = supply.snapshot()
    for name in tripped:
        c = snap.channel(name)
        # Off once the device confirmed it; over a link that fails no reading confirms the cut, so the output is
        # not claimed off (the cut is sent again every cycle).
        assert (c.setpoint, c.output_enabled) == (0.0, expected is Fault.LINK)
        assert expected.name.lower() in c.fault_text
    with pytest.raises(FaultLatchedError):
        supply.enable(tripped[0])


def test_an_interlock_pulse_between_two_polls_is_caught_by_the_event_register(sim, supply, token):
    ramp_both(supply, token, 800.0)
    sim.plant[1].events |= PlantEvent.EXTERNAL_INHIBIT  # the status bit came and went unseen
    assert supply.wait_for(lambda: supply.snapshot().channel("back").faults == Fault.DEVICE)
    assert "event_external_inhibit" in supply.snapshot().channel("back").fault_text
    assert supply.wait_for(lambda: not sim.plant[1].output_on) and sim.plant[0].output_on


def test_faults_stay_latched_until_reset_then_outputs_stay_off_until_enabled(sim, supply, token):
    ramp_both(supply, token, 1000.0)
    sim.inject("device_reset")
    assert supply.wait_for(lambda: supply.snapshot().channel("front").faults == Fault.DEVICE)
    supply.wait_cycles(10)
    assert supply.snapshot().channel("front").faults == Fault.DEVICE
    supply.reset_faults()
    supply.wait_cycles(3)
    assert not any(c.faults for c in supply.snapshot().channels) and all_off(sim)
    assert sim.plant[0].ramp_up == pytest.approx(8000.0 * 1.2)  # device limits restored after the reset
    supply.enable("front")
    assert supply.ramp_to("front", 500.0, token=token).wait(5.0) and sim.plant[0].output_on


def test_device_reset_only_with_outputs_off_and_limits_are_restored(sim, supply):
    supply.enable("front")
    with pytest.raises(RuntimeError, match="switch every output off first"):
        supply.reset_device()
    supply.disable("front")
    assert supply.wait_outputs_off(5.0)
    sim.plant[0].ramp_up = 1.0  # changed behind the driver's back; *RST and reconfiguration restore it
    supply.reset_device()
    supply.wait_cycles(3)
    assert "*RST;*OPC?" in [line for _, line in sim.command_log]
    assert sim.plant[0].ramp_up == pytest.approx(8000.0 * 1.2) and not supply.snapshot().channel("front").faults


def test_lost_heartbeat_ramps_outputs_down_at_the_slew_limit(sim, clock):
    configs = [ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=8000.0)]
    with simulated(sim, clock, configs, heartbeat_timeout_s=0.3) as hv:
        hv.enable("front")
        hv.ramp_to("front", 1000.0, token=hv.claim_control("test"))
        last_sign = clock()
        assert hv.wait_for(lambda: Fault.HEARTBEAT in hv.snapshot().channel("front").faults, 1.0)
        lapsed = clock()
        assert 0.3 < lapsed - last_sign <= 0.3 + DEFAULT_PERIOD_S + 1e-9  # the timeout, to the cycle
        assert hv.wait_for(lambda: not sim.plant[0].output_on, 1.0)
        # A minimum-jerk ramp from 1000 V at the 8 kV/s slew limit: 1.875 x 1000 / 8000 s, then off.
        assert clock() - lapsed == pytest.approx(1.875 * 1000.0 / 8000.0, abs=2 * DEFAULT_PERIOD_S)
        assert not sim.plant[0].emergency  # ramped down and switched off, not cut


@pytest.mark.parametrize("first", ["the control loop's cycle", "the client's next beat"])
def test_a_stall_of_the_whole_process_longer_than_the_timeout_ends_control(sim, clock, first):
    """Driver and client in one stalled process: the client sent nothing for three timeouts, so its control lapses,
    whether the loop's next cycle or the client's next beat comes first, and the output ramps down. (The supervisor
    process hears its node through a channel and reads it before it judges: test_supervisor_process.py.)"""
    configs = [ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=8000.0)]
    with simulated(sim, clock, configs, heartbeat_timeout_s=0.5, link_timeout_s=2.0) as hv:
        token = hv.claim_control("test")
        hv.enable("front")
        assert hv.ramp_to("front", 1000.0, token=token).wait(5.0)
        hv.heartbeat(token)
        clock.advance(1.5)  # three timeouts without a cycle or a beat
        if first == "the control loop's cycle":
            hv.step()
        with pytest.raises(ControlError, match="lapsed: no heartbeat for more than 0.5 s"):
            hv.heartbeat(token)
        assert hv.wait_for(lambda: sim.plant[0].voltage < 50.0, 5.0)
        snap = hv.snapshot()
        assert snap.controller == "" and snap.channel("front").faults == Fault.HEARTBEAT


def test_close_ramps_down_and_switches_off(sim, clock):
    hv = simulated(sim, clock, [ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=8000.0)]).open()
    hv.enable("front")
    assert hv.ramp_to("front", 1200.0, token=hv.claim_control("test")).wait(5.0)
    hv.close()
    assert all_off(sim) and sim.plant[0].voltage_set == 0.0 and not sim.plant[0].emergency


def test_exception_in_the_with_block_cuts_the_outputs(sim, clock):
    with pytest.raises(RuntimeError, match="operator code failed"):
        with simulated(sim, clock, [ChannelConfig("front", 0, max_voltage_v=3000.0)]) as hv:
            hv.enable("front")
            hv.ramp_to("front", 300.0, token=hv.claim_control("test")).wait(5.0)
            raise RuntimeError("operator code failed")
    assert all_off(sim) and sim.plant[0].emergency


def test_a_latched_device_emergency_survives_reconnect_until_reset(sim, clock):
    sim.plant[0].emergency = True
    with simulated(sim, clock, [ChannelConfig("front", 0, max_voltage_v=3000.0)]) as hv:
        assert hv.snapshot().channel("front").faults == Fault.DEVICE
        with pytest.raises(FaultLatchedError, match="is_emergency_off"):
            hv.enable("front")
        hv.reset_faults()
        hv.wait_cycles(3)
        hv.enable("front")
        hv.wait_cycles(3)
        assert sim.plant[0].output_on and not sim.plant[0].emergency


def test_device_that_cannot_take_the_ramp_speed_is_refused_at_open(clock):
    slow = SimulatedSupply(channels=1, defaults=ChannelDefaults(max_ramp_speed=500.0), clock=clock)
    hv = simulated(slow, clock, [ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=1000.0)])
    with pytest.raises(ConfigurationError, match="read_ramp reads 500, configured 1200"):
        hv.open()


def test_the_heartbeat_watchdog_is_on_by_default(sim, clock):
    configs = [ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=8000.0)]
    with simulated(sim, clock, configs) as hv:
        assert hv.snapshot().heartbeat_timeout_s == 2.0
        token = hv.claim_control("client that dies")
        hv.enable("front")
        ramp = hv.ramp_to("front", 1000.0, token=token)
        requested = clock()
        assert ramp.wait(5.0)
        assert hv.wait_for(lambda: Fault.HEARTBEAT in hv.snapshot().channel("front").faults, 10.0)
        # The 2 s timeout ran from the ramp request: judged in the first cycle after it, seen after the next step.
        assert 2.0 < clock() - requested <= 2.0 + 2 * DEFAULT_PERIOD_S + 1e-9
        assert hv.wait_for(lambda: not sim.plant[0].output_on and sim.plant[0].voltage < 1.0, 5.0)
        assert hv.snapshot().controller == ""


def test_switching_the_watchdog_off_takes_inf_and_warns_at_every_open(sim, clock, caplog):
    configs = [ChannelConfig("front", 0, max_voltage_v=3000.0)]
    with pytest.raises(ValueError, match="math.inf to switch the heartbeat watchdog off on purpose"):
        simulated(sim, clock, configs, heartbeat_timeout_s=None)
    caplog.set_level(logging.WARNING, logger="hv_driver")
    for _ in range(2):
        with simulated(sim, clock, configs, heartbeat_timeout_s=math.inf) as hv:
            assert hv.snapshot().heartbeat_timeout_s == math.inf
    warnings = [r for r in caplog.records if "heartbeat watchdog OFF" in r.getMessage()]
    assert len(warnings) == 2 and all(r.levelno == logging.WARNING for r in warnings)


def test_only_the_client_holding_control_ramps(supply, token):
    supply.enable("front")
    other = "f" * 32
    with pytest.raises(ControlError, match="control is held by 'test'"):
        supply.ramp_to("front", 500.0, token=other)
    with pytest.raises(ControlError, match="control is held by 'test'"):
        supply.heartbeat(other)
    with pytest.raises(ControlError, match="held by 'test'"):
        supply.claim_control("intruder")
    snap = supply.snapshot()
    assert snap.channel("front").target == 0.0 and snap.controller == "test" and snap.heartbeat_age_s < 30.0
    assert supply.release_control(token) == "test" and supply.snapshot().controller == ""


def test_reset_faults_leaves_healthy_channels_alone(sim, supply, token):
    ramp_both(supply, token, 2400.0)
    sim.inject("over_current", 1)
    assert supply.wait_for(lambda: Fault.OVER_CURRENT in supply.snapshot().channel("back").faults, 1.0)
    sim.clear_faults()
    assert supply.wait_for(lambda: abs(supply.snapshot().channel("back").measured_current) < 1e-6, 1.0)
    mark = len(sim.command_log)
    assert supply.reset_faults() == ["back"]
    supply.wait_cycles(5)
    sent = [line for _, line in list(sim.command_log)[mark:]]
    assert any("(@1)" in line for line in sent)  # the faulted channel's emergency off is cleared
    assert not [line for line in sent if line.startswith((":VOLT OFF", ":VOLT 0")) and "(@0" in line], sent
    front = supply.snapshot().channel("front")
    assert front.output_enabled and front.setpoint == 2400.0 and not front.faults
    assert sim.plant[0].output_on and sim.plant[0].voltage == pytest.approx(2400.0, abs=1.0)


def test_resetting_every_channel_ramps_healthy_outputs_down_at_the_device_ramp(sim, clock):
    configs = [ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=2000.0)]  # device ramp 2400 V/s
    with simulated(sim, clock, configs, heartbeat_timeout_s=30.0) as hv:
        hv.enable("front")
        assert hv.ramp_to("front", 2400.0, token=hv.claim_control("test")).wait(10.0)
        hv.wait_cycles(3)
        started = clock()
        assert hv.reset_faults(all_channels=True) == ["front"]
        assert hv.wait_for(lambda: sim.plant[0].ramping_down, 0.1)
        assert hv.wait_for(lambda: sim.plant[0].voltage < 1.0, 5.0)
        assert clock() - started == pytest.approx(2400.0 / 2400.0, abs=2 * DEFAULT_PERIOD_S)  # at the ramp, not cut
        hv.wait_cycles(10)
        front = hv.snapshot().channel("front")
        assert not front.faults and not front.output_enabled, front.fault_text
        assert not sim.plant[0].emergency


def test_open_ramps_down_an_output_an_earlier_session_left_on(sim, clock):
    left_on = sim.plant[0]
    left_on.ramp_up = left_on.ramp_down = 2400.0
    left_on.voltage_set = left_on.voltage = 2400.0
    left_on.output_on = True
    configs = [ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=2000.0)]
    with simulated(sim, clock, configs, heartbeat_timeout_s=30.0) as hv:
        assert hv.wait_for(lambda: left_on.voltage < 1.0, 5.0)
        hv.wait_cycles(10)
        assert not hv.snapshot().channel("front").faults, hv.snapshot().channel("front").fault_text
        assert not left_on.emergency


def test_a_channel_index_the_supply_does_not_have_is_refused_at_open(sim, clock):
    hv = simulated(sim, clock, [ChannelConfig("front", 999, max_voltage_v=3000.0)])
    with pytest.raises(ConfigurationError, match=r"channel 'front': index 999 is not on the supply at \S+, which has 2 "
                                                 r"channel\(s\) \(indices 0-1\)"):
        hv.open()
    assert not [line for _, line in sim.command_log if "999" in line]  # nothing sent to it


def test_open_waits_up_to_the_link_timeout_for_a_supply_that_is_starting_up(sim, clock):
    """A supply that answers late at first (still starting up) is identified."""
    sim.inject("no_reply")
    clock.call_at(clock() + 0.2, sim.clear_faults)
    configs = [ChannelConfig("front", 0, max_voltage_v=3000.0)]
    with simulated(sim, clock, configs, link_timeout_s=2.0) as hv:
        assert hv.snapshot().device_id.startswith("iseg")


def test_open_gives_up_on_a_silent_supply_after_the_link_timeout(sim, clock):
    sim.inject("no_reply")
    started = clock()
    with pytest.raises(LinkError, match=r"no reply to '\*IDN\?'"):
        simulated(sim, clock, [ChannelConfig("front", 0, max_voltage_v=3000.0)], link_timeout_s=0.4).open()
    # The set-up is retried for the link timeout, each exchange waiting its reply timeout (a quarter of it).
    assert 0.4 < clock() - started <= 0.4 + 2 * 0.1


def test_open_rides_out_answers_missing_in_the_middle_of_the_set_up(sim, clock):
    """The supply falls silent for 0.3 s right after answering the identification: the set-up is repeated, not
    given up."""
    sim.inject_after("*IDN?", "no_reply")
    clock.call_at(clock() + 0.3, sim.clear_faults)
    configs = [ChannelConfig("front", 0, max_voltage_v=3000.0)]
    with simulated(sim, clock, configs, link_timeout_s=2.0) as hv:
        hv.wait_cycles(3)
        assert not hv.snapshot().channel("front").faults
    assert sum(line == "*IDN?" for _, line in sim.command_log) >= 2  # set up again from the start
