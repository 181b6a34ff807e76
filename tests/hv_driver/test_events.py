"""The HV supervisor's event log, which the node drains and logs: faults when they latch (ERROR, channel and fault
text), faults cleared (INFO), control that ends other than by a release (WARNING), each at the supervisor's time,
none lost between two of the node's snapshots."""
import logging

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hv_driver import ChannelConfig, Fault, Supervisor, fault_names
from hv_driver.events import MAX_EVENTS, EventLog, SupervisorEvent

pytestmark = pytest.mark.fast

SNAPSHOT_PERIOD_S = 1.0 / 50.0  # the node's hv/state rate (hv_driver.yaml): it drains the log at each snapshot


@pytest.fixture
def supervisor():
    return Supervisor([ChannelConfig("front", 0), ChannelConfig("back", 1)], link_timeout_s=0.5,
                      heartbeat_timeout_s=2.0)


def lines(events: list[SupervisorEvent]) -> list[tuple[int, str]]:
    return [(event.level, event.text) for event in events]


def test_a_fault_is_an_error_once_when_it_latches_naming_channel_and_text_and_its_clearing_is_info(supervisor):
    supervisor.step(1.0)
    front = supervisor.channel("front")
    front.trip(Fault.OVER_CURRENT, "measured -0.002 A above the trip level 5e-05 A")
    front.trip(Fault.OVER_CURRENT, "measured -0.003 A above the trip level 5e-05 A")  # latched already
    front.trip(Fault.LINK, "no valid reply from the supply for 1 s")
    assert supervisor.events.drain() == [
        SupervisorEvent(1.0, logging.ERROR, "channel 'front': fault latched: over_current: measured -0.002 A above "
                                            "the trip level 5e-05 A"),
        SupervisorEvent(1.0, logging.ERROR, "channel 'front': fault latched: link: no valid reply from the supply "
                                            "for 1 s")]
    assert supervisor.events.drain() == []
    supervisor.step(1.5)
    assert supervisor.reset(1.5) == ["front"]
    assert supervisor.events.drain() == [
        SupervisorEvent(1.5, logging.INFO, "channel 'front': faults over_current, link cleared")]


def test_a_lapse_and_an_estop_are_warnings_a_release_and_a_claim_are_not_logged_here(supervisor):
    supervisor.step(0.0)
    supervisor.claim_control("sequencer", 0.0)
    assert supervisor.events.drain() == []
    for cycle in range(1, 1200):  # 12 s of a control loop at 100 Hz, the client silent
        supervisor.step(cycle * 0.01)
    (lapse,) = supervisor.events.drain()
    assert lapse.level == logging.WARNING and 10.0 < lapse.time <= 10.02
    assert lapse.text == "control of 'sequencer' lapsed: no heartbeat for more than 10 s"
    token = supervisor.claim_control("sequencer", 12.0)
    supervisor.release_control(token, 12.0)
    assert supervisor.events.drain() == []
    supervisor.claim_control("demo", 12.0)
    supervisor.estop()
    assert lines(supervisor.events.drain()) == [
        (logging.WARNING, "control ended by an emergency stop"),
        (logging.ERROR, "channel 'front': fault latched: estop: emergency stop"),
        (logging.ERROR, "channel 'back': fault latched: estop: emergency stop")]


def test_a_lost_node_ends_control_with_a_warning_and_latches_node_lost(supervisor):
    supervisor.claim_control("sequencer", 0.0)
    supervisor.node_lost(3.0, "node lost: its channel closed")
    assert lines(supervisor.events.drain())[:2] == [
        (logging.WARNING, "node lost: its channel closed"),
        (logging.ERROR, "channel 'front': fault latched: node_lost: node lost: its channel closed")]


def test_the_log_is_bounded_and_says_how_many_it_dropped():
    log = EventLog()
    for index in range(MAX_EVENTS + 5):
        log.add(float(index), logging.INFO, f"event {index} " + "x" * 1000)
    events = log.drain()
    assert len(events) == MAX_EVENTS + 1 and events[1].text.startswith("event 5 ") and len(events[1].text) == 400
    assert events[0] == SupervisorEvent(5.0, logging.WARNING, f"5 older supervisor events dropped: more than "
                                                              f"{MAX_EVENTS} since the last drain")
    assert log.drain() == []


