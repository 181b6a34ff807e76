"""The user-space link emulator on datagram socket pairs (one frame per read, as a TAP device): delay and
jitter measured on the frames it delivers, the loss rate, partition and heal, both directions, bad settings.
No root needed. The link runs on the test's own clock, polled by the test as it steps that clock (no thread), so
every delay is measured in that clock's time and no outcome depends on the host's speed."""
import math
import os
import socket
import statistics
import struct

import pytest

import netlab.link
from netlab.link import Conditions, Link, conditions_from

pytestmark = pytest.mark.fast

FRAME = struct.Struct("!Id")  # index, send time (the bench's clock)
STEP_S = 0.0005  # [s] the clock's step while frames are in flight: the resolution of the measured delays


class Clock:
    """The link's clock: time passes only when the test says so."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class Bench:
    """Two applications, A and B, joined by a Link that the bench polls whenever a frame is sent and at every step
    of the clock; what the link delivers is taken in at once and stamped with the clock's time."""

    def __init__(self, conditions: Conditions, seed: int = 0):
        self.a, a_link = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.b, b_link = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._link_ends = (a_link, b_link)
        self.clock = Clock()
        self.link = Link(a_link.fileno(), b_link.fileno(), conditions, rng=seed, clock=self.clock)
        self._arrived: dict[socket.socket, list[tuple[int, float]]] = {self.a: [], self.b: []}
        for end in self._arrived:
            end.setblocking(False)

    def _poll(self) -> None:
        self.link.poll(0.0)
        for end, arrived in self._arrived.items():
            while end.fileno() >= 0:  # a closed end takes nothing in
                try:
                    index, sent = FRAME.unpack(end.recv(64))
                except BlockingIOError:
                    break
                arrived.append((index, self.clock.now - sent))

    def run(self, seconds: float) -> None:
        """Let ``seconds`` pass in steps of STEP_S."""
        for _ in range(round(seconds / STEP_S)):
            self.clock.now += STEP_S
            self._poll()

    def send(self, sender: socket.socket, count: int, period_s: float = 0.002) -> None:
        """``count`` frames, ``period_s`` apart on the clock; the link reads each as it is sent."""
        for index in range(count):
            sender.send(FRAME.pack(index, self.clock.now))
            self._poll()
            self.run(period_s)

    def receive(self, receiver: socket.socket) -> list[tuple[int, float]]:
        """(index, delay [s]) of every frame delivered to ``receiver`` since the last call, once the link has no
        frame in flight any more."""
        while any(direction["in_flight"] for direction in self.link.stats().values()):
            self.run(STEP_S)
        arrived, self._arrived[receiver] = self._arrived[receiver], []
        return arrived

    def close(self) -> None:
        self.link.close()
        for sock in (self.a, self.b, *self._link_ends):
            sock.close()


@pytest.fixture
def bench(request):
    benches = []

    def make(conditions: Conditions, seed: int = 0) -> Bench:
        benches.append(Bench(conditions, seed))
        return benches[-1]

    yield make
    for made in benches:
        made.close()


def test_delay_jitter_and_loss_statistics_of_delivered_frames(bench):
    delay, jitter, loss, count = 0.05, 0.01, 0.05, 600
    lab = bench(Conditions(delay, jitter, loss), seed=7)
    lab.send(lab.a, count)
    received = lab.receive(lab.b)
    stats = lab.link.stats()["a_to_b"]
    assert stats["received"] == count
    assert stats["delivered"] + stats["lost"] == count and stats["in_flight"] == 0
    assert len(received) == stats["delivered"]
    # Binomial(600, 0.05): mean 30, sd 5.3; 5 sd either way
    assert 30 - 27 <= stats["lost"] <= 30 + 27, stats
    delays = [d for _, d in received]
    assert delay - jitter <= min(delays) and max(delays) <= delay + jitter + STEP_S  # never early, never late
    assert statistics.median(delays) == pytest.approx(delay, abs=jitter / 2)
    quartiles = statistics.quantiles(delays, n=4)
    assert quartiles[2] - quartiles[0] >= jitter / 2  # uniform +-10 ms: interquartile range 10 ms
    # independent draws per frame: a jitter larger than the gap between frames reorders some, as netem does
    indices = [i for i, _ in received]
    assert indices != sorted(indices)


def test_without_jitter_the_order_is_kept_and_every_frame_is_delayed(bench):
    lab = bench(Conditions(delay_s=0.03))
    lab.send(lab.a, 100)
    received = lab.receive(lab.b)
    assert [i for i, _ in received] == list(range(100))
    assert all(0.03 <= d <= 0.03 + STEP_S for _, d in received)


def test_loss_draws_are_reproducible_from_the_seed(bench):
    def lost(seed: int) -> int:
        lab = bench(Conditions(loss=0.3), seed=seed)
        lab.send(lab.a, 200, period_s=0.0)
        return lab.link.stats()["a_to_b"]["lost"]

    assert lost(3) == lost(3)
    assert lost(3) != lost(4) or lost(5) != lost(3)


