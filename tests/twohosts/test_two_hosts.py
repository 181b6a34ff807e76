"""The stack on two hosts, emulated on this machine (netlab: two network namespaces joined by a user-space
link): the HV driver (simulated supply) on the rig, assembly state, planner, simulated arm, sequencer and
recorder on the workstation, an HV console on each. Root only (namespaces, TAP devices); CI runs as root.

- the six-step grasp succeeds across a link with 50 +- 10 ms delay and 5 % loss, and a recording on the
  workstation holds every hv/state sample the driver sent in that time (checked against the rig's own console);
- heartbeats keep control over a 30 % lossy link (each is taken best effort: the newest counts);
- a partition at 2.4 kV mid-grasp: every channel below 50 V within heartbeat timeout + ramp time (+ the
  stalls of the driver's process that its own stamps show) with the fault named; the sequencer reports the
  lost driver within its own timeouts; nothing crosses the cut link (the recording reports the gap); after the
  link returns nothing is energised until a client claims control again after a fault reset.
"""
import os
import time

import pytest
from mcap.reader import make_reader
from waiting import GENEROUS_S, wait_until

from hv_driver.ramp import MIN_JERK_PEAK_RATE
from netlab import Conditions, EmulatedHosts, unavailable_reason
from netlab.stack import (SEQUENCER_PARAMETERS, SEQUENCER_STATE_TIMEOUT_S, TwoHostStack, channels_below,
                          driver_lost_logged, driver_stalls, step_durations)
from recording.analysis import load
from recording.mcap_file import recover

reason = unavailable_reason()
# stack: `make test` runs these after the other tiers, first, beside the demo (tests/conftest.py)
pytestmark = [pytest.mark.skipif(reason is not None, reason=f"two emulated hosts: {reason}"), pytest.mark.stack]

STARTUP_TIMEOUT = 120.0  # [s] three launchers and six nodes on two loaded cores
GRASP_TIMEOUT = 240.0    # [s] the grasp takes about 50 s
LOSSY = Conditions(delay_s=0.05, jitter_s=0.01, loss=0.05)
HEARTBEAT_TIMEOUT_S = 2.0     # config/hv_driver.yaml
SLEW_RATE_V_PER_S = 1000.0    # config/hv_driver.yaml
PEAK_V = 2400.0               # config/sequences/finger_grasp.yaml
SAFE_V = 50.0
# The sequencer's timeouts in the partition test: hv/state older than state_timeout_s is a lost driver (as in
# config/sequencer.yaml); then its safe stop waits up to safe_stop_timeout_s for the ramps down, an e-stop and the
# release of control up to server_timeout_s each for the service and for the reply. Until the cut the link is
# perfect, so a server wait need not cover a lossy link's repairs (netlab.stack widens it to 10 s for the lossy
# grasp), and a ramp-down from the peak takes its min-jerk time at the driver's slew limit (a second more is room
# for a loaded host). Across the cut every one of these waits runs out, as it would with longer ones.
STATE_TIMEOUT_S, SERVER_TIMEOUT_S = SEQUENCER_STATE_TIMEOUT_S, 5.0
SAFE_STOP_TIMEOUT_S = MIN_JERK_PEAK_RATE * PEAK_V / SLEW_RATE_V_PER_S + 1.0
PARTITION_SEQUENCER = {**SEQUENCER_PARAMETERS, "server_timeout_s": SERVER_TIMEOUT_S,
                       "safe_stop_timeout_s": SAFE_STOP_TIMEOUT_S}
SEQUENCER_REPORT_BOUND_S = STATE_TIMEOUT_S + SAFE_STOP_TIMEOUT_S + 4 * SERVER_TIMEOUT_S


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    out = tmp_path_factory.mktemp("two_hosts")
    with EmulatedHosts(("rig", "workstation"), seed=16) as hosts, \
            TwoHostStack(hosts, out, int(os.environ["ROS_DOMAIN_ID"])) as stack:
        stack.hosts, stack.out = hosts, out
        stack.workstation.wait_state(lambda state: True, STARTUP_TIMEOUT)  # hv/state crossed the link
        yield stack


@pytest.fixture
def clean(lab):
    """Perfect link, no latched faults (the start-up on loaded cores may starve the simulated supply)."""
    lab.hosts.set_conditions(Conditions())
    lab.hosts.heal()
    reply = lab.workstation.command("reset")
    assert reply["ok"], reply
    return lab


