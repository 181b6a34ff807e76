"""Who may command the HV: the control claim and the heartbeat watchdog, in the pure supervisor.

Only the client holding control (its session token) ramps and feeds the watchdog; control ends on
release, on a lapsed heartbeat and at an e-stop; the watchdog is on unless switched off with math.inf."""
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hv_driver import ChannelConfig, ControlError, Fault, Supervisor
from hv_driver.control import FIRST_SIGN_OF_LIFE_S, LOOP_STALL_FRACTION, MAX_CLIENT_NAME, ControlClaim
from hv_driver.supervisor import DEFAULT_HEARTBEAT_TIMEOUT_S

CONFIG = ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=1000.0)


def hold(supervisor: Supervisor, token: str, t0: float, t1: float, dt: float = 0.01, beat: bool = True) -> float:
    """Step from t0 to t1 (heartbeats with ``token`` every step when ``beat``); returns t1."""
    t = t0
    while t < t1 - 1e-12:
        t = min(t + dt, t1)
        if beat:
            supervisor.heartbeat(t, token)
        supervisor.step(t)
    return t1


def energised(heartbeat_timeout_s: float = 0.5) -> tuple[Supervisor, str]:
    """A supervisor whose client 'sequencer' holds control and has ramped front to 1000 V."""
    supervisor = Supervisor([CONFIG], link_timeout_s=100.0, heartbeat_timeout_s=heartbeat_timeout_s)
    supervisor.enable("front", 0.0)
    token = supervisor.claim_control("sequencer", 0.0)
    supervisor.ramp_to("front", 0.0, 1000.0, token=token)
    hold(supervisor, token, 0.0, 2.0)
    assert supervisor.channel("front").setpoint == 1000.0
    return supervisor, token


def test_the_heartbeat_watchdog_is_on_by_default():
    supervisor = Supervisor([CONFIG], link_timeout_s=1.0)
    assert supervisor.heartbeat_timeout_s == DEFAULT_HEARTBEAT_TIMEOUT_S == 2.0
    assert not supervisor.heartbeat_watchdog_off


@pytest.mark.parametrize("timeout", [None, 0.0, -1.0, math.nan, "2"])
def test_the_watchdog_is_never_off_by_omission(timeout):
    with pytest.raises(ValueError, match="math.inf to switch the heartbeat watchdog off on purpose"):
        Supervisor([CONFIG], link_timeout_s=1.0, heartbeat_timeout_s=timeout)


def test_switched_off_on_purpose_the_watchdog_never_trips_and_control_never_lapses():
    supervisor, token = energised(heartbeat_timeout_s=math.inf)
    assert supervisor.heartbeat_watchdog_off
    hold(supervisor, token, 2.0, 1000.0, dt=1.0, beat=False)
    assert not supervisor.channel("front").faults and supervisor.control.owner == "sequencer"


def test_a_claim_answers_a_fresh_token_and_is_refused_while_another_client_holds_control():
    supervisor = Supervisor([CONFIG], link_timeout_s=1.0)
    token = supervisor.claim_control("sequencer", 0.0)
    assert len(token) == 32 and int(token, 16) >= 0
    with pytest.raises(ControlError, match="control is held by 'sequencer' .*release it first or stay silent for 10 s"):
        supervisor.claim_control("demo", 0.5)  # no sign of life yet: the first may take FIRST_SIGN_OF_LIFE_S
    supervisor.heartbeat(0.6, token)
    with pytest.raises(ControlError, match="control is held by 'sequencer' .*release it first or stay silent for 2 s"):
        supervisor.claim_control("demo", 0.7)
    supervisor.release_control(token, 1.0)
    assert supervisor.claim_control("sequencer", 1.0) != token


def test_a_claim_repeated_before_the_first_sign_of_life_gets_the_same_session_and_after_it_is_refused():
    supervisor = Supervisor([CONFIG], link_timeout_s=1.0)
    supervisor.enable("front", 0.0)
    token = supervisor.claim_control("sequencer", 0.0, nonce="n1")
    assert supervisor.claim_control("sequencer", 9.0, nonce="n1") == token  # its first reply was lost; it asks again
    assert supervisor.control.heartbeat_age(9.0) == 0.0  # the repeat is a sign of life, not yet a use
    assert supervisor.claim_control("sequencer", 18.0, nonce="n1") == token  # within 10 s of the repeat: still held
    with pytest.raises(ControlError, match="control is held by 'sequencer'"):
        supervisor.claim_control("demo", 18.5)
    supervisor.ramp_to("front", 18.5, 500.0, token=token)  # used: from now on a repeat is refused
    with pytest.raises(ControlError, match="control is held by 'sequencer' .*release it first or stay silent for 2 s"):
        supervisor.claim_control("sequencer", 18.6, nonce="n1")


