"""Who may command the HV: the control claim and the heartbeat watchdog, in the pure supervisor.

Only the client holding control (its session token) ramps and feeds the watchdog; control ends on
release, on a lapsed heartbeat and at an e-stop; the watchdog is on unless switched off with math.inf."""
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hv_driver import ChannelConfig, ControlError, Fault, Supervisor
from hv_driver.control import FIRST_SIGN_OF_LIFE_S, MAX_CLIENT_NAME, ControlClaim
from hv_driver.supervisor import DEFAULT_HEARTBEAT_TIMEOUT_S

pytestmark = pytest.mark.fast

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


# --- stalls of the driver's own process: signs of life count from when they were sent -----------------------------
def test_beats_that_waited_in_the_channel_through_a_stall_longer_than_the_timeout_keep_the_client():
    """The supervisor's process stalls 2.5 s, past the 2 s timeout, while its client beats on: the beats wait in the
    channel with their sending stamps and are taken in before the loop judges the silence (`HvSupply.listen`)."""
    supervisor, token = energised(heartbeat_timeout_s=2.0)
    hold(supervisor, token, 2.0, 3.0)
    resumed = 3.0 + 2.5  # nothing of the supervisor ran from 3.0 to 5.5
    for sent in np.arange(3.1, resumed, 0.1):
        supervisor.heartbeat(resumed, token, sent=sent)
    supervisor.step(resumed)
    hold(supervisor, token, resumed, resumed + 1.0)
    assert supervisor.control.owner == "sequencer" and not supervisor.channel("front").faults


def test_a_client_that_died_before_a_stall_lapses_at_the_first_cycle_after_it():
    """Nothing waits in the channel: the silence is the time since the last beat, the stall included."""
    supervisor, token = energised(heartbeat_timeout_s=2.0)
    hold(supervisor, token, 2.0, 3.0)  # the last beat at 3.0
    hold(supervisor, token, 3.0, 4.0, beat=False)
    supervisor.step(4.0 + 10.0)
    assert supervisor.control.owner is None and supervisor.channel("front").faults == Fault.HEARTBEAT


def test_a_beat_that_waited_in_the_channel_counts_from_when_it_was_sent():
    """The client's last beat, sent at 3.0, is taken in at 4.9 after a stall: its silence is counted from 3.0."""
    supervisor, token = energised(heartbeat_timeout_s=2.0)
    hold(supervisor, token, 2.0, 3.0)
    supervisor.heartbeat(4.9, token, sent=3.0)
    supervisor.step(4.99)
    assert supervisor.control.owner == "sequencer"
    supervisor.step(5.01)
    assert supervisor.control.owner is None and supervisor.channel("front").faults == Fault.HEARTBEAT


def test_a_beat_sent_after_the_silence_lapsed_is_refused():
    supervisor, token = energised(heartbeat_timeout_s=2.0)
    hold(supervisor, token, 2.0, 3.0)
    with pytest.raises(ControlError, match="lapsed"):
        supervisor.heartbeat(5.5, token, sent=5.2)  # sent 2.2 s after the last one, whenever it is taken in
    assert supervisor.control.owner is None


@settings(deadline=None)  # hypothesis's per-example deadline is wall-clock time
@given(timeout=st.floats(min_value=0.05, max_value=5.0),
       beats=st.lists(st.tuples(st.floats(min_value=0.001, max_value=3.0), st.floats(min_value=0.0, max_value=10.0)),
                      min_size=1, max_size=60),
       cycle=st.floats(min_value=0.001, max_value=1.0))
@example(timeout=2.0, beats=[(1.75, 1.0), (0.5, 0.0)], cycle=0.8125)  # a delayed beat holds back the next one
def test_control_lapses_exactly_when_the_client_stops_sending_whatever_the_stalls(timeout, beats, cycle):
    """Heartbeats sent after random gaps, each taken in after a random delay (the supervisor stalled, the beat waiting
    in its channel behind those sent before it: one client's beats arrive in order), at the latest by the next control
    cycle, which judges only after what was sent before it has been taken in. The session lapses when, and only when,
    the time between two beats sent (or from the last one to a cycle) exceeds the timeout: stalls neither end a live
    client's session nor delay a dead one's lapse."""
    supervisor = Supervisor([CONFIG], link_timeout_s=1e9, heartbeat_timeout_s=timeout)
    token = supervisor.claim_control("sequencer", 0.0)
    supervisor.heartbeat(0.0, token)
    sent = np.cumsum([gap for gap, _ in beats])
    cycles = np.arange(1, int((sent[-1] + timeout) / cycle) + 3) * cycle
    taken_in = np.maximum.accumulate([min(at + delay, cycles[np.searchsorted(cycles, at)])
                                      for at, (_, delay) in zip(sent, beats)])  # first in, first out
    events = [(when, 0, at) for when, at in zip(taken_in, sent)]
    events += [(now, 1, now) for now in cycles]
    for now, is_cycle, at in sorted(events):  # a beat taken in at a cycle's time comes before its judgement
        if not is_cycle:
            try:
                supervisor.heartbeat(now, token, sent=at)
            except ControlError:  # lapsed before it was sent
                pass
            continue
        supervisor.step(now)
        gaps = np.diff([0.0, *sent[sent <= now], now])
        if np.all(gaps < timeout * (1 - 1e-9)):
            assert supervisor.control.owner == "sequencer", (now, gaps)
        if np.any(gaps > timeout * (1 + 1e-9)):
            assert supervisor.control.owner is None, (now, gaps)
            return