def run_grasp(lab, log_name: str) -> tuple[int, str]:
    process = lab.start_sequence("finger_grasp", log_name)
    code = process.wait(GRASP_TIMEOUT)
    return code, (lab.out / f"{log_name}.log").read_text()


def test_across_a_link_with_delay_and_loss_the_grasp_succeeds_and_the_recording_has_every_sample(clean):
    """One grasp shows both: the whole grasp crosses the link (a clean link is the easier case), and a
    recording on the far host misses none of its samples."""
    recording = clean.out / "lossy.mcap"
    recorder = clean.start_recorder(recording, log_name="recorder_lossy")
    first = min(wait_until(lambda: recorded_so_far(recording), "an hv/state sample in the recording"))
    clean.hosts.set_conditions(LOSSY)
    before = clean.hosts.stats()
    code, log = run_grasp(clean, "grasp_lossy")
    after, last = clean.hosts.stats(), max(state["sequence"] for state in clean.rig.states())
    clean.hosts.set_conditions(Conditions())
    # The recorder reads reliably, in order: a sample lost near the end holds back the ones after it until the
    # driver's writer repairs it, at its next periodic heartbeat.
    wait_until(lambda: max(recorded_so_far(recording), default=first) >= last,
               f"the grasp's last sample ({last}) in the recording")
    assert clean.hosts.stop(recorder) == 0
    assert code == 0, log[-3000:]
    assert "all 12 steps succeeded" in log and len(step_durations(log)) == 12
    delivered = {way: after[way]["delivered"] - before[way]["delivered"] for way in ("a_to_b", "b_to_a")}
    assert delivered["a_to_b"] > 1000 and delivered["b_to_a"] > 100, delivered  # it crossed the link
    lost = after["a_to_b"]["lost"] - before["a_to_b"]["lost"]
    assert lost > 0.02 * (after["a_to_b"]["received"] - before["a_to_b"]["received"])  # the link did lose
    report = load(str(recording)).lost_samples["/hv/state"]
    assert report["checked"] and report["lost"] == 0, report
    # What the driver sent from before the grasp (the recorder already had a sample) to its end, as its own host
    # saw it (the rig's console), is all in the recording.
    sent = {state["sequence"] for state in clean.rig.states() if first <= state["sequence"] <= last}
    recorded = recorded_sequences(recording)
    assert len(sent) > 1000 and min(recorded) == first and max(recorded) >= last, (first, last, len(sent))
    missing = sent - recorded
    assert not missing, f"{len(missing)} of {len(sent)} samples missing: {sorted(missing)[:20]}"


def recorded_sequences(path) -> set[int]:
    with open(path, "rb") as stream:
        return {message.sequence for _, _, message in make_reader(stream).iter_messages(topics=["/hv/state"])}


def recorded_times(path) -> list[tuple[float, float]]:
    """(sent, received) of every hv/state sample in a recording: the driver's source and the recorder's receipt
    timestamps [s, time.time()]."""
    with open(path, "rb") as stream:
        return [(message.publish_time / 1e9, message.log_time / 1e9)
                for _, _, message in make_reader(stream).iter_messages(topics=["/hv/state"])]


def recorded_so_far(recording) -> set[int]:
    """The hv/state samples a recorder still writing ``recording`` has flushed to it (its readable prefix)."""
    so_far = recording.with_name(f"{recording.stem}.so_far.mcap")
    return recorded_sequences(so_far) if recover(str(recording), str(so_far), overwrite=True).success else set()


def stamp_near(states: list[dict], sequence: int, later: bool) -> float:
    """The driver's stamp of sample ``sequence``, or of the nearest one the console saw (later or earlier)."""
    seen = [s for s in states if (s["sequence"] >= sequence if later else s["sequence"] <= sequence)]
    return (min if later else max)(seen, key=lambda s: s["sequence"])["stamp"]


def receipt_gaps(states: list[dict], longer_than_s: float = 0.5) -> list[float]:
    """Gaps longer than ``longer_than_s`` between a console's receipts of hv/state (its own stalls, or the link's)."""
    times = sorted(state["t"] for state in states)
    return [round(after - before, 2) for before, after in zip(times, times[1:]) if after - before > longer_than_s]


