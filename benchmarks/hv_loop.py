"""The HV supervisor in its own process (hv_driver.server), quiet and beside busy loops: the control loop's cycle
intervals, fault -> emergency-off latency and what it is made of, and SIGKILL of the node at 2.4 kV -> every output
below 50 V.

    scripts/with_env.sh python benchmarks/hv_loop.py [--seconds 10] [--trials 40] [--kills 3] [--dialect iseg-edcp]

The supervisor process runs as the node starts it (`python -m hv_driver.server`, its spec from the node's defaults)
over the simulated supplies of one dialect on ptys, which stand in for the hardware in this process at SCHED_FIFO 40
where permitted (a real supply does not share the host's CPU). The node is a stand-in process at normal priority
that loads the supervisor as `hv_driver_node` does: `snapshot()` at the hv/state rate (50 Hz) and its client's
heartbeats (10 Hz) forwarded while it holds control; it ramps, and sets up each trial, on this script's word.

Conditions: quiet at the supervisor's SCHED_FIFO 50; two busy loops beside it at SCHED_FIFO 50; two busy loops at
normal priority (realtime_priority 0); each at the shipped loop rate, and quiet at 100 Hz for comparison.
- Cycle intervals: the arrivals of each cycle's voltage query at the first simulated supply while both channels
  stream ramps; their distribution, not only its percentiles (a request runs a cycle at once: a short interval).
- Fault -> off: an arc (over-current; on a supply without current readback, the voltage collapsing) injected at a
  random phase of the loop; from the injection to the simulated output switching off, stamped by the simulated
  device, split into the wait for the next readback (the first readback line the device receives after the fault),
  the reaction (from there to the cut line: that cycle's readbacks and the supervisor's decision) and the device
  (cut line to output off).
- SIGKILL: the stand-in ramps one channel to 2.4 kV at 1000 V/s and is killed; the time until the simulated output is
  below 50 V, against heartbeat timeout + ramp time. A new stand-in then takes the orphaned supervisor over.
Writes docs/figures/hv_loop.json and docs/figures/hv_loop.png.
"""
import argparse
import dataclasses
import inspect
import json
import math
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

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from hv_driver import ChannelConfig, HvSupply  # noqa: E402
from hv_driver.dialects import DIALECTS, dialect  # noqa: E402
from hv_driver.ramp import MinimumJerkRamp  # noqa: E402
from hv_driver.realtime import make_realtime, normal_priority  # noqa: E402
from hv_driver.supervisor import DEFAULT_HEARTBEAT_TIMEOUT_S  # noqa: E402
from sim_fallback.rig import SIMULATORS  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FIGURES = os.path.join(ROOT, "docs", "figures")
SERVER = [sys.executable, "-m", "hv_driver.server"]
SHIPPED_RATE_HZ = inspect.signature(HvSupply).parameters["loop_rate_hz"].default  # the node's default too
FAST = dict(max_voltage_v=3000.0, slew_rate_v_per_s=8000.0)
KILL_SLEW_V_PER_S = 1000.0
KILL_VOLTAGE_V = 2400.0
ARC_VOLTAGE_V = 500.0
SAFE_V = 50.0
EVENT_DEADLINE_S = 30.0  # for an output to switch off or fall: a supervisor that never cuts fails the run
DEVICE_PRIORITY = 40
COMPARISON_RATE_HZ = 100.0  # the loop rate shipped before: a fault waits up to one period for its readback
BUSY = [sys.executable, "-c", "while True: pass"]
STATE_RATE_HZ = 50.0      # the node's hv/state timer: one snapshot() each
HEARTBEAT_RATE_HZ = 10.0  # its client's heartbeats (softblock_ros.hv_control), forwarded one request each

