"""Commands signed with the session token: the token never travels after the claim's reply, each counter counts
once, and a signature covers its command's content, so copies and recordings of a client's messages command
nothing. And only the claim that got a session, resent, gets it again."""
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hv_driver import ChannelConfig, ControlError, Fault, Supervisor
from hv_driver.control import (HEARTBEAT, RELEASE, REPLAY_WINDOW, ControlClaim, SessionKey, command_mac,
                               pulse_command, ramp_command, session_id, signed)

pytestmark = pytest.mark.fast

CONFIG = ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=1000.0)


def claimed(timeout_s: float = 0.5) -> tuple[Supervisor, SessionKey]:
    supervisor = Supervisor([CONFIG], link_timeout_s=100.0, heartbeat_timeout_s=timeout_s)
    supervisor.enable("front", 0.0)
    return supervisor, SessionKey(supervisor.claim_control("sequencer", 0.0, nonce="a"))


def credential(key: SessionKey, command) -> str:
    return signed(*key.sign(command))


def test_the_session_id_names_the_session_without_revealing_its_token():
    supervisor, key = claimed()
    token = supervisor.control._token
    assert key.session == session_id(token) == supervisor.control.session and token not in key.session
    session, counter, mac = key.sign(HEARTBEAT)
    assert token not in f"{session}{counter}{mac}" and (session, counter) == (key.session, 1)


def test_a_copied_heartbeat_is_refused_and_copies_alone_let_control_lapse():
    supervisor, key = claimed()
    supervisor.ramp_to("front", 0.0, 1000.0, token=credential(key, ramp_command("front", 1000.0, None)))
    t, heard = 0.0, None
    while t < 2.0:  # the live client beats; a subscriber keeps every heartbeat it saw
        t += 0.01
        heard = credential(key, HEARTBEAT)
        supervisor.heartbeat(t, heard)
        supervisor.step(t)
    assert supervisor.channel("front").setpoint == 1000.0
    for k in range(1, 101):  # the client died; the subscriber re-sends what it heard
        t = 2.0 + 0.01 * k
        with pytest.raises(ControlError, match="a copied or replayed command|lapsed: no heartbeat for more than 0.5 s"):
            supervisor.heartbeat(t, heard)
        supervisor.step(t)
    front = supervisor.channel("front")
    assert front.faults == Fault.HEARTBEAT and supervisor.control.owner is None


def test_a_heartbeats_signature_neither_ramps_nor_releases_and_a_goals_signs_only_its_own_content():
    supervisor, key = claimed()
    heartbeat = key.sign(HEARTBEAT)
    with pytest.raises(ControlError, match="signature does not match"):
        supervisor.ramp_to("front", 0.1, 800.0, token=signed(*heartbeat))
    with pytest.raises(ControlError, match="signature does not match"):
        supervisor.release_control(signed(*heartbeat), 0.1)
    goal = key.sign(ramp_command("front", 100.0, None))
    with pytest.raises(ControlError, match="signature does not match"):
        supervisor.ramp_to("front", 0.1, 2400.0, token=signed(*goal))  # the fields of a 100 V goal, 2400 V asked
    supervisor.ramp_to("front", 0.1, 100.0, token=signed(*goal))
    assert supervisor.channel("front").target == 100.0 and supervisor.control.owner == "sequencer"


def test_a_replayed_release_and_ramp_of_an_earlier_session_do_nothing_to_the_live_one():
    supervisor, old = claimed(timeout_s=2.0)
    ramp = credential(old, ramp_command("front", 500.0, None))
    release = credential(old, RELEASE)
    supervisor.ramp_to("front", 0.0, 500.0, token=ramp)
    assert supervisor.release_control(release, 0.5) == "sequencer"
    live = SessionKey(supervisor.claim_control("sequencer", 1.0, nonce="b"))
    supervisor.heartbeat(1.1, credential(live, HEARTBEAT))
    for replayed in (ramp, release):
        with pytest.raises(ControlError, match=f"for session {old.session}, not its session {live.session}"):
            supervisor.release_control(replayed, 1.2) if replayed is release else \
                supervisor.ramp_to("front", 1.2, 500.0, token=replayed)
    assert supervisor.control.owner == "sequencer" and supervisor.control.session == live.session


