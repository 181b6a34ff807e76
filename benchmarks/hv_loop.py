"""HV control loop over ptys against each simulated supply: loop rate, jitter, fault-to-off latency per dialect.

Two channels per dialect: one two-channel iseg module, or two single-channel Keithley 2290 units / PPV boards
(two ports behind one driver). Writes docs/figures/hv_loop.json and docs/figures/hv_loop.png.
    scripts/with_env.sh python benchmarks/hv_loop.py [--seconds 10] [--trials 40] [--dialects ppv ...]
Loop timing is taken where the device sees it: arrival times of each cycle's voltage query at the first
simulated supply. Latency = time from the fault (injection, or the estop() call) to the simulated output
switching off, stamped by the simulated device. An over-current is an arc: the iseg and Keithley see the
current, the PPV (no current readback) only the voltage collapsing (BREAKDOWN, two readbacks below half the
held setpoint).
"""
import argparse
import json
import os
import sys
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from hv_driver import ChannelConfig, HvSupply  # noqa: E402
from hv_driver.dialects import DIALECTS, dialect  # noqa: E402
from sim_fallback.rig import SIMULATORS  # noqa: E402

FIGURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "figures")
LOOP_RATE_HZ = 100.0
LIMITS = dict(max_voltage_v=3000.0, slew_rate_v_per_s=8000.0)
CLIENT = "hv_loop benchmark"  # the client holding control of the supply


def start_rig(name: str):
    """The simulated supplies of ``name`` for channels front and back; (simulators, channel configs)."""
    cls = SIMULATORS[name]
    if cls.dialect.capabilities.channels_per_device == 1:
        sims = [cls(1, rng=k).start() for k in range(2)]
        return sims, [ChannelConfig("front", 0, device=0, **LIMITS), ChannelConfig("back", 0, device=1, **LIMITS)]
    return [cls(2).start()], [ChannelConfig("front", 0, **LIMITS), ChannelConfig("back", 1, **LIMITS)]


def measure_loop(sim, hv, token: str, seconds: float, dialect_name: str) -> np.ndarray:
    """Stream ramps on both channels for ``seconds``; return the cycle intervals seen by the device [s]."""
    for name in ("front", "back"):
        hv.enable(name)
    start, targets = time.monotonic(), [2400.0, 0.0]
    k = 0
    while time.monotonic() - start < seconds:
        handles = [hv.ramp_to(name, targets[k % 2], token=token) for name in ("front", "back")]
        for handle in handles:
            handle.wait(5.0)
        k += 1
        print(f"{dialect_name} loop: {time.monotonic() - start:5.1f} / {seconds:g} s", flush=True)
    for name in ("front", "back"):
        hv.ramp_to(name, 0.0, token=token).wait(5.0)
    query = DIALECTS[dialect_name].commands["measure_voltage"].template.split(" ")[0]
    arrivals = np.array([t for t, line in sim.command_log if t >= start and line.startswith(query)])
    return np.diff(arrivals)


def fault_latency(sim, hv, trials: int, cause: str, rng: np.random.Generator, dialect_name: str) -> np.ndarray:
    """Fault-to-output-off latencies [s] over ``trials`` runs of ``cause`` ("over_current" / "estop")."""
    latencies = []
    for trial in range(trials):
        hv.reset_faults()
        hv.wait_cycles(3)
        hv.enable("front")
        token = hv.claim_control(CLIENT)  # a fresh session: an e-stop ends the last one
        hv.ramp_to("front", 500.0, token=token).wait(5.0)
        hv.wait_cycles(1)
        time.sleep(rng.uniform(0.0, 1.0 / LOOP_RATE_HZ))  # spread the fault over the loop phase
        if cause == "estop":
            t0 = time.monotonic()
            hv.estop()
        else:
            t0 = sim.inject("over_current", 0)
        while sim.plant[0].output_on:
            time.sleep(0.005)  # the off time is stamped by the simulated device itself
        latencies.append(sim.plant[0].off_at - t0)
        sim.clear_faults()
        while abs(hv.snapshot().channel("front").measured_current) > 1e-6:  # averaged readback settles
            hv.wait_cycles(1)
        if hv.snapshot().controller:
            hv.release_control(token)
        if (trial + 1) % 10 == 0:
            print(f"{dialect_name} {cause}: trial {trial + 1}/{trials}", flush=True)
    return np.array(latencies)


