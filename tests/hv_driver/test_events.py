"""The log lines of the HV driver: faults when they latch (ERROR, channel and fault text), faults cleared (INFO),
control that ends other than by a release (WARNING)."""
import dataclasses
import logging

from hv_driver import Fault
from hv_driver.driver import ChannelSnapshot, SupplySnapshot
from hv_driver.events import snapshot_events

FRONT = ChannelSnapshot("front", 0, 0.0, 0.0, 0.0, 0.0, 3000.0, True, False, Fault(0), "")
IDLE = SupplySnapshot("sim", "pty", False, "", 0.0, (FRONT, dataclasses.replace(FRONT, name="back", index=1)))


def with_fault(snapshot: SupplySnapshot, fault: Fault, text: str) -> SupplySnapshot:
    front = dataclasses.replace(snapshot.channels[0], faults=fault, fault_text=text, output_enabled=False)
    return dataclasses.replace(snapshot, channels=(front, snapshot.channels[1]))


def test_a_fault_is_logged_as_an_error_once_when_it_latches_naming_channel_and_text():
    tripped = with_fault(IDLE, Fault.OVER_CURRENT, "over_current: measured -0.002 A above the trip level 5e-05 A")
    assert snapshot_events(IDLE, tripped) == [
        (logging.ERROR, "channel 'front': fault latched: over_current: measured -0.002 A above the trip level "
                        "5e-05 A")]
    assert snapshot_events(tripped, tripped) == []
    both = with_fault(IDLE, Fault.OVER_CURRENT | Fault.LINK, "link: no valid reply from the supply for 1 s")
    assert snapshot_events(tripped, both) == [
        (logging.ERROR, "channel 'front': fault latched: link: no valid reply from the supply for 1 s")]
    assert snapshot_events(both, IDLE) == [(logging.INFO, "channel 'front': faults over_current, link cleared")]


def test_a_fault_latched_before_the_first_snapshot_is_logged():
    estop = with_fault(IDLE, Fault.ESTOP, "estop: emergency stop")
    assert snapshot_events(None, estop) == [(logging.ERROR, "channel 'front': fault latched: estop: emergency stop")]


def test_a_lapse_is_a_warning_a_release_is_not_logged_here_and_a_claim_is_not_either():
    held = dataclasses.replace(IDLE, controller="sequencer")
    lapsed = dataclasses.replace(IDLE, control_ended="control of 'sequencer' lapsed: no heartbeat for more than 2 s")
    released = dataclasses.replace(IDLE, control_ended="control released by 'sequencer'")
    assert snapshot_events(IDLE, held) == []
    assert snapshot_events(held, lapsed) == [
        (logging.WARNING, "control of 'sequencer' lapsed: no heartbeat for more than 2 s")]
    assert snapshot_events(held, released) == []
    assert snapshot_events(lapsed, lapsed) == []
