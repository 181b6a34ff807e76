"""Time as an input: the clock the driver's loop, its serial links and the simulated supplies read and wait on.

`MONOTONIC` is the real clock (time.monotonic, time.sleep): the loop runs in its own thread over real ports.
`SimulatedClock` is advanced by hand: an `HvSupply` given one runs no thread; its loop is stepped period by period
(`HvSupply.run_for`, and every wait of its handles runs the loop until the wait ends), each exchange answered at
once by a simulated supply on the same clock (`sim_fallback.memory_port.MemoryPort`), so every timing property
of the supervisor can be tested deterministically, without sleeps.
"""
import heapq
import itertools
import math
import time


class MonotonicClock:
    """The machine's monotonic clock [s]."""

    simulated = False

    def __call__(self) -> float:
        return time.monotonic()

    @staticmethod
    def sleep(seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class SimulatedClock:
    """A clock [s] that moves only when advanced: `advance`, `advance_to`, or `sleep` (which waits by advancing).
    `call_at` schedules an action (e.g. a fault of a simulated device) at a time: an advance across it stops there,
    runs it, and goes on."""

    simulated = True

    def __init__(self, start: float = 0.0):
        if not math.isfinite(start):
            raise ValueError(f"start={start!r}: a finite time [s]")
        self._now = float(start)
        self._due: list[tuple[float, int, object]] = []  # (time, order, action) heap
        self._order = itertools.count()

    def __call__(self) -> float:
        return self._now

    def call_at(self, t: float, action) -> None:
        """Run ``action()`` once the clock reaches ``t`` (at once if it has)."""
        if t <= self._now:
            action()
            return
        heapq.heappush(self._due, (float(t), next(self._order), action))

    def advance(self, seconds: float) -> float:
        """Move the clock forward by ``seconds`` (a negative or non-finite step is refused); returns the new time."""
        if not (math.isfinite(seconds) and seconds >= 0):
            raise ValueError(f"seconds={seconds!r}: a finite step >= 0 (the clock never runs backwards)")
        end = self._now + seconds
        while self._due and self._due[0][0] <= end:
            t, _, action = heapq.heappop(self._due)
            self._now = max(self._now, t)
            action()
        self._now = end
        return self._now

    def advance_to(self, t: float) -> float:
        """Move the clock to ``t`` if that is later; returns the new time."""
        return self.advance(max(0.0, t - self._now))

    def sleep(self, seconds: float) -> None:
        self.advance(max(0.0, seconds))


MONOTONIC = MonotonicClock()


def as_clock(clock):
    """``clock`` as a clock with ``sleep``: a plain callable returning seconds keeps real waits (time.sleep)."""
    if clock is None:
        return MONOTONIC
    if hasattr(clock, "sleep"):
        return clock
    return _CallableClock(clock)


class _CallableClock(MonotonicClock):
    """A time source given as a bare callable (e.g. ``time.monotonic``): read from it, wait in real time."""

    def __init__(self, read):
        self._read = read

    def __call__(self) -> float:
        return self._read()