def test_a_ramp_without_the_live_token_is_refused_naming_the_owner():
    supervisor = Supervisor([CONFIG], link_timeout_s=1.0)
    supervisor.enable("front", 0.0)
    with pytest.raises(ControlError, match="no client holds control; claim it first"):
        supervisor.ramp_to("front", 0.0, 500.0, token="")
    supervisor.claim_control("sequencer", 0.0)
    with pytest.raises(ControlError, match="control is held by 'sequencer'"):
        supervisor.ramp_to("front", 0.1, 500.0, token="0" * 32)
    assert supervisor.channel("front").target == 0.0


def test_a_replayed_heartbeat_cannot_keep_an_output_energised():
    """A recording of an earlier session replays that session's token: it is not the live one."""
    supervisor = Supervisor([CONFIG], link_timeout_s=100.0, heartbeat_timeout_s=0.5)
    recorded = supervisor.claim_control("sequencer", 0.0)
    supervisor.release_control(recorded, 0.3)
    supervisor.enable("front", 1.0)
    live = supervisor.claim_control("sequencer", 1.0)
    supervisor.ramp_to("front", 1.0, 1000.0, token=live)
    t = hold(supervisor, live, 1.0, 3.0)  # then the live client dies; the recording plays on
    refused = 0
    for k in range(1, 101):
        try:
            supervisor.heartbeat(t + 0.01 * k, recorded)
        except ControlError as error:
            refused += 1
            assert "not its session's" in str(error) or "no client holds control" in str(error)
        supervisor.step(t + 0.01 * k)
    assert refused == 100
    front = supervisor.channel("front")
    assert front.faults == Fault.HEARTBEAT and "'sequencer'" in front.fault_text
    assert supervisor.control.owner is None
    assert front.fault_text == "heartbeat: control of 'sequencer' lapsed: no heartbeat for more than 0.5 s"


def test_control_lapses_with_the_heartbeat_and_its_token_is_dead_for_good():
    supervisor, token = energised()
    hold(supervisor, token, 2.0, 2.6, beat=False)
    assert supervisor.control.owner is None and supervisor.channel("front").faults == Fault.HEARTBEAT
    with pytest.raises(ControlError, match="lapsed: no heartbeat for more than 0.5 s"):
        supervisor.heartbeat(2.61, token)
    assert supervisor.claim_control("demo", 2.7) != token


def test_a_client_that_learns_its_token_late_still_holds_control():
    """On a lossy link the claim's reply can arrive seconds later (resent at the transport's next heartbeat):
    the session waits FIRST_SIGN_OF_LIFE_S for the first heartbeat, then the usual timeout applies."""
    supervisor = Supervisor([CONFIG], link_timeout_s=100.0, heartbeat_timeout_s=2.0)
    token = supervisor.claim_control("sequencer", 0.0)
    hold(supervisor, token, 0.0, 3.5, beat=False)
    supervisor.heartbeat(3.5, token)  # 3.5 s after the claim, beyond the 2 s timeout
    supervisor.enable("front", 3.5)
    supervisor.ramp_to("front", 3.5, 500.0, token=token)
    hold(supervisor, token, 3.5, 5.4, beat=False)
    assert supervisor.control.owner == "sequencer" and not supervisor.channel("front").faults
    hold(supervisor, token, 5.4, 5.6, beat=False)  # from the first sign of life on, 2 s of silence end the session as always
    assert supervisor.control.owner is None and supervisor.channel("front").faults == Fault.HEARTBEAT


