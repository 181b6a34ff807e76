"""The HV supervisor in its own process (hv_driver.server), quiet and beside busy loops: control-loop period and
jitter, arc -> emergency-off latency, and SIGKILL of the node at 2.4 kV -> every output below 50 V.

    scripts/with_env.sh python benchmarks/hv_supervisor_process.py [--seconds 10] [--trials 40] [--kills 3]

The simulated iseg module runs in this process on a pty, standing in for the hardware, at SCHED_FIFO priority 40
where permitted (a real supply does not share the host's CPU); the supervisor process talks to it as to a serial
supply. Conditions at the default 100 Hz loop: quiet at the supervisor's SCHED_FIFO 50; two busy loops beside it
at SCHED_FIFO 50; two busy loops at normal priority (realtime_priority 0); and quiet and busy at SCHED_FIFO 50 with
a 200 Hz loop (loop_rate_hz), whose shorter period bounds the arc latency. Loop timing is taken where the device sees it: the arrival of each
cycle's voltage query. Latency: from the injected arc to the simulated output switching off, stamped by the
simulated device. SIGKILL: a node stand-in process ramps front to 2400 V at 1000 V/s, beating its heartbeat, and is
killed; the time until the simulated output is below 50 V is compared with heartbeat timeout + ramp time.
Writes docs/figures/hv_supervisor_process.json and .png.
"""
import argparse
import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path[:0] = [os.path.dirname(os.path.dirname(os.path.abspath(__file__))), os.path.dirname(os.path.abspath(__file__))]
from hv_driver import ChannelConfig, RemoteSupply  # noqa: E402
from hv_loop import summary  # noqa: E402 (this script's folder)
from hv_driver.ramp import MinimumJerkRamp  # noqa: E402
from hv_driver.realtime import make_realtime, normal_priority  # noqa: E402
from sim_fallback.hv_supply import SimulatedSupply  # noqa: E402

FIGURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "figures")
SERVER = [sys.executable, "-m", "hv_driver.server"]
FAST = dict(max_voltage_v=3000.0, slew_rate_v_per_s=8000.0)
HEARTBEAT_TIMEOUT_S = 2.0
KILL_SLEW_V_PER_S = 1000.0
KILL_VOLTAGE_V = 2400.0
# condition: (busy loops beside the supervisor, its SCHED_FIFO priority (0: normal), its loop rate [Hz]).
# An arc is seen at the next current readback, so its latency is bounded by one loop period plus an exchange.
CONDITIONS = {"quiet, SCHED_FIFO 50": (0, 50, 100.0), "2 busy loops, SCHED_FIFO 50": (2, 50, 100.0),
              "2 busy loops, normal priority": (2, 0, 100.0), "quiet, SCHED_FIFO 50, 200 Hz": (0, 50, 200.0),
              "2 busy loops, SCHED_FIFO 50, 200 Hz": (2, 50, 200.0)}
BUSY = [sys.executable, "-c", "while True: pass"]

NODE = """
import json, sys, threading, time
from hv_driver import RemoteSupply
supply = RemoteSupply(json.loads(sys.argv[1]), json.loads(sys.argv[2]), sys.argv[3]).open()
token = supply.claim_control("node stand-in")
def beat():
    while True:
        supply.heartbeat(token)
        time.sleep(0.1)
threading.Thread(target=beat, daemon=True).start()
supply.reset_faults()  # what the last arc left latched in the device
supply.enable("front")
handle = supply.ramp_to("front", float(sys.argv[4]), token=token)
assert handle.wait(60.0) and handle.succeeded, handle.message
print("up", flush=True)
threading.Event().wait()
"""


def spec(port: str, slew: float, priority: int, rate_hz: float) -> dict:
    channels = [ChannelConfig("front", 0, **{**FAST, "slew_rate_v_per_s": slew}),
                ChannelConfig("back", 1, **{**FAST, "slew_rate_v_per_s": slew})]
    return {"ports": [port], "baudrate": None, "channels": [dataclasses.asdict(c) for c in channels],
            "dialect": "iseg-edcp", "loop_rate_hz": rate_hz, "link_timeout_s": 0.5,
            "heartbeat_timeout_s": HEARTBEAT_TIMEOUT_S, "expected_identity": "", "realtime_priority": priority,
            "orphan_timeout_s": 60.0, "keepalive_timeout_s": 1.0}