@pytest.mark.parametrize("loss, delivered", [(0.0, 50), (1.0, 0)])
def test_no_loss_delivers_everything_and_full_loss_nothing(bench, loss, delivered):
    lab = bench(Conditions(loss=loss))
    lab.send(lab.a, 50, period_s=0.0)
    assert len(lab.receive(lab.b)) == delivered


def test_a_partition_drops_frames_in_flight_and_everything_until_healed(bench):
    lab = bench(Conditions(delay_s=0.2))
    lab.send(lab.a, 20, period_s=0.0)  # in flight for 0.2 s
    lab.link.partition()
    lab.send(lab.a, 10, period_s=0.0)
    lab.send(lab.b, 10, period_s=0.0)
    lab.run(0.5)  # past the delay of the frames that were in flight
    assert lab.receive(lab.b) == [] and lab.receive(lab.a) == []
    stats = lab.link.stats()
    assert stats["a_to_b"]["partitioned"] == 30 and stats["b_to_a"]["partitioned"] == 10
    lab.link.heal()
    lab.send(lab.b, 5, period_s=0.0)
    assert [i for i, _ in lab.receive(lab.a)] == list(range(5))


def test_both_directions_are_carried_and_counted_independently(bench):
    lab = bench(Conditions(delay_s=0.01))
    lab.send(lab.a, 30, period_s=0.0)
    lab.send(lab.b, 20, period_s=0.0)
    assert len(lab.receive(lab.b)) == 30 and len(lab.receive(lab.a)) == 20
    stats = lab.link.stats()
    assert (stats["a_to_b"]["delivered"], stats["b_to_a"]["delivered"]) == (30, 20)


def test_conditions_change_while_running(bench):
    lab = bench(Conditions())
    lab.send(lab.a, 5, period_s=0.0)
    assert max(d for _, d in lab.receive(lab.b)) == 0.0
    lab.link.conditions = conditions_from("delay_s=0.15", lab.link.conditions)
    lab.send(lab.a, 5, period_s=0.0)
    assert min(d for _, d in lab.receive(lab.b)) >= 0.15


def test_a_far_end_that_refuses_frames_is_counted_not_fatal(bench):
    lab = bench(Conditions())
    lab.b.close()  # B's application is gone: writes toward it fail
    lab.send(lab.a, 5, period_s=0.0)
    assert lab.link.stats()["a_to_b"]["send_errors"] == 5
    lab.send(lab.a, 1, period_s=0.0)  # the link still runs
    assert lab.link.stats()["a_to_b"]["received"] == 6


def test_every_frame_read_is_accounted_for_at_every_moment(monkeypatch):
    """received = delivered + lost + partitioned + send_errors + in_flight in every snapshot, also one taken while a
    frame is being written (it was counted nowhere then, and a test that waited for nothing in flight read one send
    error short)."""
    a, a_link = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    b, b_link = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    link = Link(a_link.fileno(), b_link.fileno(), Conditions())
    snapshots = []

    class SnapshotOnWrite:
        """The link's `os`, taking a snapshot of its counts as each frame goes out."""

        def __getattr__(self, name):
            return getattr(os, name)

        def write(self, fd, data):
            snapshots.append(link.stats()["a_to_b"])
            return os.write(fd, data)

    monkeypatch.setattr(netlab.link, "os", SnapshotOnWrite())
    try:
        for closed in (False, True):  # delivered, then refused by a far end that is gone
            if closed:
                b.close()
            for index in range(3):
                a.send(FRAME.pack(index, 0.0))
            for _ in range(3):
                link.poll(0.01)
        stats = link.stats()["a_to_b"]
        assert (stats["delivered"], stats["send_errors"], len(snapshots)) == (3, 3, 6)
        for snapshot in [*snapshots, stats]:
            accounted = sum(snapshot[k] for k in ("delivered", "lost", "partitioned", "send_errors", "in_flight"))
            assert accounted == snapshot["received"], snapshot
    finally:
        link.close()
        for end in (a, a_link, b, b_link):
            end.close()


@pytest.mark.parametrize("fields, message", [
    ({"delay_s": -0.01}, r"delay_s=-0.01: a number 0..60"),
    ({"jitter_s": math.nan}, r"jitter_s=nan: a number 0..60"),
    ({"loss": 1.5}, r"loss=1.5: a number 0..1"),
    ({"loss": True}, r"loss=True"),
])
def test_bad_conditions_are_refused_naming_the_field(fields, message):
    with pytest.raises(ValueError, match=message):
        Conditions(**fields)


@pytest.mark.parametrize("text, message", [
    ("delay=0.1", r"unknown setting 'delay'; known: delay_s, jitter_s, loss"),
    ("loss=lots", r"loss='lots': a number"),
    ("delay_s=inf", r"delay_s='inf': a finite number"),
    ("loss=2", r"loss=2.0: a number 0..1"),
])
def test_a_bad_set_command_is_refused_naming_the_setting(text, message):
    with pytest.raises(ValueError, match=message):
        conditions_from(text, Conditions())


def test_a_set_command_changes_only_what_it_names():
    assert conditions_from("loss=0.05", Conditions(0.05, 0.01, 0.0)) == Conditions(0.05, 0.01, 0.05)
