"""Fault -> 0 V in simulated time: each fault the HV supervisor answers, on every dialect, with the node's default
limits (config/hv_driver.yaml: slew 1000 V/s, link timeout 0.5 s, heartbeat timeout 2 s) at 2.4 kV.

The driver's loop and the simulated supplies run on one SimulatedClock, linked in memory (sim_fallback.memory_port),
so every number is deterministic: the time from the fault to the first cycle that finds it latched (a cycle whose
exchanges fail takes their reply timeouts), and to the output falling through 50 V, timed exactly by the simulated
device's own output. These are the supervisor's own bounds, without a
host's scheduling; what a loaded host adds is measured by benchmarks/hv_loop.py. Writes
docs/figures/hv_fault_bounds.json and .png:
    scripts/with_env.sh python benchmarks/hv_fault_bounds.py
"""
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from hv_driver import ChannelConfig, Fault, HvSupply  # noqa: E402
from hv_driver.clock import SimulatedClock  # noqa: E402
from hv_driver.dialects import DIALECTS, CurrentSensing, dialect  # noqa: E402
from sim_fallback.memory_port import MemoryPort  # noqa: E402
from sim_fallback.rig import SIMULATORS  # noqa: E402

FIGURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "figures")
VOLTS, SAFE_V = 2400.0, 50.0
LINK_TIMEOUT_S, HEARTBEAT_TIMEOUT_S = 0.5, 2.0
DEAF_S = 1.0  # how long the deaf supply stays deaf
# scenario -> the fault it latches (an arc on a supply without current readback: BREAKDOWN, see `expected`)
SCENARIOS = {"arc": Fault.OVER_CURRENT, "no_reply": Fault.LINK, "deaf": Fault.LINK,
             "readback_drift": Fault.READBACK_MISMATCH, "client_silent": Fault.HEARTBEAT, "estop": Fault.ESTOP}


def expected(name: str, fault: str) -> Fault:
    """The fault the supply of dialect ``name`` lets the supervisor name for ``fault``."""
    blind = dialect(name).capabilities.current is CurrentSensing.NONE
    return Fault.BREAKDOWN if fault == "arc" and blind else SCENARIOS[fault]


def scenario(name: str, fault: str) -> dict:
    """One channel at 2.4 kV on one simulated supply of dialect ``name``; the fault; the times [s] from it."""
    clock = SimulatedClock()
    sim = SIMULATORS[name](1, clock=clock)
    supply = HvSupply(MemoryPort(sim), channels=[ChannelConfig("leg", 0)], dialect=dialect(name),
                      link_timeout_s=LINK_TIMEOUT_S, heartbeat_timeout_s=HEARTBEAT_TIMEOUT_S, handle_signals=False,
                      clock=clock).open()
    try:
        token = supply.claim_control("hv_fault_bounds")
        supply.enable("leg")
        ramp = supply.ramp_to("leg", VOLTS, token=token)
        while not ramp.done:
            supply.heartbeat(token)
            supply.run_for(0.1)
        sim.watch(0, SAFE_V)
        start = clock()
        if fault == "estop":
            supply.estop()
        elif fault == "client_silent":
            pass  # the client's last sign of life was its last heartbeat, just before
        else:
            sim.inject({"arc": "over_current"}.get(fault, fault), 0)
            if fault == "deaf":
                clock.call_at(start + DEAF_S, sim.clear_faults)
        named, latched = expected(name, fault), None
        while (not sim.edges(0, falling=True) or latched is None) and clock() - start < 20.0:
            supply.step()
            if latched is None and named in supply.snapshot().channel("leg").faults:
                latched = clock() - start
        falls = sim.edges(0, falling=True)
        return {"fault": named.name, "latched_s": latched, "below_50_v_s": falls[0] - start if falls else None}
    finally:
        supply.abort()


def main() -> int:
    results = {fault: {name: scenario(name, fault) for name in DIALECTS} for fault in SCENARIOS}
    os.makedirs(FIGURES, exist_ok=True)
    record = {"volts": VOLTS, "slew_rate_v_per_s": ChannelConfig("leg", 0).slew_rate_v_per_s,
              "link_timeout_s": LINK_TIMEOUT_S, "heartbeat_timeout_s": HEARTBEAT_TIMEOUT_S, "deaf_s": DEAF_S,
              "results": results}
    with open(os.path.join(FIGURES, "hv_fault_bounds.json"), "w") as out:
        json.dump(record, out, indent=2)
    figure, axes = plt.subplots(figsize=(9, 4))
    width = 0.8 / len(DIALECTS)
    for k, name in enumerate(DIALECTS):
        values = [results[fault][name]["below_50_v_s"] or 0.0 for fault in SCENARIOS]
        axes.bar([i + k * width for i in range(len(SCENARIOS))], values, width, label=name)
    axes.set_xticks([i + width for i in range(len(SCENARIOS))], list(SCENARIOS))
    axes.set_ylabel("fault -> output below 50 V [s, simulated]")
    axes.set_yscale("log")
    axes.legend()
    axes.set_title(f"{VOLTS:g} V, node defaults; deaf: the supply hears the cut only after {DEAF_S:g} s")
    figure.tight_layout()
    figure.savefig(os.path.join(FIGURES, "hv_fault_bounds.png"), dpi=100)
    for fault, per_dialect in results.items():
        print(fault, {name: (r["latched_s"], r["below_50_v_s"]) for name, r in per_dialect.items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