def test_heartbeats_keep_control_over_a_very_lossy_link(clean):
    """No lapse over four heartbeat timeouts of the driver's own time on a 30 % lossy link; then the link is cut,
    and the same record shows the lapse (so it would have shown one before)."""
    console = clean.workstation
    assert console.command("claim link tester")["ok"]
    try:
        assert console.command("ramp front 500")["ok"]
        clean.hosts.set_conditions(Conditions(delay_s=0.05, jitter_s=0.01, loss=0.3))
        since = time.time()
        until = clean.rig.wait_state(lambda state: state["stamp"] >= since + 4 * HEARTBEAT_TIMEOUT_S,
                                     GENEROUS_S, since)["stamp"]
        states = [state for state in clean.rig.states(since) if since <= state["stamp"] <= until]
        # The driver does not count its own stalls as the client's silence (hv_driver.control), so neither
        # does this test; when it fails, the stalls of each side tell a stalled host from a lost link.
        stalls = driver_stalls(states, since, until)
        seen = (f"the driver's stalls {[round(stall, 2) for stall in stalls]} s, gaps in the hv/state the "
                f"workstation's console took {receipt_gaps(console.states(since))} s, load average "
                f"{os.getloadavg()[0]:.1f}")
        assert states and not any(state["channels"]["front"]["faults"] for state in states), \
            f"{states[-1]['channels']['front']['fault_text']}; {seen}"
        assert all(state["channels"]["front"]["voltage_v"] > 450.0 for state in states)
        clean.hosts.partition()
        lapsed = clean.rig.wait_state(lambda state: state["channels"]["front"]["faults"], GENEROUS_S, until)
        assert "heartbeat: control of 'link tester' lapsed" in lapsed["channels"]["front"]["fault_text"]
    finally:
        clean.hosts.heal()
        clean.hosts.set_conditions(Conditions())
        console.command("release")
    clean.rig.wait_state(lambda state: channels_below(state, SAFE_V), STARTUP_TIMEOUT, since=time.time())