def loop_intervals(sim, supply, token: str, seconds: float) -> np.ndarray:
    """Ramps streamed on both channels for ``seconds``; the cycle intervals seen by the device [s]."""
    for name in ("front", "back"):
        supply.enable(name)
    start, k = time.monotonic(), 0
    while time.monotonic() - start < seconds:
        handles = [supply.ramp_to(name, (2400.0, 0.0)[k % 2], token=token) for name in ("front", "back")]
        for handle in handles:
            handle.wait(10.0)
        k += 1
    for name in ("front", "back"):
        supply.ramp_to(name, 0.0, token=token).wait(10.0)
    arrivals = np.array([t for t, line in list(sim.command_log) if t >= start and line.startswith(":MEAS:VOLT?")])
    return np.diff(arrivals)


def arc_latencies(sim, supply, trials: int, rate_hz: float, rng: np.random.Generator) -> np.ndarray:
    latencies = []
    for _ in range(trials):
        supply.reset_faults()
        supply.wait_cycles(3)
        supply.enable("front")
        token = supply.claim_control("benchmark")
        supply.ramp_to("front", 500.0, token=token).wait(10.0)
        supply.wait_cycles(1)
        time.sleep(rng.uniform(0.0, 1.0 / rate_hz))  # spread the fault over the loop phase
        t0 = sim.inject("over_current", 0)
        while sim.plant[0].output_on:
            time.sleep(0.001)
        latencies.append(sim.plant[0].off_at - t0)
        sim.clear_faults()
        while abs(supply.snapshot().channel("front").measured_current) > 1e-6:
            supply.wait_cycles(1)
        if supply.snapshot().controller:
            supply.release_control(token)
    return np.array(latencies)