def test_a_pulse_is_signed_over_its_whole_waveform():
    claim = ControlClaim(timeout_s=2.0)
    key = SessionKey(claim.claim("gait", 0.0))
    command = pulse_command(["a", "b"], 600.0, 5.0, 0.5, 0.0, 10, "smooth", None)
    fields = key.sign(command)
    longer = pulse_command(["a", "b"], 600.0, 5.0, 0.5, 0.0, 1000, "smooth", None)
    with pytest.raises(ControlError, match="signature does not match"):
        claim.confirm(signed(*fields), 0.1, longer)
    claim.confirm(signed(*fields), 0.1, command)


def test_only_the_same_claim_resent_gets_the_same_session():
    """Two clients claiming at the same moment under one name: the second is refused, never given the token."""
    claim = ControlClaim(timeout_s=2.0)
    token = claim.claim("sequencer", 0.0, nonce="first")
    with pytest.raises(ControlError, match="control is held by 'sequencer'"):
        claim.claim("sequencer", 0.01, nonce="second")
    with pytest.raises(ControlError, match="control is held by 'sequencer'"):
        claim.claim("sequencer", 0.01)  # without a nonce, never a repeat
    assert claim.claim("sequencer", 0.5, nonce="first") == token


@given(first=st.text(st.characters(exclude_categories=("Cs",)), min_size=1, max_size=64).filter(str.isprintable),
       other=st.text(st.characters(exclude_categories=("Cs",)), max_size=64).filter(str.isprintable))
def test_any_printable_nonce_resent_gets_the_same_session_and_no_other_nonce_does(first, other):
    """Non-ASCII nonces too (a claim with one was left unanswered: its comparison raised)."""
    claim = ControlClaim(timeout_s=2.0)
    token = claim.claim("sequencer", 0.0, nonce=first)
    assert claim.claim("sequencer", 0.5, nonce=first) == token
    if other != first:
        with pytest.raises(ControlError, match="control is held by 'sequencer'"):
            claim.claim("sequencer", 0.5, nonce=other)


@pytest.mark.parametrize("nonce", [None, 7, "x" * 65, "bad\nnonce"])
def test_a_malformed_nonce_is_refused_naming_the_rule(nonce):
    with pytest.raises(ValueError, match="nonce=.*printable, at most 64 characters"):
        ControlClaim(timeout_s=2.0).claim("sequencer", 0.0, nonce=nonce)


@given(st.lists(st.integers(-5, 3 * REPLAY_WINDOW), max_size=200))
def test_each_counter_is_accepted_once_and_none_older_than_the_window(counters):
    claim = ControlClaim(timeout_s=2.0)
    token = claim.claim("sequencer", 0.0)
    session, accepted, newest = session_id(token), set(), 0
    for counter in counters:
        fields = signed(session, counter, command_mac(token, session, counter, HEARTBEAT)) if counter >= 0 else \
            f"{session}:{counter}:{'0' * 64}"
        expected = counter > 0 and counter not in accepted and counter > newest - REPLAY_WINDOW
        try:
            claim.confirm(fields, 0.1, HEARTBEAT)
            assert expected, f"counter {counter} accepted again or too old (newest {newest})"
            accepted.add(counter)
            newest = max(newest, counter)
        except ControlError:
            assert not expected, f"fresh counter {counter} refused (newest {newest})"


@given(session=st.text(max_size=20), counter=st.integers(0, 2**64), mac=st.text(max_size=70),
       command=st.sampled_from([HEARTBEAT, RELEASE, ramp_command("front", 800.0, None)]))
def test_no_forged_command_is_accepted(session, counter, mac, command):
    claim = ControlClaim(timeout_s=2.0)
    token = claim.claim("sequencer", 0.0)
    live = session_id(token)
    if session == live and mac == command_mac(token, live, counter, command):
        return  # the one genuine signature (never drawn in practice)
    with pytest.raises(ControlError, match="refused: control is held by 'sequencer'"):
        claim.confirm(signed(session, counter, mac), 0.1, command)
    assert claim.owner == "sequencer"
