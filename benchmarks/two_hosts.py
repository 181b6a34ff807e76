"""The stack on two emulated hosts (netlab): grasp time against added link delay, and how fast a partition at
2.4 kV brings every channel below 50 V.

The HV driver (simulated supply) runs in the namespace "rig"; assembly state, planner, simulated arm and
sequencer in "workstation"; a user-space link emulator joins them (the kernel's netem is not available here,
see netlab). Root only.

1. Grasp time: the six-step finger grasp (config/sequences/finger_grasp.yaml, 12 steps) run ``--runs`` times
   under each link condition; the time is the sum of the step durations the sequencer reports.
2. Partition: the grasp started, the link cut once the back fingers are above 2.35 kV; the time from the cut
   to the rig's hv/state showing the HEARTBEAT fault latched, and every channel (measured and set point) below
   50 V, against the bound
   heartbeat timeout + ramp time; the time until the sequencer on the workstation logs "HV driver lost",
   and until its goal ends (after its safe stop's bounded waits). Then the link is healed and the latched
   fault reset for the next run.

The rig's processes run at a higher priority and the sequencer with wider timeouts (netlab/stack.py says why).

Writes docs/figures/two_hosts.json and .png; node output in a temporary directory (printed).
    sudo scripts/with_env.sh python benchmarks/two_hosts.py [--runs 3] [--partitions 5]
"""
import argparse
import json
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import yaml  # noqa: E402

from hv_driver.ramp import MIN_JERK_PEAK_RATE  # noqa: E402
from netlab import Conditions, EmulatedHosts, unavailable_reason  # noqa: E402
from netlab.stack import (RIG_NICENESS, SEQUENCER_PARAMETERS, TwoHostStack, channels_below,  # noqa: E402
                          driver_lost_logged, step_durations)

FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
CONFIG = Path(__file__).resolve().parent.parent / "config"
STARTUP_TIMEOUT = 120.0  # [s] three launchers and five nodes on two loaded cores
GRASP_TIMEOUT = 240.0    # [s]
SAFE_V, HIGH_V = 50.0, 2350.0
CONDITIONS = {  # label: link condition, each direction
    "0 ms": Conditions(),
    "25 ms": Conditions(delay_s=0.025),
    "50 +- 10 ms": Conditions(delay_s=0.05, jitter_s=0.01),
    "50 +- 10 ms, 5 % loss": Conditions(delay_s=0.05, jitter_s=0.01, loss=0.05),
    "100 ms": Conditions(delay_s=0.1),
}


def driver_settings() -> tuple[float, float]:
    """(heartbeat timeout [s], slew rate [V/s]) of config/hv_driver.yaml."""
    params = yaml.safe_load((CONFIG / "hv_driver.yaml").read_text())["hv_driver"]["ros__parameters"]
    return float(params["heartbeat_timeout_s"]), float(params["slew_rate_v_per_s"])


def ready(stack: TwoHostStack) -> None:
    """A perfect link, no latched fault, every channel low: the start of each run."""
    stack.lab.set_conditions(Conditions())
    stack.lab.heal()
    stack.workstation.wait_state(lambda state: True, STARTUP_TIMEOUT, since=time.time())
    reply = stack.workstation.command("reset")
    if not reply["ok"]:
        raise RuntimeError(f"fault reset refused: {reply['message']}")
    stack.rig.wait_state(lambda state: channels_below(state, SAFE_V), STARTUP_TIMEOUT, since=time.time())


def grasp(stack: TwoHostStack, conditions: Conditions, log_name: str) -> dict:
    ready(stack)
    stack.lab.set_conditions(conditions)
    process = stack.start_sequence("finger_grasp", log_name)
    code = process.wait(GRASP_TIMEOUT)
    log = (stack.out / f"{log_name}.log").read_text()
    return {"exit_code": code, "succeeded": code == 0, "grasp_time_s": round(sum(step_durations(log).values()), 2),
            "failure": failure_line(log), "load_average_1min": os.getloadavg()[0]}


def failure_line(log: str) -> str:
    """The line of run_sequence's output that says why the sequence failed ("" if none does)."""
    return next((line for line in log.splitlines() if line.startswith(("step ", "timed out", "no "))), "")


def partition(stack: TwoHostStack, heartbeat_timeout: float, slew_rate: float, log_name: str) -> dict:
    ready(stack)
    process, high = stack.start_grasp_to_peak(HIGH_V, log_name, GRASP_TIMEOUT)
    if high is None:  # the grasp failed before its peak (see its failure): no partition this time
        return {"reached_peak": False, "failure": failure_line((stack.out / f"{log_name}.log").read_text())}
    cut = time.time()
    stack.lab.partition()
    bound = heartbeat_timeout + MIN_JERK_PEAK_RATE * high["channels"]["back"]["setpoint_v"] / slew_rate
    safe = stack.rig.wait_state(lambda s: channels_below(s, SAFE_V), bound + 30.0, cut)
    faulted = stack.rig.wait_state(lambda s: s["channels"]["back"]["faults"], 10.0, cut)
    code = process.wait(GRASP_TIMEOUT)
    ended = time.time() - cut
    logged = driver_lost_logged(stack.logs["sequencer"].read_text(), cut)
    return {"reached_peak": True, "fault_latched_s": round(faulted["stamp"] - cut, 3),
            "below_50_v_s": round(safe["stamp"] - cut, 3), "bound_s": round(bound, 3),
            "load_average_1min": os.getloadavg()[0],
            "sequencer_logged_s": None if logged is None else round(logged - cut, 2),
            "sequencer_ended_s": round(ended, 2), "sequencer_exit_code": code,
            "fault": faulted["channels"]["back"]["fault_text"]}


