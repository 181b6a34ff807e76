"""HvSupply in real time: its loop in its own thread over a simulated supply on a real pty, and a driver process
ended by a signal. Waits are for events with generous deadlines and the driver's link and readback windows are
longer than any stall of a loaded host, so no outcome depends on the host's speed (timing is tested in simulated
time: test_driver_sim.py, test_dialects_sim.py)."""
import os
import signal
import subprocess
import sys
import textwrap

import pytest
from dialect_rig import (FAST_LIMITS, REAL_TIME_CURRENT_TRIP_A, REAL_TIME_LINK_TIMEOUT_S, REAL_TIME_MISMATCH_TIME_S,
                         WAIT_S, Rig, all_off, ramp_both)
from waiting import GENEROUS_S

from hv_driver import ControlError, Fault, FaultLatchedError
from hv_driver.dialects import DIALECTS

pytestmark = pytest.mark.integration

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.mark.parametrize("name", list(DIALECTS))
def test_every_dialect_ramps_both_channels_on_real_ptys(name, wait_until):
    """The loop in its own thread, each simulator serving a real pty in real time."""
    made = Rig(name, {**FAST_LIMITS, "mismatch_time_s": REAL_TIME_MISMATCH_TIME_S,
                      "current_trip_a": REAL_TIME_CURRENT_TRIP_A},
               link_timeout_s=REAL_TIME_LINK_TIMEOUT_S)
    try:
        made.check_ramps_both_channels(lambda predicate: wait_until(predicate, "the outputs' ramp"))
    finally:
        made.close()


def test_estop_while_another_thread_streams_ramps(pty_sim, pty_supply, background, wait_until):
    """The loop in its own thread: requests from another thread race the e-stop."""
    sim, supply, token = pty_sim, pty_supply, pty_supply.claim_control("test")
    ramp_both(supply, token, 800.0)
    refused = []

    def stream():  # keeps requesting new ramps until 20 requests after the e-stop were refused
        k = 0
        while len(refused) <= 20:
            k += 1
            try:
                supply.heartbeat(token)
                supply.ramp_to("front" if k % 2 else "back", 200.0 + (k * 37) % 1500, token=token)
            except (FaultLatchedError, ControlError) as error:
                refused.append(error)
            supply.wait_cycles(1, timeout=1.0)
    background(stream)
    supply.wait_cycles(5)
    supply.estop()
    wait_until(lambda: all_off(sim) and len(refused) > 20, "the outputs off and 20 requests refused")
    snap = supply.snapshot()
    assert snap.estop and all(c.faults == Fault.ESTOP and not c.output_enabled for c in snap.channels)
    assert all(ch.emergency for ch in sim.plant)  # device-side emergency off, latched
    assert "emergency stop" in str(refused[-1]) and snap.controller == ""  # the e-stop ended the session


def test_sigterm_switches_the_outputs_off(pty_sim):
    """A driver process on a real pty, ended by SIGTERM, cuts its outputs. It holds its output without beating
    (its watchdog off on purpose) until the signal, however long the test takes to send it."""
    sim = pty_sim
    script = textwrap.dedent(f"""
        import math, time
        from hv_driver import ChannelConfig, HvSupply
        hv = HvSupply({sim.port!r}, channels=[ChannelConfig("front", 0, max_voltage_v=3000.0)],
                      link_timeout_s={REAL_TIME_LINK_TIMEOUT_S!r}, heartbeat_timeout_s=math.inf).open()
        hv.enable("front")
        assert hv.ramp_to("front", 400.0, token=hv.claim_control("test")).wait({WAIT_S!r})
        print("ramped", flush=True)
        time.sleep(3600)
    """)
    child = subprocess.Popen([sys.executable, "-c", script], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "ramped"
        assert sim.plant[0].output_on
        child.send_signal(signal.SIGTERM)
        assert child.wait(timeout=GENEROUS_S) == 128 + signal.SIGTERM
    finally:
        child.kill()
        child.stdout.close()
    assert all_off(sim) and sim.plant[0].emergency


def test_the_real_time_loop_ramps_and_trips_on_a_real_pty(pty_sim, pty_supply, wait_until):
    """The loop in its own thread over a real pty ramps both channels and cuts an arc."""
    token = pty_supply.claim_control("test")
    ramp_both(pty_supply, token, 1500.0)
    wait_until(lambda: all(abs(ch.voltage - 1500.0) < 5.0 for ch in pty_sim.plant), "both outputs at 1500 V")
    pty_sim.inject("over_current", 0)
    wait_until(lambda: Fault.OVER_CURRENT in pty_supply.snapshot().channel("front").faults
               and not pty_sim.plant[0].output_on, "the arc cut")
    assert pty_sim.plant[1].output_on and not pty_supply.snapshot().channel("back").faults
