"""Sequencer through the whole stack: gait timing and fault-to-safe-state latency.

Starts the HV driver node (simulated supply on a pty, 6 channels, 16 kV/s), the simulated arm and the
sequencer as processes; this process sends RunSequence goals and records hv/state (100 Hz).
Node output goes to out/sequencer_gait.log.

1. Gait: the `walk_forward` step of config/sequences/legged_gait.yaml (diagonal leg pairs alternating,
   600 V edges at 16 kV/s) at 1..5 Hz. From the measured leg voltages: achieved frequency (slope of
   the rising 375 V crossings against cycle number), edge jitter (residual of that fit) and the phase
   of the second pair (ideal 0.5).
2. Fault: the finger grasp (timings scaled down) with an over-current injected on `front` while the
   arm surrounds the object (back fingers at 2.4 kV). Latency from the injection to the sequencer's
   result (sent after the safe stop), and to every channel measured below 50 V.

Writes docs/figures/sequencer_gait.json and .png.
    scripts/with_env.sh python benchmarks/sequencer_gait.py
"""
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import rclpy  # noqa: E402
import yaml  # noqa: E402
from rclpy.executors import MultiThreadedExecutor  # noqa: E402
from softblock_interfaces.action import RunSequence  # noqa: E402
from softblock_interfaces.msg import HvState, SequenceEvent  # noqa: E402
from softblock_interfaces.srv import InjectFault  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from softblock_ros.client import ActionClient  # noqa: E402
from softblock_ros.launcher import Stack  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FIGURES = ROOT / "docs" / "figures"
SEQUENCES = ROOT / "config" / "sequences"
LOG = ROOT / "out" / "sequencer_gait.log"
CHANNELS = ["front", "back", "leg_front_left", "leg_front_right", "leg_rear_left", "leg_rear_right"]
FREQUENCIES = [1.0, 2.0, 3.0, 4.0, 5.0]  # [Hz]
CYCLES = 8
REPEATS = 3
FAULT_TRIALS = 5
SAFE_VOLTAGE = 50.0  # [V]


def wait(predicate, timeout=60.0, what="condition"):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out waiting for {what}")
        time.sleep(0.005)


PARAMS = {
    "hv_driver": {"channel_names": CHANNELS, "channel_indices": list(range(len(CHANNELS))),
                  "slew_rate_v_per_s": 16_000.0, "publish_rate_hz": 100.0},
    "sim_arm": {"max_speed_m_per_s": 2.0, "max_acceleration_m_per_s2": 20.0},
    "sequencer": {"heartbeat_rate_hz": 10.0},
}


class Bench:
    """The stack's nodes as processes (softblock_ros.launcher), observed and driven from this process."""

    def __init__(self, directory: Path, log):
        self.directory = directory
        params = directory / "params.yaml"
        sequencer = {**PARAMS["sequencer"], "sequences_dir": str(directory)}  # where start() writes the goals' files
        nodes = {**PARAMS, "sequencer": sequencer}
        params.write_text(yaml.safe_dump({node: {"ros__parameters": values} for node, values in nodes.items()}))
        self.stack = Stack(nodes=["hv_driver", "sim_arm", "sequencer"], params=params, output=log).start()
        self.executor = MultiThreadedExecutor(num_threads=4)
        self.client = rclpy.create_node("sequencer_bench")
        self.executor.add_node(self.client)
        threading.Thread(target=self.executor.spin, daemon=True).start()
        self.action = ActionClient(self.client, RunSequence, "sequencer/run")
        self.inject = self.client.create_client(InjectFault, "hv/inject_fault")
        self.reset = self.client.create_client(Trigger, "hv/reset_faults")
        self.samples, self.events = [], []
        self.client.create_subscription(HvState, "hv/state", self.on_state, 100)
        self.client.create_subscription(SequenceEvent, "sequencer/events",
                                        lambda msg: self.events.append((time.monotonic(), msg)), 100)
        assert self.action.wait_for_server(timeout_sec=30.0)

    def close(self) -> None:
        self.executor.shutdown()
        self.stack.stop()

    def on_state(self, msg: HvState) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        self.samples.append((stamp, time.monotonic(), {c.name: c.measured_voltage for c in msg.channels}))

    def call(self, client, request):
        assert client.wait_for_service(timeout_sec=5.0)
        future = client.call_async(request)
        wait(future.done, what=client.srv_name)
        return future.result()

    def start(self, document: dict):
        self.call(self.inject, InjectFault.Request(fault="clear"))
        self.call(self.reset, Trigger.Request())
        path = self.directory / f"{document['name']}.yaml"
        path.write_text(yaml.safe_dump(document))
        self.samples, self.events = [], []
        future = self.action.send_goal_async(RunSequence.Goal(sequence=document["name"]))
        wait(future.done, what="goal response")
        return future.result()

    @staticmethod
    def result(handle):
        future = handle.get_result_async()
        wait(future.done, what="sequence result")
        return future.result().result


def rising_crossings(samples, channel: str, level: float) -> np.ndarray:
    t = np.array([s[0] for s in samples])
    v = np.array([s[2][channel] for s in samples])
    above = v >= level
    index = np.flatnonzero(~above[:-1] & above[1:])
    # Linear interpolation between the two samples around each crossing.
    return t[index] + (level - v[index]) / (v[index + 1] - v[index]) * (t[index + 1] - t[index])


def gait_document(frequency: float) -> dict:
    gait = yaml.safe_load((SEQUENCES / "legged_gait.yaml").read_text())
    walk = gait["steps"][0]
    for branch in walk["parallel"]:
        branch["pulse_train"].update(frequency=frequency, cycles=CYCLES)
    return {"name": f"gait_{frequency:g}hz", "channels": gait["channels"], "defaults": gait["defaults"],
            "steps": [walk]}


