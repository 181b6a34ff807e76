"""What an operator must read in the HV driver's log, queued by the supervisor as it happens: faults latching
(ERROR, channel and fault text) and clearing (INFO), control ending other than by a release (WARNING: a lapse, an
e-stop, the node lost; a release and a claim are logged where they are answered). Each event carries the supervisor's
time, that of the control cycle it happened in. The node drains the queue at its state rate and logs every event, so
a fault that latched and was reset between two of its snapshots is logged too. Pure: no I/O."""
import logging
from collections import deque
from typing import NamedTuple

MAX_EVENTS = 128  # queued between two drains; beyond, the oldest go (counted, and said at the next drain)
MAX_TEXT = 400    # characters of one event's text (a device's fault text is the device's)


class SupervisorEvent(NamedTuple):  # a tuple: it crosses the supervisor's channel as a JSON list
    time: float  # [s] on the supervisor's clock
    level: int   # a `logging` level
    text: str


class EventLog:
    """A bounded queue of SupervisorEvent, oldest first."""

    def __init__(self, capacity: int = MAX_EVENTS):
        self._events: deque[SupervisorEvent] = deque(maxlen=capacity)
        self._dropped = 0

    def add(self, time: float, level: int, text: str) -> None:
        if len(self._events) == self._events.maxlen:
            self._dropped += 1
        self._events.append(SupervisorEvent(time, level, text[:MAX_TEXT]))

    def drain(self) -> list[SupervisorEvent]:
        """The events queued since the last drain, oldest first, after a WARNING if some were dropped."""
        events = list(self._events)
        if self._dropped:
            events.insert(0, SupervisorEvent(events[0].time, logging.WARNING, f"{self._dropped} older supervisor "
                                             f"events dropped: more than {self._events.maxlen} since the last drain"))
        self._events.clear()
        self._dropped = 0
        return events