def plot(result: dict, path: Path) -> None:
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 5.0))
    labels = list(result["grasp"])
    times = [[run["grasp_time_s"] for run in result["grasp"][label] if run["succeeded"]] for label in labels]
    left.boxplot([t or [math.nan] for t in times],
                 tick_labels=[f"{label}\n{len(t)}/{len(result['grasp'][label])} ok" for label, t in zip(labels, times)])
    left.tick_params(axis="x", labelrotation=20)
    left.set_ylabel("grasp time [s] (sum of the 12 steps)")
    left.set_title(f"finger grasp across the link ({result['runs']} runs each)")
    partitions = result["partition"]["runs"]
    right.plot(range(1, len(partitions) + 1), [run["fault_latched_s"] for run in partitions], "x",
               label="cut -> HEARTBEAT fault latched (rig)")
    right.plot(range(1, len(partitions) + 1), [run["below_50_v_s"] for run in partitions], "o",
               label="cut -> every channel < 50 V (rig)")
    right.plot(range(1, len(partitions) + 1), [run["sequencer_logged_s"] for run in partitions], "^",
               label="cut -> sequencer logs 'HV driver lost'")
    right.plot(range(1, len(partitions) + 1), [run["sequencer_ended_s"] for run in partitions], "s",
               label="cut -> sequencer's goal ends (after its safe stop)")
    right.axhline(partitions[0]["bound_s"], color="k", ls="--", label="heartbeat timeout + ramp time")
    right.set_yscale("log")
    right.set_xticks(range(1, len(partitions) + 1))
    right.set_xlabel("run")
    right.set_ylabel("time after the cut [s]")
    right.set_title("partition at 2.4 kV mid-grasp")
    right.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3, help="grasps per link condition")
    parser.add_argument("--partitions", type=int, default=5, help="partition runs")
    parser.add_argument("--out-dir", type=Path, default=FIGURES)
    args = parser.parse_args()
    reason = unavailable_reason()
    if reason:
        print(f"two emulated hosts: {reason}", file=sys.stderr)
        return 2
    heartbeat_timeout, slew_rate = driver_settings()
    work = Path(tempfile.mkdtemp(prefix="two_hosts_"))
    print(f"node output in {work}", flush=True)
    domain = int(os.environ.get("ROS_DOMAIN_ID", "1"))
    result = {"runs": args.runs, "sequencer": SEQUENCER_PARAMETERS, "rig_niceness": RIG_NICENESS,
              "conditions": {label: vars(c) for label, c in CONDITIONS.items()},
              "grasp": {}, "partition": {}}
    with EmulatedHosts(("rig", "workstation")) as lab, TwoHostStack(lab, work, domain) as stack:
        stack.workstation.wait_state(lambda state: True, STARTUP_TIMEOUT)
        for label, conditions in CONDITIONS.items():
            runs = result["grasp"][label] = []
            for run in range(args.runs):
                runs.append(grasp(stack, conditions, f"grasp_{len(result['grasp'])}_{run}"))
                print(f"grasp, {label}, run {run + 1}/{args.runs}: {runs[-1]}", flush=True)
        runs, attempts = [], []
        while len(runs) < args.partitions and len(attempts) < 2 * args.partitions:
            attempts.append(partition(stack, heartbeat_timeout, slew_rate, f"partition_{len(attempts)}"))
            if attempts[-1]["reached_peak"]:
                runs.append(attempts[-1])
            print(f"partition, attempt {len(attempts)} ({len(runs)}/{args.partitions} cut at the peak): "
                  f"{attempts[-1]}", flush=True)
    for label, grasps in result["grasp"].items():
        times = [run["grasp_time_s"] for run in grasps if run["succeeded"]]
        result["grasp"][label] = grasps
        result.setdefault("grasp_summary", {})[label] = {
            "succeeded": f"{len(times)}/{len(grasps)}", "median_s": statistics.median(times) if times else None}
    logged = [r["sequencer_logged_s"] for r in runs if r["sequencer_logged_s"] is not None]
    result["partition"] = {"runs": runs, "attempts_not_at_peak": [a for a in attempts if not a["reached_peak"]],
                           "median_below_50_v_s": statistics.median(r["below_50_v_s"] for r in runs),
                           "max_below_50_v_s": max(r["below_50_v_s"] for r in runs),
                           "within_bound": f"{sum(r['below_50_v_s'] <= r['bound_s'] for r in runs)}/{len(runs)}",
                           "median_fault_latched_s": statistics.median(r["fault_latched_s"] for r in runs),
                           "sequencer_logged": f"{len(logged)}/{len(runs)}",
                           "median_sequencer_logged_s": statistics.median(logged) if logged else None,
                           "median_sequencer_ended_s": statistics.median(r["sequencer_ended_s"] for r in runs),
                           "bound_s": runs[0]["bound_s"]}
    args.out_dir.mkdir(parents=True, exist_ok=True)
    (args.out_dir / "two_hosts.json").write_text(json.dumps(result, indent=2) + "\n")
    plot(result, args.out_dir / "two_hosts.png")
    print(json.dumps({"grasp": result["grasp_summary"],
                      "partition": {k: v for k, v in result["partition"].items() if k != "runs"}}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