def test_a_fault_latched_and_reset_between_two_snapshots_is_reported(supervisor):
    """Old: the node logged what differed between two of its snapshots (50 Hz), so an over-current that latched and
    was reset between two of them was never logged."""
    supervisor.step(0.0)
    assert supervisor.events.drain() == []  # the node's snapshot at 0 s
    front = supervisor.channel("front")
    supervisor.step(0.005)
    front.observe(0.005, 0.0, 1.0)  # an arc: 1 A
    supervisor.step(0.010)
    supervisor.reset(0.012)
    supervisor.step(0.015)
    assert not front.faults  # the node's next snapshot, at 0.02 s, shows no fault
    events = supervisor.events.drain()
    assert [(event.time, event.level) for event in events] == [(0.005, logging.ERROR), (0.010, logging.INFO)]
    assert [event.text for event in events] == [
        "channel 'front': fault latched: over_current: measured 1 A above the trip level 5e-05 A",
        "channel 'front': faults over_current cleared"]
    assert events[-1].time - events[0].time < SNAPSHOT_PERIOD_S


def test_the_driver_hands_its_supervisors_events_out_once(sim, supply, token):
    supply.enable("front")
    assert supply.ramp_to("front", 500.0, token=token).wait(5.0)
    supply.drain_events()
    sim.inject("device_reset")
    assert supply.wait_for(lambda: supply.snapshot().channel("front").faults == Fault.DEVICE, 2.0)
    supply.reset_faults()
    supply.wait_cycles(3)
    assert not any(channel.faults for channel in supply.snapshot().channels)
    assert [(level, text.split(": device")[0]) for level, text in lines(supply.drain_events())] == [
        (logging.ERROR, "channel 'front': fault latched"), (logging.INFO, "channel 'front': faults device cleared")]
    assert supply.drain_events() == []


OPERATIONS = st.lists(st.one_of(
    st.tuples(st.just("trip"), st.sampled_from(["front", "back"]),
              st.sampled_from([Fault.OVER_CURRENT, Fault.LINK, Fault.DEVICE, Fault.READBACK_MISMATCH])),
    st.tuples(st.just("reset"), st.booleans()), st.tuples(st.just("step"), st.floats(0.0, 0.05)),
    st.just(("drain",))), max_size=40)


@given(OPERATIONS)
def test_every_latch_and_clear_is_drained_once_in_order_whenever_the_node_drains(operations):
    """Against a model of the latched faults: each fault that latches is one ERROR event, each reset of a faulted
    channel one INFO event naming what it cleared, in the order they happened, at non-decreasing times."""
    supervisor = Supervisor([ChannelConfig("front", 0), ChannelConfig("back", 1)], link_timeout_s=0.5,
                            heartbeat_timeout_s=2.0)
    latched = {"front": Fault(0), "back": Fault(0)}
    expected, drained, now = [], [], 0.0
    for operation in operations:
        if operation[0] == "trip":
            _, name, fault = operation
            supervisor.channel(name).trip(fault, "injected")
            if fault not in latched[name]:
                latched[name] |= fault
                expected.append((logging.ERROR, f"channel {name!r}: fault latched: {fault.name.lower()}: injected"))
        elif operation[0] == "reset":
            supervisor.reset(now, all_channels=operation[1])
            for name, faults in latched.items():
                if faults:
                    expected.append((logging.INFO, f"channel {name!r}: faults {fault_names(faults)} cleared"))
                latched[name] = Fault(0)
        elif operation[0] == "step":
            now += operation[1]
            supervisor.step(now)
        else:
            drained += supervisor.events.drain()
    drained += supervisor.events.drain()
    assert lines(drained) == expected
    assert [event.time for event in drained] == sorted(event.time for event in drained)