# The node stand-in: opens the supervisor as the node does, polls snapshot() at the hv/state rate, forwards its
# client's heartbeats while it holds control, and runs one command per stdin line, answering one stdout line.
NODE = f"""
import json, sys, threading, time
from hv_driver import HvError, RemoteSupply
supply = RemoteSupply(json.loads(sys.argv[1]), json.loads(sys.argv[2]), sys.argv[3]).open()
held = {{"token": None}}
ATTEMPTS = 10
def state():
    while True:
        supply.snapshot()
        time.sleep(1 / {STATE_RATE_HZ})
def beats():  # forwarded as the node forwards its client's: at once, the answer not awaited
    while True:
        token = held["token"]
        if token is not None:
            try:
                supply.forward_heartbeat(token, lambda error: None)  # a beat of a session just ended is refused
            except HvError:  # the supply closed
                return
        time.sleep(1 / {HEARTBEAT_RATE_HZ})
threading.Thread(target=state, daemon=True).start()
threading.Thread(target=beats, daemon=True).start()
def claim():
    if held["token"] is not None and supply.snapshot().controller:
        supply.release_control(held["token"])
    held["token"] = supply.claim_control("benchmark")
    return held["token"]
def arm(volts, channel):  # reset, then ramp; returns the attempts a fault (a starved process) failed
    for failed in range(ATTEMPTS):
        for _ in range(100):  # until the last arc's averaged current readback has decayed below the trip
            supply.reset_faults()
            supply.wait_cycles(3)
            if not supply.snapshot().channel(channel).faults:
                break
        try:
            supply.enable(channel)
            handle = supply.ramp_to(channel, volts, token=claim())
            if handle.wait(60.0) and handle.succeeded:
                supply.wait_cycles(2)
                return failed
            reason = handle.message
        except HvError as error:
            reason = str(error)
        print(f"node stand-in: arming failed, again: {{reason}}", file=sys.stderr, flush=True)
    raise RuntimeError(f"arming failed {{ATTEMPTS}} times")
def both_on():
    supply.reset_faults()
    supply.wait_cycles(3)
    for name in ("front", "back"):
        supply.enable(name)
    return claim()
def stream(seconds):  # ramps on both channels; returns how often a fault (a starved process) interrupted them
    token, interrupted = both_on(), 0
    start, k = time.monotonic(), 0
    while time.monotonic() - start < seconds:
        try:
            handles = [supply.ramp_to(name, (2400.0, 0.0)[k % 2], token=token) for name in ("front", "back")]
            for handle in handles:
                handle.wait(10.0)
        except HvError as error:
            print(f"node stand-in: streaming interrupted, again: {{error}}", file=sys.stderr, flush=True)
            token, interrupted = both_on(), interrupted + 1
        k += 1
    for name in ("front", "back"):
        supply.disable(name)
    supply.wait_outputs_off(10.0)
    return interrupted
print("ready", flush=True)
for line in sys.stdin:
    verb, *args = line.split()
    if verb == "close":
        supply.close()
        print("closed", flush=True)
        break
    print(f"ok {{arm(float(args[0]), args[1]) if verb == 'arm' else stream(float(args[0]))}}", flush=True)
"""


@dataclasses.dataclass(frozen=True)
class Condition:
    name: str
    busy_loops: int
    priority: int   # the supervisor's SCHED_FIFO priority; 0: normal scheduling
    rate_hz: float


class Progress:
    """One line that shows where the run is (rewritten in place on a terminal)."""

    def __init__(self):
        self._tty = sys.stdout.isatty()

    def show(self, text: str) -> None:
        if self._tty:
            print(f"\r\033[K{text}", end="", flush=True)
        else:
            print(text, flush=True)

    def done(self) -> None:
        if self._tty:
            print(flush=True)


class Node:
    """The node stand-in process (normal priority, as the node runs)."""

    def __init__(self, spec: dict, path: str):
        self.process = subprocess.Popen([sys.executable, "-c", NODE, json.dumps(SERVER), json.dumps(spec), path],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT,
                                        preexec_fn=normal_priority)
        self.interrupted = 0
        self._expect("ready")

    def _expect(self, word: str) -> str:
        """What the stand-in said after ``word``."""
        line = self.process.stdout.readline().strip()
        said, _, rest = line.partition(" ")
        if said != word:
            raise RuntimeError(f"node stand-in said {line!r}, not {word!r} (see its error above)")
        return rest

    def run(self, command: str) -> None:
        """``arm VOLTS CHANNEL`` (reset, ramp) or ``stream SECONDS``; counts in ``interrupted`` how often a fault
        interrupted it and it started again (the stand-in starved past its keep-alive timeout: NODE_LOST, or the
        simulated supply past the link timeout: LINK)."""
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()
        self.interrupted += int(self._expect("ok"))

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.stdin.write("close\n")
            self.process.stdin.flush()
            self._expect("closed")
            self.process.wait(timeout=30.0)

    def kill(self) -> None:
        self.process.kill()
        self.process.wait()


