"""What changed between two snapshots of the supply that an operator must read in the log: faults latching and
clearing, control ending without a release (lapsed, e-stop). Pure: the caller logs the lines at their level."""
import logging

from .driver import SupplySnapshot
from .faults import fault_names

RELEASED = "control released by "  # a release is logged where it is answered


def snapshot_events(before: SupplySnapshot | None, after: SupplySnapshot) -> list[tuple[int, str]]:
    """(logging level, line) for each change from ``before`` (None: the first snapshot) to ``after``: ERROR for a
    fault that latched (channel, faults, the fault text), INFO for faults cleared, WARNING for control that ended
    other than by a release (a lapse or an e-stop; a session claimed between the two snapshots hides it)."""
    events = []
    previous = {c.name: c.faults for c in before.channels} if before else {}
    for channel in after.channels:
        was = previous.get(channel.name, type(channel.faults)(0))
        if channel.faults & ~was:
            events.append((logging.ERROR, f"channel {channel.name!r}: fault latched: {channel.fault_text}"))
        elif was and not channel.faults:
            events.append((logging.INFO, f"channel {channel.name!r}: faults {fault_names(was)} cleared"))
    ended = after.control_ended
    if before and before.controller and not after.controller and not ended.startswith(RELEASED):
        events.append((logging.WARNING, ended))
    return events