def kill_to_safe(sim, port: str, priority: int, rate_hz: float) -> float:
    """Seconds from SIGKILL of a node stand-in holding 2.4 kV to the simulated output below 50 V."""
    directory = tempfile.mkdtemp(prefix="hv-bench-")
    path = os.path.join(directory, "s.sock")
    node_spec = spec(port, KILL_SLEW_V_PER_S, priority, rate_hz)
    node = subprocess.Popen([sys.executable, "-c", NODE, json.dumps(SERVER), json.dumps(node_spec), path,
                             str(KILL_VOLTAGE_V)], stdout=subprocess.PIPE, text=True, preexec_fn=normal_priority)
    try:
        assert node.stdout.readline().strip() == "up", "the node stand-in did not reach its voltage"
        t0 = time.monotonic()
        os.kill(node.pid, signal.SIGKILL)
        while sim.plant[0].voltage >= 50.0:
            time.sleep(0.002)
        elapsed = time.monotonic() - t0
    finally:
        node.kill()
        node.wait()
    RemoteSupply(SERVER, node_spec, path).open().close()  # take the orphaned supervisor over and end it
    shutil.rmtree(directory, ignore_errors=True)
    return elapsed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="loop timing run per condition [s]")
    parser.add_argument("--trials", type=int, default=40, help="arcs per condition")
    parser.add_argument("--kills", type=int, default=3, help="SIGKILLs of the node per condition")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    os.makedirs(FIGURES, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    device_realtime = make_realtime(40)
    ramp_time = MinimumJerkRamp(KILL_VOLTAGE_V, 0.0, 0.0, KILL_SLEW_V_PER_S).duration
    bound = HEARTBEAT_TIMEOUT_S + ramp_time
    result = {"command": "scripts/with_env.sh python benchmarks/hv_supervisor_process.py " + " ".join(
        argv if argv is not None else sys.argv[1:]), "cpu_count": os.cpu_count(), "device_realtime": device_realtime,
        "kill_bound_s": bound, "conditions": {}}
    data = {}
    for condition, (busy_count, priority, rate_hz) in CONDITIONS.items():
        busy = [subprocess.Popen(BUSY, preexec_fn=normal_priority) for _ in range(busy_count)]
        sim = SimulatedSupply(channels=2).start()
        try:
            time.sleep(1.0)  # the busy loops reach full speed
            print(f"{condition}: loop timing", flush=True)
            with RemoteSupply(SERVER, spec(sim.port, FAST["slew_rate_v_per_s"], priority, rate_hz),
                              os.path.join(tempfile.mkdtemp(prefix="hv-bench-"), "s.sock")) as supply:
                token = supply.claim_control("benchmark")
                intervals = loop_intervals(sim, supply, token, args.seconds)
                supply.release_control(token)
                print(f"{condition}: {args.trials} arcs", flush=True)
                latencies = arc_latencies(sim, supply, args.trials, rate_hz, rng)
            kills = []
            for k in range(args.kills):
                print(f"{condition}: SIGKILL {k + 1}/{args.kills}", flush=True)
                kills.append(kill_to_safe(sim, sim.port, priority, rate_hz))
            load = os.getloadavg()[0]
        finally:
            sim.stop()
            for process in busy:
                process.kill()
                process.wait()
        data[condition] = (intervals, latencies, np.array(kills), rate_hz)
        result["conditions"][condition] = {
            "loop_rate_hz_set": rate_hz, "loop_rate_hz_median": float(1.0 / np.median(intervals)), "cycle_interval_ms": summary(intervals),
            "jitter_ms": summary(np.abs(intervals * 1e3 - 1e3 / rate_hz), scale=1.0),
            "arc_to_off_ms": summary(latencies), "kill_to_below_50_v_s": [float(t) for t in kills],
            "kills_within_bound": int(sum(t <= bound for t in kills)), "load_average_1min": load}
    with open(os.path.join(FIGURES, "hv_supervisor_process.json"), "w") as stream:
        json.dump(result, stream, indent=2)
    plot(data, bound)
    print(json.dumps(result, indent=2))
    return 0


def plot(data: dict, bound: float) -> None:
    fig, (ax_loop, ax_arc, ax_kill) = plt.subplots(1, 3, figsize=(15, 4.2))
    for k, (condition, (intervals, latencies, kills, rate_hz)) in enumerate(data.items()):
        ax_loop.hist(intervals * 1e3, bins=60, histtype="step", color=f"C{k}",
                     label=f"{condition}: p99 {np.percentile(intervals, 99) * 1e3:.1f} ms")
        ordered = np.sort(latencies) * 1e3
        ax_arc.step(ordered, np.arange(1, ordered.size + 1) / ordered.size, where="post", color=f"C{k}",
                    label=f"{condition}: p99 {np.percentile(ordered, 99):.1f} ms")
        ax_kill.plot([k] * kills.size, kills, "o", color=f"C{k}")
        ax_loop.axvline(1e3 / rate_hz, color=f"C{k}", ls="--", lw=1)
    ax_loop.set(xlabel="cycle interval at the device [ms]", ylabel="cycles", yscale="log", title="control loop")
    ax_loop.legend(fontsize=7)
    for target, style in ((10.0, "--"), (20.0, ":")):
        ax_arc.axvline(target, color="k", ls=style, lw=1, label=f"{target:g} ms goal")
    ax_arc.set(xlabel="arc to output off [ms]", ylabel="fraction of arcs", xscale="log", title="arc -> emergency off")
    ax_arc.legend(fontsize=7, loc="lower right")
    ax_kill.axhline(bound, color="k", ls="--", lw=1, label=f"heartbeat timeout + ramp time ({bound:.2f} s)")
    ax_kill.set(xticks=range(len(data)), xticklabels=[c.replace(", ", "\n") for c in data], ylabel="s",
                title="SIGKILL of the node at 2.4 kV -> below 50 V", ylim=(0, bound * 1.2))
    ax_kill.tick_params(axis="x", labelsize=7)
    ax_kill.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(FIGURES, "hv_supervisor_process.png"), dpi=120)


if __name__ == "__main__":
    sys.exit(main())
