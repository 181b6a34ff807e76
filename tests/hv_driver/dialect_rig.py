"""`Rig`: each dialect's simulated supplies behind one HvSupply, for the tests that run the same scenario on every
dialect."""
import numpy as np

from hv_driver import ChannelConfig, HvSupply
from hv_driver.clock import SimulatedClock
from hv_driver.dialects import dialect
from sim_fallback.memory_port import MemoryPort
from sim_fallback.rig import SIMULATORS


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
        assert all(h.wait(5.0) for h in handles)
        return handles

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
