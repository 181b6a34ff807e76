"""CPU per process of the whole stack: `make demo` (the six-step grasp on the simulated backend) run REPEATS
times; every process the demo starts (launcher, nodes, the simulated supply) is sampled from /proc twice a
second until it exits. A process's CPU is its last sample (up to half a second of a process that exits is
not counted). Medians over the runs; the share is CPU over the demo's wall time (1.0 = one core busy).
Writes docs/figures/node_cpu.json and .png.

    scripts/with_env.sh python benchmarks/node_cpu.py [--repeats 3]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from recorder_load import cpu_seconds  # noqa: E402

FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
SAMPLE_PERIOD_S = 0.5


def descendants(pid: int) -> list[int]:
    """Every live process below ``pid`` (from /proc's children lists)."""
    found, todo = [], [pid]
    while todo:
        parent = todo.pop()
        try:
            tasks = os.listdir(f"/proc/{parent}/task")
        except FileNotFoundError:
            continue
        for task in tasks:
            try:
                with open(f"/proc/{parent}/task/{task}/children", encoding="ascii") as children:
                    kids = [int(kid) for kid in children.read().split()]
            except FileNotFoundError:
                continue
            found += kids
            todo += kids
    return found


def process_name(pid: int) -> str | None:
    """The module a Python process runs (``-m softblock_ros.sequencer_node`` -> sequencer_node), else None."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as cmdline:
            argv = cmdline.read().decode(errors="replace").split("\0")
    except FileNotFoundError:
        return None
    if "-m" in argv[:-1]:
        module = argv[argv.index("-m") + 1]
        return module.removeprefix("softblock_ros.").removesuffix("_node")
    return None


def one_run(out: str, domain: int) -> tuple[float, dict[str, float]]:
    """Wall time of one demo and the CPU seconds of each of its processes (the demo's own included)."""
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_DOMAIN_ID": str(domain)}
    start = time.monotonic()
    demo = subprocess.Popen([sys.executable, "-m", "softblock_ros.demo", "--out", out], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    cpu: dict[int, tuple[str, float]] = {}
    while demo.poll() is None:
        for pid in [demo.pid, *descendants(demo.pid)]:
            name = "demo client" if pid == demo.pid else process_name(pid)
            try:
                if name:
                    cpu[pid] = (name, cpu_seconds(pid))
            except FileNotFoundError:  # it exited since it was listed
                pass
        time.sleep(SAMPLE_PERIOD_S)
    wall = time.monotonic() - start
    if demo.returncode != 0:
        raise SystemExit(f"the demo failed (exit {demo.returncode}); run `make demo` to see why")
    per_name: dict[str, float] = defaultdict(float)
    for name, seconds in cpu.values():
        per_name[name] += seconds
    return wall, dict(per_name)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="demo runs (median over them)")
    parser.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0")) or 61,
                        help="ROS domain of the demo's nodes")
    args = parser.parse_args(argv)
    walls, totals, runs = [], [], defaultdict(list)
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(args.repeats):
            wall, cpu = one_run(os.path.join(tmp, f"demo{run}"), args.domain)
            walls.append(wall)
            totals.append(sum(cpu.values()))
            for name, seconds in cpu.items():
                runs[name].append(seconds)
            print(f"[{run + 1}/{args.repeats}] demo {wall:.1f} s, CPU {sum(cpu.values()):.1f} s "
                  f"(most: {max(cpu, key=cpu.get)} {max(cpu.values()):.1f} s)", flush=True)
    wall = statistics.median(walls)
    per_process = {name: {"cpu_s": statistics.median(seconds), "share": statistics.median(seconds) / wall,
                          "runs": len(seconds)}
                   for name, seconds in sorted(runs.items(), key=lambda item: -statistics.median(item[1]))}
    total = statistics.median(totals)
    result = {"what": __doc__.splitlines()[0], "repeats": args.repeats, "demo_wall_s": wall,
              "total_cpu_s": total, "cores": os.cpu_count(), "processes": per_process}
    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "node_cpu.json").write_text(json.dumps(result, indent=2) + "\n")

    names = list(per_process)[::-1]
    figure, axis = plt.subplots(figsize=(7, 0.35 * len(names) + 1.2))
    axis.barh(names, [per_process[name]["cpu_s"] for name in names], color="tab:blue")
    for index, name in enumerate(names):
        axis.text(per_process[name]["cpu_s"], index, f" {100 * per_process[name]['share']:.0f} %", va="center",
                  fontsize=8)
    axis.set_xlabel(f"CPU per demo run [s] (median of {args.repeats}); label: share of one core")
    axis.set_title(f"CPU of each process over one demo ({wall:.0f} s wall, {total:.0f} s CPU in all)")
    figure.tight_layout()
    figure.savefig(FIGURES / "node_cpu.png", dpi=120)
    for name, row in per_process.items():
        print(f"{name:>22}: {row['cpu_s']:5.1f} s CPU ({100 * row['share']:3.0f} % of a core)")
    print(f"{'all':>22}: {total:5.1f} s CPU in {wall:.1f} s; wrote {FIGURES / 'node_cpu.json'} and .png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