def summary(values: np.ndarray, scale: float = 1e3) -> dict:
    return {"median": float(np.median(values) * scale), "p99": float(np.percentile(values, 99) * scale),
            "max": float(values.max() * scale), "n": int(values.size)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="loop timing run length [s]")
    parser.add_argument("--trials", type=int, default=40, help="fault injections per cause")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dialects", nargs="+", choices=list(DIALECTS), default=list(DIALECTS))
    args = parser.parse_args(argv)
    os.makedirs(FIGURES, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    period_ms = 1e3 / LOOP_RATE_HZ
    result = {"command": "scripts/with_env.sh python benchmarks/hv_loop.py " + " ".join(argv or sys.argv[1:]),
              "loop_rate_hz_setting": LOOP_RATE_HZ, "cpu_count": os.cpu_count(), "dialects": {}}
    intervals, latencies = {}, {}
    for name in args.dialects:
        sims, configs = start_rig(name)
        try:
            with HvSupply([sim.port for sim in sims], channels=configs, loop_rate_hz=LOOP_RATE_HZ,
                          dialect=dialect(name), handle_signals=False) as hv:
                token = hv.claim_control(CLIENT)
                intervals[name] = measure_loop(sims[0], hv, token, args.seconds, name)
                hv.release_control(token)
                latencies[name] = {cause: fault_latency(sims[0], hv, args.trials, cause, rng, name)
                                   for cause in ("over_current", "estop")}
        finally:
            for sim in sims:
                sim.stop()
        result["dialects"][name] = {
            "loop_rate_hz_median": float(1.0 / np.median(intervals[name])),
            "cycle_interval_ms": summary(intervals[name]),
            "jitter_ms": summary(np.abs(intervals[name] * 1e3 - period_ms), scale=1.0),
            "fault_to_off_ms": {cause: summary(values) for cause, values in latencies[name].items()},
            "load_average_1min": os.getloadavg()[0]}
    with open(os.path.join(FIGURES, "hv_loop.json"), "w") as stream:
        json.dump(result, stream, indent=2)
    fig, (ax_loop, ax_lat) = plt.subplots(1, 2, figsize=(11, 4.2))
    for k, (name, values) in enumerate(intervals.items()):
        ax_loop.hist(values * 1e3, bins=60, histtype="step", color=f"C{k}",
                     label=f"{name}: median {result['dialects'][name]['loop_rate_hz_median']:.1f} Hz")
        for cause, style in (("over_current", "-"), ("estop", ":")):
            ordered = np.sort(latencies[name][cause]) * 1e3
            ax_lat.step(ordered, np.arange(1, ordered.size + 1) / ordered.size, where="post", ls=style,
                        color=f"C{k}", label=f"{name} {cause}: median {np.median(ordered):.1f} ms")
    ax_loop.axvline(period_ms, color="k", ls="--", lw=1, label=f"{period_ms:g} ms period")
    ax_loop.set(xlabel="cycle interval at the device [ms]", ylabel="cycles", yscale="log", title="control loop")
    ax_loop.legend(fontsize=8)
    ax_lat.axvline(20.0, color="k", ls="--", lw=1, label="20 ms target")
    ax_lat.set(xlabel="fault to output off [ms]", ylabel="fraction of trials", xscale="log",
               title="fault-to-off latency per supply")
    ax_lat.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(os.path.join(FIGURES, "hv_loop.png"), dpi=120)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
