"""A cut is confirmed by the device, never assumed: the silence case of a supply that stops reading its input (a
pulled cable on its receive line) while its output is up, on every dialect, in simulated time. The Keithley 2290
answers no setting, so its cut goes out into the silence without an error; when the unit reads again it has lost the
line it resumed in (the cut's first line) and reports its output on. The driver re-sends the cut every cycle until the
device reports the output off, latches CUT_UNCONFIRMED for a device that reports it on after a cut, and its snapshot
never shows an output off that the device may still hold on."""
import pytest

from dialect_rig import Rig

from hv_driver import Fault
from hv_driver.clock import SimulatedClock
from hv_driver.dialects import DIALECTS

LIMITS = dict(max_voltage_v=3000.0, slew_rate_v_per_s=8000.0, mismatch_tolerance_v=150.0, mismatch_time_s=0.2,
              current_trip_a=100e-6)
# What each dialect shows when the unit comes back: the iseg module and the PPV board answer every setting, so the
# lost line is a failed exchange and the cut is simply sent again; the 2290 does not, and reads back HV on.
RESUMED = {"iseg-edcp": Fault(0), "keithley-2290": Fault.CUT_UNCONFIRMED, "ppv": Fault(0)}


@pytest.fixture(params=list(DIALECTS))
def rig(request):
    made = Rig(request.param, LIMITS, link_timeout_s=0.5, clock=SimulatedClock())
    yield request.param, made
    made.close()


def never_claims_off(made, channel: str):
    """Fails when the snapshot shows ``channel`` off while its device holds the output on."""
    snap = made.supply.snapshot().channel(channel)
    assert snap.output_enabled or not made.plant(channel).output_on, (snap, made.plant(channel))


def test_a_cut_into_a_deaf_supply_is_sent_again_until_the_device_reports_it_off(rig):
    name, made = rig
    made.ramp(600.0)
    sim, _ = made.where["a"]
    made.inject("deaf", "a")
    while Fault.LINK not in made.supply.snapshot().channel("a").faults:
        made.supply.step()
        never_claims_off(made, "a")
    made.supply.run_for(0.5)  # the cut goes out every cycle, unread
    assert made.plant("a").output_on and made.plant("a").voltage == pytest.approx(600.0, abs=5.0)
    snap = made.supply.snapshot().channel("a")
    assert snap.output_enabled and snap.setpoint == 0.0  # commanded 0 V, but not claimed off

    sim.clear_faults()  # the unit reads its input again, starting in the middle of a line
    assert made.supply.wait_for(lambda: not made.supply.snapshot().channel("a").output_enabled, 1.0)
    assert not made.plant("a").output_on and made.plant("a").voltage_set == 0.0
    faults = made.supply.snapshot().channel("a").faults
    assert Fault.LINK in faults and RESUMED[name] in faults, made.supply.snapshot().channel("a").fault_text
    for _ in range(20):  # confirmed: it stays off, and the cut is not sent any more
        made.supply.step()
        never_claims_off(made, "a")
    sent = [line for _, line in list(sim.command_log)[-20:]]
    cut_line = made.supply.dialect.encode("output_off" if name != "iseg-edcp" else "emergency_off", [0])
    assert cut_line not in sent, sent
    if made.where["b"][0] is not sim:  # a supply of its own (two units, two boards) is untouched
        assert made.plant("b").output_on and not made.supply.snapshot().channel("b").faults


def test_the_device_reporting_its_output_on_after_a_cut_latches_cut_unconfirmed_and_is_cut_again(rig):
    """A device that acknowledges the cut's first line as usual but does not act on it (its output stays on): every
    cycle the cut goes out again, and the channel is named CUT_UNCONFIRMED."""
    name, made = rig
    made.ramp(600.0)
    sim, index = made.where["a"]
    dialect = made.supply.dialect
    # The cut's line (on the iseg module of every channel cut: the e-stop cuts both in one line).
    cut = dialect.encode("emergency_off" if dialect.capabilities.emergency_off else "output_off", [index])
    cut = cut.split(",(@")[0]
    acknowledgement = {"iseg-edcp": "1", "keithley-2290": None, "ppv": "0"}[name]
    execute, ignored = sim.execute, []

    def ignoring_the_cut(line):
        if line.startswith(cut):
            ignored.append(line)
            return acknowledgement
        return execute(line)
    sim.execute = ignoring_the_cut
    made.supply.estop()
    made.supply.run_for(0.2)
    snap = made.supply.snapshot().channel("a")
    assert Fault.CUT_UNCONFIRMED in snap.faults and "reports its output on" in snap.fault_text
    assert snap.output_enabled  # as the device reports it
    assert len(ignored) >= 10  # cut again, cycle after cycle
    sim.execute = execute
    assert made.supply.wait_for(lambda: not made.supply.snapshot().channel("a").output_enabled, 0.1)
    assert not made.plant("a").output_on


def test_a_second_cut_after_a_reset_is_sent_and_confirmed_again(rig):
    """A confirmed cut, a reset, the output up again: the next fault's cut goes out and must be confirmed anew (a
    confirmation that outlived the reset left the second e-stop unsent, the output at its voltage)."""
    _, made = rig
    for round_ in range(3):
        made.ramp(600.0)
        assert made.plant("a").output_on and made.plant("a").voltage > 500.0  # up (a regulated output still settling)
        made.supply.estop()
        assert made.supply.wait_for(lambda: not made.supply.snapshot().channel("a").output_enabled, 1.0), round_
        assert not made.plant("a").output_on and not made.plant("b").output_on, round_
        made.supply.reset_faults()
        made.token = made.supply.claim_control("test")  # the e-stop ended the session
        made.supply.run_for(0.05)