def supervisor_spec(name: str, ports: list[str], priority: int, rate_hz: float, slew: float) -> dict:
    """What the node sends its supervisor process (hv_driver_node._supervisor_spec), with the node's defaults."""
    single = SIMULATORS[name].dialect.capabilities.channels_per_device == 1
    channels = [ChannelConfig("front", 0, device=0, **{**FAST, "slew_rate_v_per_s": slew}),
                ChannelConfig("back", 0 if single else 1, device=1 if single else 0,
                              **{**FAST, "slew_rate_v_per_s": slew})]
    return {"ports": ports, "baudrate": None, "channels": [dataclasses.asdict(c) for c in channels], "dialect": name,
            "loop_rate_hz": rate_hz, "link_timeout_s": 0.5, "heartbeat_timeout_s": DEFAULT_HEARTBEAT_TIMEOUT_S,
            "expected_identity": "", "realtime_priority": priority, "orphan_timeout_s": 60.0,
            "keepalive_timeout_s": 1.0}


def start_supplies(name: str) -> list:
    """The simulated supplies of ``name`` for front and back: one two-channel module, or two single-channel units."""
    cls = SIMULATORS[name]
    if cls.dialect.capabilities.channels_per_device == 1:
        return [cls(1, rng=k).start() for k in range(2)]
    return [cls(2).start()]


def wait_until(predicate, what: str) -> None:
    deadline = time.monotonic() + EVENT_DEADLINE_S
    while not predicate():
        if time.monotonic() > deadline:
            raise RuntimeError(f"no {what} within {EVENT_DEADLINE_S:g} s")
        time.sleep(0.001)


def first_line(sim, prefix: str, after: float) -> float:
    """When the simulated supply received the first line starting with ``prefix`` after ``after`` (NaN: none)."""
    return next((t for t, line in list(sim.command_log) if t > after and line.startswith(prefix)), math.nan)


def cycle_intervals(sim, node: Node, name: str, seconds: float) -> np.ndarray:
    """Both channels streaming ramps for ``seconds``; the cycle intervals seen by the supply [s]."""
    start = time.monotonic()
    node.run(f"stream {seconds}")
    query = DIALECTS[name].commands["measure_voltage"].template.split(" ")[0]
    return np.diff([t for t, line in list(sim.command_log) if t >= start and line.startswith(query)])


def fault_latencies(sim, node: Node, name: str, condition: Condition, trials: int, rng: np.random.Generator,
                    progress: Progress) -> np.ndarray:
    """Per arc: (injection -> output off, -> the first of the cycle's readback lines after it, -> the cut line) [s]:
    the wait for a readback, the rest of that cycle's readbacks with the supervisor's reaction, the device."""
    commands, capabilities = DIALECTS[name].commands, DIALECTS[name].capabilities
    readbacks = [commands[operation].template.split(" ")[0] for operation in
                 ("measure_voltage", "measure_current", *capabilities.status_operations) if operation in commands]
    cut = commands["emergency_off" if capabilities.emergency_off else "output_off"].template.split("{")[0].rstrip(",")
    rows = []
    for trial in range(trials):
        progress.show(f"{condition.name}: arc {trial + 1}/{trials}")
        node.run(f"arm {ARC_VOLTAGE_V} front")
        time.sleep(rng.uniform(0.0, 1.0 / condition.rate_hz))  # spread the fault over the loop phase
        t0 = sim.inject("over_current", 0)
        wait_until(lambda: not sim.plant[0].output_on, "the output switched off after an arc")
        off = sim.plant[0].off_at
        first_readback = min((t for t in (first_line(sim, prefix, t0) for prefix in readbacks) if t == t),
                             default=math.nan)
        rows.append((off - t0, first_readback - t0, first_line(sim, cut, t0) - t0))
        sim.clear_faults()
    return np.array(rows)


