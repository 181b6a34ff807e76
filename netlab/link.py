"""A network link emulated in user space: frames between two endpoints, delayed, jittered, lost or cut.

The kernel's netem qdisc does the same job, but kernels without the sch_netem module (a Firecracker VM's,
this project's CI) cannot load it, so the frames go through this process instead: each endpoint is a file
descriptor that carries one frame per read and per write (a TAP device, or a datagram socket in tests).

Every frame, in each direction independently: dropped while the link is partitioned, else dropped with
probability ``loss``, else delivered after ``delay_s`` + uniform(-``jitter_s``, +``jitter_s``) (never below
0), like netem without a distribution table. Frames are released in the order they fall due, so a jitter
larger than the gap between two frames reorders them, as with netem. A partition also drops the frames
already in flight (a pulled cable), and nothing is sent until the link is healed.
"""
from __future__ import annotations

import heapq
import math
import os
import random
import selectors
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field

MAX_FRAME = 65536  # [bytes] larger than any frame a TAP device with a standard MTU delivers


@dataclass(frozen=True)
class Conditions:
    """What the link does to every frame (each direction alike)."""

    delay_s: float = 0.0   # mean one-way delay [s]
    jitter_s: float = 0.0  # delay varies uniformly by up to this much either way [s]
    loss: float = 0.0      # fraction of frames dropped, 0..1

    def __post_init__(self):
        for name, value, high in (("delay_s", self.delay_s, 60.0), ("jitter_s", self.jitter_s, 60.0),
                                  ("loss", self.loss, 1.0)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= high:
                raise ValueError(f"{name}={value!r}: a number 0..{high:g}")


@dataclass
class DirectionStats:
    """Counts of one direction: every frame read is delivered, lost, cut by a partition, failed or in flight."""

    received: int = 0
    delivered: int = 0
    lost: int = 0          # dropped by the loss rate
    partitioned: int = 0   # dropped because the link was partitioned (also frames in flight at that moment)
    send_errors: int = 0   # the far endpoint refused the frame (device down, queue full)
    in_flight: int = 0


@dataclass(order=True)
class _Frame:
    due: float
    order: int
    direction: int = field(compare=False)
    data: bytes = field(compare=False)


class Link:
    """Moves frames between ``end_a`` and ``end_b`` (non-blocking descriptors, one frame per read/write).

    ``serve(stop)`` runs it in the calling thread until ``stop`` is set; ``poll(timeout, watch)`` runs one
    round and says which extra descriptors are readable, for a program that also reads commands. The
    conditions and the partition may be changed from another thread at any time.
    """

    def __init__(self, end_a: int, end_b: int, conditions: Conditions = Conditions(),
                 rng: random.Random | int | None = None, clock: Callable[[], float] = time.monotonic):
        self._ends = (end_a, end_b)
        self._conditions = conditions
        self._rng = rng if isinstance(rng, random.Random) else random.Random(rng)
        self._clock = clock
        self._lock = threading.Lock()
        self._queue: list[_Frame] = []
        self._order = 0
        self._partitioned = False
        self._stats = (DirectionStats(), DirectionStats())
        self._selector = selectors.DefaultSelector()
        for direction, end in enumerate(self._ends):
            os.set_blocking(end, False)
            self._selector.register(end, selectors.EVENT_READ, direction)
        self._watched: set[int] = set()

    @property
    def conditions(self) -> Conditions:
        return self._conditions

    @conditions.setter
    def conditions(self, conditions: Conditions) -> None:
        if not isinstance(conditions, Conditions):
            raise TypeError(f"conditions must be a Conditions, not {type(conditions).__name__}")
        self._conditions = conditions

    @property
    def partitioned(self) -> bool:
        return self._partitioned

    def partition(self) -> None:
        """Cut the link: frames in flight and every frame from now on are dropped, both ways."""
        with self._lock:
            self._partitioned = True
            for frame in self._queue:
                self._stats[frame.direction].partitioned += 1
                self._stats[frame.direction].in_flight -= 1
            self._queue.clear()

    def heal(self) -> None:
        """Restore the link under the present conditions."""
        with self._lock:
            self._partitioned = False

    def stats(self) -> dict:
        """Counts per direction: ``a_to_b`` and ``b_to_a``."""
        with self._lock:
            return {"a_to_b": asdict(self._stats[0]), "b_to_a": asdict(self._stats[1])}

    def _accept(self, direction: int, data: bytes, now: float) -> None:
        stats, conditions = self._stats[direction], self._conditions
        stats.received += 1
        if self._partitioned:
            stats.partitioned += 1
            return
        if conditions.loss and self._rng.random() < conditions.loss:
            stats.lost += 1
            return
        delay = conditions.delay_s
        if conditions.jitter_s:
            delay += self._rng.uniform(-conditions.jitter_s, conditions.jitter_s)
        self._order += 1
        heapq.heappush(self._queue, _Frame(now + max(delay, 0.0), self._order, direction, data))
        stats.in_flight += 1

    def _read(self, direction: int) -> None:
        end = self._ends[direction]
        while True:
            try:
                data = os.read(end, MAX_FRAME)
            except (BlockingIOError, InterruptedError):
                return
            if not data:
                return
            with self._lock:
                self._accept(direction, data, self._clock())

    def _deliver_due(self) -> float | None:
        """Send every frame that is due; the time until the next one (None when none is queued)."""
        while True:
            with self._lock:
                if not self._queue:
                    return None
                wait = self._queue[0].due - self._clock()
                if wait > 0:
                    return wait
                frame = heapq.heappop(self._queue)
            try:
                os.write(self._ends[1 - frame.direction], frame.data)
                delivered = True
            except OSError:  # the far device is down or its queue is full: the frame is lost, as on a wire
                delivered = False
            with self._lock:  # in flight until its outcome is counted, so every snapshot accounts for every frame
                stats = self._stats[frame.direction]
                stats.in_flight -= 1
                if delivered:
                    stats.delivered += 1
                else:
                    stats.send_errors += 1

    def poll(self, timeout: float | None, watch: Iterable[int] = ()) -> list[int]:
        """One round: deliver what is due, wait up to ``timeout`` (less when a frame falls due) for frames or
        for one of ``watch`` to become readable, take in the frames; returns the readable ``watch`` fds."""
        watch = set(watch)
        for fd in watch - self._watched:
            self._selector.register(fd, selectors.EVENT_READ, None)
        for fd in self._watched - watch:
            self._selector.unregister(fd)
        self._watched = watch
        next_due = self._deliver_due()
        if next_due is not None:
            timeout = next_due if timeout is None else min(timeout, next_due)
        ready = []
        for key, _ in self._selector.select(timeout):
            if key.data is None:
                ready.append(key.fd)
            else:
                self._read(key.data)
        self._deliver_due()
        return ready

    def serve(self, stop: threading.Event, poll_period_s: float = 0.05) -> None:
        """Run until ``stop`` is set (checked at least every ``poll_period_s``)."""
        while not stop.is_set():
            self.poll(poll_period_s)

    def close(self) -> None:
        """Stop watching the endpoints (they stay open: whoever opened them closes them)."""
        self._selector.close()


def conditions_from(text: str, base: Conditions) -> Conditions:
    """``"delay_s=0.05 jitter_s=0.01 loss=0.05"`` applied over ``base``; ValueError naming a bad field."""
    values = asdict(base)
    for item in text.split():
        name, _, value = item.partition("=")
        if name not in values:
            raise ValueError(f"unknown setting {name!r}; known: {', '.join(values)}")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"{name}={value!r}: a number") from None
        if not math.isfinite(number):
            raise ValueError(f"{name}={value!r}: a finite number")
        values[name] = number
    return Conditions(**values)
