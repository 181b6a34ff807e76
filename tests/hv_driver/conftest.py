"""Fixtures for the HV driver tests: a scripted serial port; a simulated supply linked in memory to the driver,
both on the test's simulated clock (deterministic, no sleeps); the same supply on a real pty for the few real-time
integration tests."""
import dataclasses
import threading
import time

import pytest
import waiting
from dialect_rig import REAL_TIME_LINK_TIMEOUT_S, REAL_TIME_MISMATCH_TIME_S

from hv_driver import ChannelConfig, HvSupply
from hv_driver.clock import SimulatedClock
from sim_fallback.hv_supply import SimulatedSupply
from sim_fallback.memory_port import MemoryPort


class ScriptedPort:
    """pyserial stand-in that plays (sent, reply) pairs; fails on unexpected writes and leftovers."""

    def __init__(self, exchanges):
        self.exchanges = list(exchanges)
        self.buffer = bytearray()
        self.flushed = 0

    def write(self, data: bytes) -> int:
        assert self.exchanges, f"unexpected write {data!r}"
        sent, reply = self.exchanges.pop(0)
        assert data == sent, f"wrote {data!r}, script expects {sent!r}"
        if isinstance(reply, Exception):
            raise reply
        self.buffer += reply
        return len(data)

    @property
    def in_waiting(self) -> int:
        return len(self.buffer)

    def read(self, size: int = 1) -> bytes:
        if not self.buffer:
            time.sleep(0.001)  # a real port waits for its timeout; keep the loop from spinning
        chunk = bytes(self.buffer[:size])
        del self.buffer[:size]
        return chunk

    def reset_input_buffer(self) -> None:
        self.flushed += 1
        self.buffer.clear()

    def assert_done(self) -> None:
        assert not self.exchanges, f"exchanges never sent: {self.exchanges}"
        assert not self.buffer, f"reply bytes never read: {bytes(self.buffer)!r}"


@pytest.fixture
def scripted_port():
    ports = []

    def make(exchanges):
        ports.append(ScriptedPort(exchanges))
        return ports[-1]
    yield make
    for port in ports:
        port.assert_done()


# Fast limits so ramps in tests take a fraction of a second.
FAST = dict(max_voltage_v=3000.0, slew_rate_v_per_s=8000.0, mismatch_tolerance_v=150.0, mismatch_time_s=0.2)
CHANNELS = [ChannelConfig("front", 0, **FAST), ChannelConfig("back", 1, **FAST)]


@pytest.fixture
def channels():
    """The fast two-channel configuration (a fixture: test modules cannot import a conftest by name when
    several test folders, each with its own conftest, run together)."""
    return CHANNELS


@pytest.fixture
def clock():
    """The simulated time of a test: the supply's loop and the simulated device both run on it."""
    return SimulatedClock()


@pytest.fixture
def sim(clock):
    """A two-channel simulated iseg module on the test's simulated clock (no pty: `memory_port` links it)."""
    return SimulatedSupply(channels=2, clock=clock)


@pytest.fixture
def supply(sim, clock):
    # The heartbeat watchdog stays on, with a timeout longer than any test holds an output without a request
    # (its own tests set a short one).
    hv = HvSupply(MemoryPort(sim), channels=CHANNELS, link_timeout_s=0.5, heartbeat_timeout_s=30.0,
                  handle_signals=False, clock=clock).open()
    yield hv
    hv.abort()


@pytest.fixture
def token(supply):
    """The test's control session of ``supply``."""
    return supply.claim_control("test")


@pytest.fixture
def pty_sim():
    """A simulated iseg module on a real pty, served in its own thread in real time (integration tests)."""
    supply = SimulatedSupply(channels=2).start()
    yield supply
    supply.stop()


@pytest.fixture
def pty_supply(pty_sim):
    channels = [dataclasses.replace(config, mismatch_time_s=REAL_TIME_MISMATCH_TIME_S) for config in CHANNELS]
    hv = HvSupply(pty_sim.port, channels=channels, link_timeout_s=REAL_TIME_LINK_TIMEOUT_S, heartbeat_timeout_s=30.0,
                  handle_signals=False).open()
    yield hv
    hv.abort()


@pytest.fixture
def wait_until():
    """``wait_until(predicate, what)``: the real-time wait of the integration tests (tests/waiting.py)."""
    return waiting.wait_until


@pytest.fixture
def background():
    """``background(fn)`` runs fn in a thread that is joined at teardown."""
    threads = []

    def start(function):
        thread = threading.Thread(target=function, daemon=True)
        thread.start()
        threads.append(thread)
        return thread
    yield start
    for thread in threads:
        thread.join(timeout=5.0)