def kill_to_safe(name: str, sims: list, condition: Condition) -> tuple[float, int]:
    """Seconds from SIGKILL of the node stand-in holding 2.4 kV to the simulated output below 50 V, and how often a
    fault interrupted arming it."""
    directory = tempfile.mkdtemp(prefix="hv-bench-")
    path = os.path.join(directory, "s.sock")
    spec = supervisor_spec(name, [sim.port for sim in sims], condition.priority, condition.rate_hz,
                           KILL_SLEW_V_PER_S)
    node = Node(spec, path)
    try:
        node.run(f"arm {KILL_VOLTAGE_V} front")
        t0 = time.monotonic()
        os.kill(node.process.pid, signal.SIGKILL)
        wait_until(lambda: sims[0].plant[0].voltage < SAFE_V, f"the output below {SAFE_V:g} V after the SIGKILL")
        elapsed = time.monotonic() - t0
    finally:
        node.kill()
    Node(spec, path).close()  # takes the orphaned supervisor over (NODE_LOST latched) and ends it
    shutil.rmtree(directory, ignore_errors=True)
    return elapsed, node.interrupted


def distribution(intervals: np.ndarray, period: float) -> dict:
    """The cycle intervals as the share in each band around the period, and their percentiles [ms]."""
    ratio = intervals / period
    bands = {"below 0.5 P (a cycle run at once on a request or a fault)": ratio < 0.5,
             "0.5-0.9 P": (ratio >= 0.5) & (ratio < 0.9), "0.9-1.1 P (on time)": (ratio >= 0.9) & (ratio <= 1.1),
             "1.1-1.5 P": (ratio > 1.1) & (ratio <= 1.5), "1.5-2 P": (ratio > 1.5) & (ratio <= 2.0),
             "above 2 P (a cycle missed)": ratio > 2.0}
    return {"share": {band: float(np.mean(mask)) for band, mask in bands.items()},
            "percentiles_ms": {f"p{q:g}": float(np.percentile(intervals, q) * 1e3) for q in (0.1, 1, 50, 99, 99.9)},
            "max_ms": float(intervals.max() * 1e3), "n": int(intervals.size)}


def summary(values: np.ndarray) -> dict:
    """Median, p99 and max [ms] of the values that were seen; not_seen: trials in which the simulated device
    received no such line between the fault and its output switching off."""
    seen = values[np.isfinite(values)]
    if not seen.size:
        return {"n": 0, "not_seen": int(values.size)}
    return {"median_ms": float(np.median(seen) * 1e3), "p99_ms": float(np.percentile(seen, 99) * 1e3),
            "max_ms": float(seen.max() * 1e3), "n": int(seen.size), "not_seen": int(values.size - seen.size)}


