"""`Rig`: each dialect's simulated supplies behind one HvSupply, for the tests that run the same scenario on every
dialect; steps the driver tests share, in simulated and in real time."""
import numpy as np

from hv_driver import ChannelConfig, HvSupply
from hv_driver.clock import SimulatedClock
from hv_driver.dialects import dialect
from hv_driver.dialects.base import CurrentSensing
from sim_fallback.memory_port import MemoryPort
from sim_fallback.rig import SIMULATORS

# Ramps of a fraction of a second. The trip leaves room for the charging current of a host-ramped supply (Keithley):
# its output follows each setpoint step with a 10 ms lag into 2 nF, and a cycle whose exchange with one supply ran
# late sends the other two steps of up to two periods' slew each almost at once (test_dialects_sim.py's Keithley
# test); an arc (2 mA) and ten times the load still trip it.
FAST_LIMITS = dict(max_voltage_v=3000.0, slew_rate_v_per_s=8000.0, mismatch_tolerance_v=150.0, mismatch_time_s=0.2,
                   current_trip_a=100e-6)

# On real ptys in real time the host's speed must not decide an outcome: the link window (and with it each reply's,
# a quarter of it) and the readback window are longer than any stall of a loaded host, and the trip is above the
# largest charging current any gap between setpoint and output can draw from a host-ramped supply (Keithley): up to
# max_voltage_v into 2 nF with its 10 ms lag, 2 nF x 3 kV / 10 ms = 0.6 mA (test_dialects_sim.py). The windows'
# timing and the trip are tested in simulated time.
REAL_TIME_LINK_TIMEOUT_S = 20.0
REAL_TIME_MISMATCH_TIME_S = 20.0
REAL_TIME_CURRENT_TRIP_A = 1e-3
WAIT_S = 60.0  # [s] of the clock the rig runs on: a wait ends at its event, the deadline only when that never comes


def all_off(sim) -> bool:
    return not any(ch.output_on for ch in sim.plant)


def ramp_both(supply, token, volts):
    for name in ("front", "back"):
        supply.enable(name)
    handles = [supply.ramp_to(name, volts, token=token) for name in ("front", "back")]
    assert all(h.wait(WAIT_S) for h in handles)
    assert all(h.succeeded for h in handles), [h.message for h in handles]


class Rig:
    """Two channels ``a`` and ``b`` with ``limits`` (ChannelConfig fields) of the dialect's simulator(s) behind one
    HvSupply, control claimed (``token``): one two-channel iseg module, or two single-channel devices (two ports).
    With ``clock`` (a SimulatedClock) the simulators are linked in memory and everything runs in simulated time,
    each line taking ``exchange_s`` on the wire; without, they serve real ptys in real time. ``options``: further
    arguments of the simulators."""

    def __init__(self, name: str, limits: dict, link_timeout_s: float, clock: SimulatedClock | None = None,
                 exchange_s: float = 0.0, **options):
        cls = SIMULATORS[name]
        single = cls.dialect.capabilities.channels_per_device == 1
        self.clock = clock
        options = options if clock is None else {**options, "clock": clock}
        self.sims = [cls(1, rng=k, **options) for k in range(2)] if single else [cls(2, **options)]
        if clock is None:
            for sim in self.sims:
                sim.start()
        # channel -> (simulator, plant index)
        self.where = {"a": (self.sims[0], 0), "b": (self.sims[-1], 0 if single else 1)}
        configs = [ChannelConfig("a", 0, device=0, **limits),
                   ChannelConfig("b", 0 if single else 1, device=1 if single else 0, **limits)]
        ports = [s.port for s in self.sims] if clock is None else [MemoryPort(s, exchange_s) for s in self.sims]
        self.supply = HvSupply(ports, channels=configs, dialect=dialect(name), link_timeout_s=link_timeout_s,
                               heartbeat_timeout_s=30.0, handle_signals=False, clock=clock).open()
        self.token = self.supply.claim_control("test")

    def plant(self, channel: str):
        sim, index = self.where[channel]
        return sim.plant[index]

    def inject(self, fault: str, channel: str | None = None) -> None:
        targets = [self.where[channel]] if channel else [(sim, None) for sim in self.sims]
        for sim, index in targets:
            sim.inject(fault, index)

    def ramp(self, volts: float) -> list:
        for name in "ab":
            self.supply.enable(name)
        handles = [self.supply.ramp_to(name, volts, token=self.token) for name in "ab"]
        assert all(h.wait(WAIT_S) for h in handles)
        return handles

    def check_ramps_both_channels(self, wait) -> None:
        """Both channels ramped to 2400 V and back without a fault; ``wait(predicate)`` is true once the predicate
        holds (on the rig's clock)."""
        handles = self.ramp(2400.0)
        assert all(h.succeeded for h in handles), [h.message for h in handles]
        assert wait(lambda: all(abs(self.plant(c).voltage - 2400.0) < 5.0 for c in "ab"))
        snapshot = self.supply.snapshot()
        assert not any(c.faults for c in snapshot.channels)
        if self.supply.dialect.capabilities.current is CurrentSensing.NONE:  # NaN, never a made-up 0 A
            assert all(c.measured_current != c.measured_current for c in snapshot.channels)
        else:  # at rest the charging current is gone; the loop may still hold a reading from the ramp's end
            assert wait(lambda: all(abs(c.measured_current) < 1e-5 for c in self.supply.snapshot().channels))
        for handle in [self.supply.ramp_to(c, 0.0, token=self.token) for c in "ab"]:
            assert handle.wait(WAIT_S) and handle.succeeded

    def watch(self, channel: str, level: float) -> None:
        sim, index = self.where[channel]
        sim.watch(index, level)

    def edges(self, channel: str, falling: bool = False) -> np.ndarray:
        sim, index = self.where[channel]
        return np.array(sim.edges(index, falling))

    def close(self) -> None:
        self.supply.abort()
        for sim in self.sims:
            sim.stop()