def test_a_claim_that_never_shows_a_sign_of_life_lapses_after_the_first_sign_wait():
    supervisor = Supervisor([CONFIG], link_timeout_s=100.0, heartbeat_timeout_s=2.0)
    supervisor.claim_control("sequencer", 0.0)
    supervisor.step(FIRST_SIGN_OF_LIFE_S - 0.1)
    assert supervisor.control.owner == "sequencer"
    supervisor.step(FIRST_SIGN_OF_LIFE_S + 0.1)
    assert supervisor.control.owner is None
    assert supervisor.control.ended == f"control of 'sequencer' lapsed: no heartbeat for more than {FIRST_SIGN_OF_LIFE_S:g} s"
    supervisor.claim_control("demo", FIRST_SIGN_OF_LIFE_S + 0.2)


def test_a_new_client_never_inherits_outputs_a_lapsed_session_left_energised():
    """The old client's silence is noticed by the claim itself, before the control loop's next cycle: what it
    left energised trips, and the new session starts with nothing raised."""
    supervisor, token = energised(heartbeat_timeout_s=0.5)
    hold(supervisor, token, 2.0, 2.45, beat=False)  # the old client fell silent at 2.0
    supervisor.claim_control("demo", 2.52)  # before the loop's next cycle
    front = supervisor.channel("front")
    assert front.faults == Fault.HEARTBEAT and front.target == 0.0
    assert "control of 'sequencer' lapsed" in front.fault_text


def test_release_ramps_the_outputs_the_session_left_energised_down_without_a_fault():
    supervisor, token = energised()
    supervisor.release_control(token, 2.0)
    commands = [supervisor.step(2.0 + 0.01 * k)["front"] for k in range(1, 300)]
    front = supervisor.channel("front")
    assert not front.faults and front.output_enabled and front.setpoint == 0.0
    assert any(0.0 < c.setpoint < 1000.0 for c in commands)  # ramped, not cut


def test_the_estop_is_open_to_everyone_and_ends_the_control_session():
    supervisor, token = energised()
    supervisor.estop()
    assert supervisor.estop_latched and supervisor.control.owner is None
    with pytest.raises(ControlError, match=r"no client holds control \(control ended by an emergency stop\)"):
        supervisor.heartbeat(2.1, token)


@pytest.mark.parametrize("client", ["", "   ", "x" * (MAX_CLIENT_NAME + 1), "two\nlines", None, 7])
def test_bad_client_names_are_refused_naming_the_rule(client):
    with pytest.raises(ValueError, match="a printable name of 1 to 64 characters"):
        Supervisor([CONFIG], link_timeout_s=1.0).claim_control(client, 0.0)


@settings(deadline=None)  # hypothesis's per-example deadline is wall-clock time
@given(st.one_of(st.none(), st.text(max_size=80), st.binary(max_size=40), st.integers(), st.floats()))
def test_no_token_but_the_live_one_is_accepted(token):
    claim = ControlClaim(timeout_s=2.0)
    live = claim.claim("sequencer", 0.0)
    if token == live:
        claim.confirm(token, 0.1)
    else:
        with pytest.raises(ControlError, match="held by 'sequencer'"):
            claim.confirm(token, 0.1)
    assert claim.owner == "sequencer"


@settings(deadline=None)  # hypothesis's per-example deadline is wall-clock time
@given(timeout=st.floats(min_value=0.05, max_value=5.0),
       gaps=st.lists(st.floats(min_value=0.0, max_value=15.0), min_size=1, max_size=30))
def test_control_lapses_exactly_when_a_heartbeat_gap_exceeds_the_timeout(timeout, gaps):
    """The first gap (claim to first heartbeat) may last up to FIRST_SIGN_OF_LIFE_S, every later one the timeout."""
    supervisor = Supervisor([CONFIG], link_timeout_s=100.0, heartbeat_timeout_s=timeout)
    token, t = supervisor.claim_control("sequencer", 0.0), 0.0
    for k, gap in enumerate(gaps):
        previous, t = t, t + gap
        if t - previous > (max(timeout, FIRST_SIGN_OF_LIFE_S) if k == 0 else timeout):  # the gap as the clock sees it
            with pytest.raises(ControlError, match="lapsed"):
                supervisor.heartbeat(t, token)
            return
        supervisor.heartbeat(t, token)
    assert supervisor.control.owner == "sequencer"