def run_condition(name: str, condition: Condition, args, rng, progress: Progress) -> dict:
    busy = [subprocess.Popen(BUSY, preexec_fn=normal_priority) for _ in range(condition.busy_loops)]
    sims = start_supplies(name)
    directory = tempfile.mkdtemp(prefix="hv-bench-")
    try:
        time.sleep(1.0)  # the busy loops reach full speed
        spec = supervisor_spec(name, [sim.port for sim in sims], condition.priority, condition.rate_hz,
                               FAST["slew_rate_v_per_s"])
        node = Node(spec, os.path.join(directory, "s.sock"))
        try:
            progress.show(f"{condition.name}: cycle intervals, {args.seconds:g} s")
            intervals = cycle_intervals(sims[0], node, name, args.seconds)
            latencies = fault_latencies(sims[0], node, name, condition, args.trials, rng, progress)
            interrupted = node.interrupted
        finally:
            node.close()
        kills = []
        for k in range(args.kills):
            progress.show(f"{condition.name}: SIGKILL of the node {k + 1}/{args.kills}")
            elapsed, failed = kill_to_safe(name, sims, condition)
            kills.append(elapsed)
            interrupted += failed
        load = os.getloadavg()[0]
    finally:
        for sim in sims:
            sim.stop()
        for process in busy:
            process.kill()
            process.wait()
        shutil.rmtree(directory, ignore_errors=True)
    progress.done()
    return {"intervals": intervals, "latencies": latencies, "kills": np.array(kills), "load": load,
            "interrupted": interrupted}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="cycle interval run per condition [s]")
    parser.add_argument("--trials", type=int, default=40, help="arcs per condition")
    parser.add_argument("--kills", type=int, default=3, help="SIGKILLs of the node per condition")
    parser.add_argument("--dialect", choices=list(DIALECTS), default="iseg-edcp")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    os.makedirs(FIGURES, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    rate = SHIPPED_RATE_HZ
    conditions = [Condition(f"quiet, FIFO 50, {rate:g} Hz", 0, 50, rate),
                  Condition(f"2 busy loops, FIFO 50, {rate:g} Hz", 2, 50, rate),
                  Condition(f"2 busy loops, normal priority, {rate:g} Hz", 2, 0, rate)]
    if rate != COMPARISON_RATE_HZ:
        conditions.append(Condition(f"quiet, FIFO 50, {COMPARISON_RATE_HZ:g} Hz", 0, 50, COMPARISON_RATE_HZ))
    device_realtime = make_realtime(DEVICE_PRIORITY)  # the simulated supplies' threads inherit it
    ramp_time = MinimumJerkRamp(KILL_VOLTAGE_V, 0.0, 0.0, KILL_SLEW_V_PER_S).duration
    bound = DEFAULT_HEARTBEAT_TIMEOUT_S + ramp_time
    progress = Progress()
    data = {condition.name: run_condition(args.dialect, condition, args, rng, progress) for condition in conditions}
    result = {"command": "scripts/with_env.sh python benchmarks/hv_loop.py " + " ".join(
        argv if argv is not None else sys.argv[1:]), "dialect": args.dialect, "cpu_count": os.cpu_count(),
        "device_realtime": device_realtime, "shipped_loop_rate_hz": rate, "kill_bound_s": bound, "conditions": {}}
    for condition in conditions:
        measured = data[condition.name]
        latencies = measured["latencies"]
        result["conditions"][condition.name] = {
            "loop_rate_hz": condition.rate_hz, "realtime_priority": condition.priority,
            "busy_loops": condition.busy_loops, "load_average_1min": measured["load"],
            "cycle_interval": distribution(measured["intervals"], 1.0 / condition.rate_hz),
            "fault_to_off": summary(latencies[:, 0]),
            "fault_to_next_readback": summary(latencies[:, 1]),
            "next_readback_to_cut_line": summary(latencies[:, 2] - latencies[:, 1]),
            "cut_line_to_off": summary(latencies[:, 0] - latencies[:, 2]),
            "kill_to_below_50_v_s": [float(t) for t in measured["kills"]],
            "kills_within_bound": int(sum(t <= bound for t in measured["kills"])),
            "runs_interrupted_by_a_fault": measured["interrupted"]}
    with open(os.path.join(FIGURES, "hv_loop.json"), "w") as stream:
        json.dump(result, stream, indent=2)
    plot(conditions, data, bound)
    print(json.dumps(result, indent=2))
    return 0


def plot(conditions: list[Condition], data: dict, bound: float) -> None:
    fig, (ax_loop, ax_arc, ax_kill) = plt.subplots(1, 3, figsize=(16, 4.6))
    for k, condition in enumerate(conditions):
        measured = data[condition.name]
        period_ms = 1e3 / condition.rate_hz
        ax_loop.hist(measured["intervals"] / (period_ms / 1e3), bins=np.linspace(0.0, 3.0, 121), histtype="step",
                     color=f"C{k}", label=condition.name)
        ordered = np.sort(measured["latencies"][:, 0]) * 1e3
        ax_arc.step(ordered, np.arange(1, ordered.size + 1) / ordered.size, where="post", color=f"C{k}",
                    label=f"{condition.name}: p99 {np.percentile(ordered, 99):.1f} ms")
        ax_kill.plot([k] * measured["kills"].size, measured["kills"], "o", color=f"C{k}")
    ax_loop.set(xlabel="cycle interval at the device / loop period", ylabel="cycles", yscale="log",
                title="control loop cycle intervals")
    ax_loop.legend(fontsize=7)
    for target, style in ((10.0, "--"), (20.0, ":")):
        ax_arc.axvline(target, color="k", ls=style, lw=1, label=f"{target:g} ms goal")
    ax_arc.set(xlabel="fault to output off [ms]", ylabel="fraction of arcs", xscale="log",
               title="fault -> emergency off")
    ax_arc.legend(fontsize=7, loc="lower right")
    ax_kill.axhline(bound, color="k", ls="--", lw=1, label=f"heartbeat timeout + ramp time ({bound:.2f} s)")
    ax_kill.set(xticks=range(len(conditions)), xticklabels=[c.name.replace(", ", "\n") for c in conditions],
                ylabel="s", title="SIGKILL of the node at 2.4 kV -> below 50 V", ylim=(0, bound * 1.2))
    ax_kill.tick_params(axis="x", labelsize=7)
    ax_kill.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(FIGURES, "hv_loop.png"), dpi=120)


if __name__ == "__main__":
    sys.exit(main())