def measure_gait(bench: Bench, frequency: float) -> dict:
    result = bench.result(bench.start(gait_document(frequency)))
    if not result.success:
        return {"requested_hz": frequency, "failed": result.message}
    voltage = gait_document(frequency)["steps"][0]["parallel"][0]["pulse_train"]["voltage"]
    a = rising_crossings(bench.samples, "leg_front_left", voltage / 2)
    b = rising_crossings(bench.samples, "leg_front_right", voltage / 2)
    cycles = np.arange(len(a))
    period, offset = np.polyfit(cycles, a, 1)
    residual = a - (offset + period * cycles)
    n = min(len(a), len(b))
    return {"requested_hz": frequency, "achieved_hz": float(1.0 / period), "rises": int(len(a)),
            "jitter_ms": float(np.std(residual) * 1e3), "pair_phase": float(np.median((b[:n] - a[:n]) / period))}


def grasp_document() -> dict:
    grasp = yaml.safe_load((SEQUENCES / "finger_grasp.yaml").read_text())
    grasp["defaults"].update(speed=2.0, slew_rate=15_000.0)
    for step in grasp["steps"]:
        if "move_arm" in step:
            step["move_arm"]["speed"] = 0.05 if step["name"] == "surround_object" else 2.0
    return grasp


def measure_fault(bench: Bench) -> dict:
    handle = bench.start(grasp_document())
    wait(lambda: any(m.step_name == "surround_object" and m.phase == "started" for _, m in bench.events),
         what="surround_object started")
    injected = time.monotonic()
    bench.call(bench.inject, InjectFault.Request(channel="front", fault="over_current"))
    result = bench.result(handle)
    result_at = time.monotonic()
    if result.failed_step != "surround_object" or "over_current" not in result.message:
        return {"failed": result.message}
    def first_safe_sample():
        return next((received for _, received, volts in list(bench.samples)
                     if received > injected and max(map(abs, volts.values())) < SAFE_VOLTAGE), None)

    wait(lambda: first_safe_sample() is not None, what="every channel below 50 V on hv/state")
    safe_at = first_safe_sample()
    return {"result_ms": (result_at - injected) * 1e3, "safe_state_ms": (safe_at - injected) * 1e3}


def main() -> int:
    os.makedirs(FIGURES, exist_ok=True)
    os.makedirs(LOG.parent, exist_ok=True)
    rclpy.init()
    try:
        with tempfile.TemporaryDirectory() as directory, open(LOG, "w") as log:
            bench = Bench(Path(directory), log)
            try:
                gait = []
                for repeat in range(REPEATS):
                    for frequency in FREQUENCIES:
                        gait.append(measure_gait(bench, frequency))
                        print(f"gait {repeat + 1}/{REPEATS} {frequency:g} Hz: {gait[-1]}", flush=True)
                faults = []
                for trial in range(FAULT_TRIALS):
                    faults.append(measure_fault(bench))
                    print(f"fault {trial + 1}/{FAULT_TRIALS}: {faults[-1]}", flush=True)
            finally:
                bench.close()
    finally:
        rclpy.try_shutdown()
    failed_runs = [run for run in gait + faults if "failed" in run]
    gait = [run for run in gait if "failed" not in run]
    faults = [run for run in faults if "failed" not in run]
    summary = {
        "command": "scripts/with_env.sh python benchmarks/sequencer_gait.py",
        "gait_cycles": CYCLES, "repeats": REPEATS,
        "pulse_train": gait_document(1.0)["steps"][0]["parallel"][0]["pulse_train"],
        "gait": gait, "failed_runs": failed_runs,
        "gait_median": {f"{f:g}": {key: float(np.median([g[key] for g in gait if g["requested_hz"] == f]))
                                   for key in ("achieved_hz", "jitter_ms", "pair_phase")}
                        for f in FREQUENCIES if any(g["requested_hz"] == f for g in gait)},
        "fault_trials": faults,
        "fault_median_ms": {key: float(np.median([f[key] for f in faults])) for key in ("result_ms", "safe_state_ms")},
    }
    (FIGURES / "sequencer_gait.json").write_text(json.dumps(summary, indent=2))
    fig, (ax_f, ax_l) = plt.subplots(1, 2, figsize=(10, 4))
    requested = np.array([g["requested_hz"] for g in gait])
    ax_f.plot([0, 5.5], [0, 5.5], color="0.7", lw=1, label="ideal")
    ax_f.plot(requested, [g["achieved_hz"] for g in gait], "o", label=f"achieved ({REPEATS} runs)")
    ax_f.set(xlabel="requested pulse frequency [Hz]", ylabel="achieved [Hz] (hv/state)",
             title="Legged gait through sequencer + HV driver")
    ax_f.legend()
    for k, key in enumerate(("result_ms", "safe_state_ms")):
        values = [f[key] for f in faults]
        ax_l.plot(np.full(len(values), k), values, "o", alpha=0.6)
        ax_l.plot([k - 0.2, k + 0.2], [np.median(values)] * 2, color="k")
    ax_l.set_xticks([0, 1], ["fault -> sequence result", "fault -> all channels < 50 V"])
    ax_l.set(ylabel="latency [ms]", title=f"Over-current, back fingers at 2.4 kV ({FAULT_TRIALS} trials, median bar)")
    fig.tight_layout()
    fig.savefig(FIGURES / "sequencer_gait.png", dpi=120)
    print(json.dumps({key: summary[key] for key in ("gait_median", "fault_median_ms", "failed_runs")}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