# --- stalls of the driver's own loop ---------------------------------------------------------------------
@pytest.mark.parametrize("first", ["the control loop's cycle", "a queued heartbeat"])
def test_a_stall_of_the_driver_longer_than_the_timeout_keeps_a_client_that_kept_beating(first):
    """The driver's process stalls past the 2 s timeout (seen: 1.6 s on a quiet 2-core host) while its client
    beats on. The beats wait in the transport's buffers; after the stall, whichever runs first (the loop's cycle,
    or the executor taking a queued beat) must not find the last one 2.5 s old and end control."""
    supervisor, token = energised(heartbeat_timeout_s=2.0)
    hold(supervisor, token, 2.0, 3.0)
    resumed = 3.0 + 2.5  # nothing of the driver ran for 2.5 s
    if first == "the control loop's cycle":
        supervisor.step(resumed)
    supervisor.heartbeat(resumed + 0.001, token)
    hold(supervisor, token, resumed + 0.001, resumed + 1.0)
    assert supervisor.control.owner == "sequencer" and not supervisor.channel("front").faults


def test_after_a_stall_of_the_whole_host_the_client_has_time_to_beat_again():
    """The client stalled with the driver (one host): its next beat comes after the stall, across the link."""
    supervisor, token = energised(heartbeat_timeout_s=2.0)
    hold(supervisor, token, 2.0, 3.0)
    hold(supervisor, token, 3.0 + 5.0, 3.0 + 5.0 + 0.5, beat=False)  # 5 s stall, then 0.5 s to the next beat
    supervisor.heartbeat(8.5, token)
    assert supervisor.control.owner == "sequencer" and not supervisor.channel("front").faults


def test_a_client_that_died_before_a_stall_still_lapses_after_it():
    supervisor, token = energised(heartbeat_timeout_s=2.0)
    hold(supervisor, token, 2.0, 3.0)  # the last beat at 3.0
    hold(supervisor, token, 3.0, 4.0, beat=False)
    supervisor.step(4.0 + 10.0)  # a 10 s stall counts as LOOP_STALL_FRACTION of the timeout
    due = 14.0 + 2.0 - (1.0 + LOOP_STALL_FRACTION * 2.0)  # the silence counted so far: 1 s, then the stall's share
    hold(supervisor, token, 14.0, due - 0.02, beat=False)
    assert supervisor.control.owner == "sequencer"
    hold(supervisor, token, due - 0.02, due + 0.02, beat=False)
    assert supervisor.control.owner is None and supervisor.channel("front").faults == Fault.HEARTBEAT


@settings(deadline=None)  # hypothesis's per-example deadline is wall-clock time
@given(timeout=st.floats(min_value=0.05, max_value=5.0),
       cycles=st.lists(st.tuples(st.floats(min_value=0.001, max_value=3.0), st.booleans()), min_size=1, max_size=80))
def test_a_silent_client_lapses_no_earlier_than_the_timeout_and_no_later_than_the_drivers_stalls_allow(
        timeout, cycles):
    """Control loop cycles after random gaps (some of them stalls), heartbeats on some cycles. The session
    never lapses while the client's last beat is within the timeout of the clock, and it lapses once the
    silence, less what of it the driver's loop was stalled beyond LOOP_STALL_FRACTION of the timeout per
    gap, exceeds the timeout. A loop that never stalls times the watchdog exactly."""
    supervisor = Supervisor([CONFIG], link_timeout_s=1e9, heartbeat_timeout_s=timeout)
    token, t = supervisor.claim_control("sequencer", 0.0), 0.0
    supervisor.heartbeat(0.0, token)
    supervisor.step(0.0)
    last_beat, stalled = 0.0, 0.0  # stalled: [s] of the silence beyond the most a gap counts
    for gap, beat in cycles:
        t += gap
        stalled += max(0.0, gap - LOOP_STALL_FRACTION * timeout)
        supervisor.step(t)
        if t - last_beat <= timeout:
            assert supervisor.control.owner == "sequencer"
        if t - last_beat - stalled > timeout * (1 + 1e-9):
            assert supervisor.control.owner is None
            return
        if supervisor.control.owner is None:  # within rounding of the bound
            assert t - last_beat - stalled == pytest.approx(timeout)
            return
        if beat:
            supervisor.heartbeat(t, token)
            last_beat, stalled = t, 0.0
    assert supervisor.control.owner == "sequencer"
