"""Kinematics throughput: block transforms per second, vectorised vs a per-block Python loop.

A "block transform" is one block's end frame composed onto its chain. Chains of BLOCKS blocks with
random angles and snap-fit rotations, over batch sizes; each point is the median of REPEATS runs, in
wall-clock time and in CPU time of this process (the machine is shared: CPU time shows the work done,
wall-clock time what a caller waits). Writes docs/figures/kinematics_throughput.json and .png.
    scripts/with_env.sh python benchmarks/kinematics_throughput.py [--quick]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from planner.kinematics import CAP_LENGTH, chain_frames, chain_shape, planar_chain  # noqa: E402

BLOCKS = 8
FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"


def naive_chain_frames(theta, length, phi) -> list[np.ndarray]:
    """Reference: one 4x4 homogeneous transform per block, built and multiplied in a Python loop."""
    frame = np.eye(4)
    frames = [frame]
    for bend, rod, turn in zip(theta, length, phi):
        c_t, s_t, c_p, s_p = math.cos(bend), math.sin(bend), math.cos(turn), math.sin(turn)
        radius_x = rod * (1 - c_t) / bend if bend else 0.0
        radius_z = rod * s_t / bend if bend else rod
        x, z = radius_x + CAP_LENGTH * s_t, CAP_LENGTH + radius_z + CAP_LENGTH * c_t
        local = np.array(
            [
                [c_p * c_t, -s_p, c_p * s_t, c_p * x],
                [s_p * c_t, c_p, s_p * s_t, s_p * x],
                [-s_t, 0.0, c_t, z],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
        frame = frame @ local
        frames.append(frame)
    return frames


def naive_batch(theta, length, phi):
    return [naive_chain_frames(t, l, p) for t, l, p in zip(theta, length, phi)]


METHODS = {
    # name: (function of (theta, length, phi, half_turns), largest batch, label)
    "naive_loop": (lambda t, l, p, h: naive_batch(t, l, p), 10_000, "per-block Python loop (4x4 frames)"),
    "chain_frames": (lambda t, l, p, h: chain_frames(t, l, p), 200_000, "chain_frames (3D frames)"),
    "chain_shape": (lambda t, l, p, h: chain_shape(t, l, p), 100_000, "chain_shape (3D, 10 samples/block)"),
    "planar_chain": (lambda t, l, p, h: planar_chain(t, l, h), 100_000, "planar_chain (2D, 10 samples/block)"),
}


def measure(function, batch: int, repeats: int, rng) -> tuple[float, float]:
    theta = rng.uniform(0.0, 0.8, (batch, BLOCKS))
    length = rng.choice([10e-3, 12.5e-3, 15e-3], (batch, BLOCKS))
    phi = rng.integers(0, 12, (batch, BLOCKS)) * (math.pi / 6)
    half_turns = rng.integers(0, 2, (batch, BLOCKS)) * math.pi
    wall, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        function(theta, length, phi, half_turns)
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return statistics.median(wall), statistics.median(cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--quick", action="store_true", help="small batches only (a smoke run)")
    args = parser.parse_args()
    batches = [1, 10, 100, 1_000, 10_000, 100_000, 200_000]
    if args.quick:
        batches = batches[:4]
    rng = np.random.default_rng(0)
    load_before = os.getloadavg()
    results = {}
    started = time.perf_counter()
    for name, (function, largest, _) in METHODS.items():
        rows = []
        for batch in (b for b in batches if b <= largest):
            seconds, cpu_seconds = measure(function, batch, args.repeats, rng)
            rate = batch * BLOCKS / seconds
            cpu_rate = batch * BLOCKS / max(cpu_seconds, 1e-9)
            rows.append({"batch": batch, "median_s": seconds, "median_cpu_s": cpu_seconds,
                         "block_transforms_per_s": rate, "block_transforms_per_cpu_s": cpu_rate})
            print(f"[{time.perf_counter() - started:6.1f} s] {name:13s} batch {batch:7d}: "
                  f"{rate:10.3e} block transforms/s ({cpu_rate:10.3e} per CPU-s)")
        results[name] = rows
    best = {name: max(r["block_transforms_per_s"] for r in rows) for name, rows in results.items()}
    best_cpu = {name: max(r["block_transforms_per_cpu_s"] for r in rows) for name, rows in results.items()}
    report = {
        "blocks_per_chain": BLOCKS,
        "repeats": args.repeats,
        "statistic": "median of repeats",
        "cpu_count": os.cpu_count(),
        "load_average_1min_before": load_before[0],
        "load_average_1min_after": os.getloadavg()[0],
        "numpy": np.__version__,
        "python": platform.python_version(),
        "results": results,
        "best_block_transforms_per_s": best,
        "best_block_transforms_per_cpu_s": best_cpu,
        "speedup_chain_frames_vs_naive": best["chain_frames"] / best["naive_loop"],
    }
    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "kinematics_throughput.json").write_text(json.dumps(report, indent=1))

    figure, axes = plt.subplots(figsize=(6.4, 4.2))
    for k, (name, (_, _, label)) in enumerate(METHODS.items()):
        rows, colour = results[name], f"C{k}"
        batch = [r["batch"] for r in rows]
        axes.loglog(batch, [r["block_transforms_per_s"] for r in rows], "o-", color=colour, label=label)
        axes.loglog(batch, [r["block_transforms_per_cpu_s"] for r in rows], ":", color=colour)
    axes.axhline(1e6, color="grey", linestyle="--", linewidth=1, label="target 1e6 / s")
    axes.plot([], [], "k:", label="same, per CPU-second")
    axes.set(xlabel="chains per call (batch), 8 blocks each", ylabel="block transforms / s (median, wall clock)",
             title=f"Kinematics throughput ({os.cpu_count()} cores, load {load_before[0]:.1f})")
    axes.grid(True, which="both", alpha=0.3)
    axes.legend(fontsize="small")
    figure.tight_layout()
    figure.savefig(FIGURES / "kinematics_throughput.png", dpi=110)
    print(f"wrote {FIGURES / 'kinematics_throughput.json'} and .png; best: "
          + ", ".join(f"{n} {v:.2e}/s" for n, v in best.items()))


if __name__ == "__main__":
    main()