def test_a_partition_at_2_4_kv_ramps_down_reports_and_stays_off_until_asked_again(clean):
    clean.restart_sequencer(PARTITION_SEQUENCER)  # it starts while the recorder does
    recording = clean.out / "partition.mcap"
    recorder = clean.start_recorder(recording, log_name="recorder_partition")
    wait_until(lambda: recorded_so_far(recording), "an hv/state sample in the recording")
    clean.wait_sequencer_serving()
    grasp, high = clean.start_grasp_to_peak(PEAK_V - SAFE_V, "grasp_partition", GRASP_TIMEOUT)
    assert high is not None, (clean.out / "grasp_partition.log").read_text()[-3000:]  # it failed before its peak
    # The workstation sees the driver's samples up to the cut: the record below would show one that crossed it.
    clean.workstation.wait_state(lambda state: state["stamp"] >= high["stamp"], GENEROUS_S)
    cut = time.time()
    clean.hosts.partition()
    partitioned = time.time()  # the emulator has cut the link: nothing stamped after this can cross it

    # The driver: the sequencer's session lapses, every output ramps below 50 V, the fault is named.
    ramp_time = MIN_JERK_PEAK_RATE * high["channels"]["back"]["setpoint_v"] / SLEW_RATE_V_PER_S
    safe = clean.rig.wait_state(lambda s: channels_below(s, SAFE_V), HEARTBEAT_TIMEOUT_S + ramp_time + 30.0, cut)
    faulted = clean.rig.wait_state(lambda s: s["channels"]["back"]["faults"], GENEROUS_S, cut)
    # How long that takes is the watchdog's and the ramp's, tested on simulated time (tests/hv_driver); here it is
    # reported only: on shared cores the driver's whole process can stall (seen: 1.6 s without a cycle or a sample).
    stalls = driver_stalls(clean.rig.states(cut), cut, safe["stamp"])
    print(f"partition -> every channel below {SAFE_V:g} V after {safe['stamp'] - cut:.2f} s (nominal "
          f"{HEARTBEAT_TIMEOUT_S + ramp_time:.2f} s), fault latched after {faulted['stamp'] - cut:.2f} s, the "
          f"driver's stalls {[round(stall, 3) for stall in stalls]} s, load average {os.getloadavg()[0]:.1f}")
    back = faulted["channels"]["back"]
    assert back["fault_text"] == "heartbeat: control of 'sequencer' lapsed: no heartbeat for more than 2 s"

    # The sequencer: logs the lost driver once its state timeout has passed; its goal fails naming it after
    # its safe stop's bounded waits, and the client ends.
    code = grasp.wait(SEQUENCER_REPORT_BOUND_S + 30.0)
    ended = time.time() - cut
    logged = driver_lost_logged(clean.logs["sequencer"].read_text(), cut)
    assert logged is not None, "the sequencer did not log the lost driver"
    logged -= cut
    print(f"partition -> the sequencer logged the lost driver after {logged:.2f} s (state timeout "
          f"{STATE_TIMEOUT_S:g} s), its goal ended after {ended:.1f} s (bound {SEQUENCER_REPORT_BOUND_S:g} s)")
    log = (clean.out / "grasp_partition.log").read_text()
    assert code == 1 and "HV driver lost: no hv/state for" in log, log[-3000:]
    # its safe stop's waits ran out: nothing it sent crossed the cut link
    assert "ramp to 0 V timed out" in log and "e-stop FAILED" in log, log[-3000:]
    assert logged > 0.0  # after the cut, not before

    # Nothing crossed the cut link (no shared-memory path around it), while the driver went on publishing.
    assert [state for state in clean.rig.states() if state["stamp"] > partitioned]
    crossed = [state for state in clean.workstation.states() if state["stamp"] > partitioned]
    assert not crossed, f"hv/state reached the workstation through the partition: {crossed[:3]}"
    healed = time.time()
    clean.hosts.heal()
    clean.workstation.wait_state(lambda state: True, STARTUP_TIMEOUT, since=healed)
    # What the sequencer sent into the cut link has arrived or is gone once its writers' repairs have had two
    # heartbeat timeouts of the driver's time since the link returned.
    clean.rig.wait_state(lambda state: state["stamp"] >= healed + 2 * HEARTBEAT_TIMEOUT_S, GENEROUS_S, healed)
    after = clean.rig.states(healed)
    assert all(channels_below(state, SAFE_V) for state in after)
    assert after[-1]["channels"]["back"]["faults"], "the fault was cleared without a reset"
    assert not [c for c in clean.rig.controls(healed) if c["controller"]], "control held after the link returned"

    # A client asks again: control first, then a fault reset, then a ramp.
    console = clean.workstation
    refused = console.command("ramp back 1000")
    # A client without a session cannot sign a command, so it refuses before sending (hv_control.HvControl).
    assert not refused["ok"] and "holds no control of the HV driver: claim it first" in refused["message"], refused
    assert console.command("claim operator")["ok"]
    try:
        refused = console.command("ramp back 1000")
        assert not refused["ok"] and "reset them first" in refused["message"], refused
        assert console.command("reset")["ok"]
        reset_at = time.time()
        # A reset energises nothing: every sample the driver stamped from then until the ramp was asked for is
        # below 50 V, and after the ramp the same record shows the output up.
        clean.rig.wait_state(lambda state: state["stamp"] >= reset_at, GENEROUS_S, reset_at)
        ramp_asked = time.time()
        assert console.command("ramp back 1000")["ok"]
        assert clean.rig.wait_state(lambda s: s["channels"]["back"]["voltage_v"] > 950.0, GENEROUS_S, reset_at)
    finally:
        console.command("release")
    between = [state for state in clean.rig.states() if reset_at <= state["stamp"] < ramp_asked]
    assert between and all(channels_below(state, SAFE_V) for state in between)
    assert clean.hosts.stop(recorder) == 0

    # The workstation's recording reports the samples the partition cost, from the cut on. Its reader is reliable:
    # a partition shorter than the driver's lease on its readers ends with the writer repairing the newest samples
    # it still holds, so the gap may end before the return, but nothing sent after the cut arrived before it.
    report = load(str(recording)).lost_samples["/hv/state"]
    assert report["checked"] and report["lost"] > 0
    gap, states = max(report["gaps"], key=lambda g: g["lost"]), clean.rig.states()
    assert stamp_near(states, gap["after"], later=True) <= partitioned, (gap, partitioned)
    assert stamp_near(states, gap["before"], later=False) > partitioned, (gap, partitioned)
    early = [(sent, received) for sent, received in recorded_times(recording)
             if sent > partitioned and received < healed]
    assert not early, f"hv/state sent after the cut reached the recording before the link returned: {early[:3]}"
