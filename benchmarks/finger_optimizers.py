"""Finger design: cost versus wall time of the prefix branch and bound ("exact") and the paper's PSO, and
the spread of PSO over 20 seeds. Writes docs/figures/finger_optimizers.{json,png}.

    scripts/with_env.sh python benchmarks/finger_optimizers.py          # ~3 min: 3 objects x 4, 5 blocks
    scripts/with_env.sh python benchmarks/finger_optimizers.py --full   # 4, 5, 6 blocks, 20 seeds everywhere
    scripts/with_env.sh python benchmarks/finger_optimizers.py --certify  # + certified optima, 4 blocks (~10 min)
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

from planner import design  # noqa: E402
from planner.contours import OBJECTS_CATALOG, load_mask  # noqa: E402
from planner.table import load_table  # noqa: E402

FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
OBJECTS = ("asymmetric", "strawberry", "gingerbread")
FAILURE_MARGIN = 0.05  # a run ending more than 5 % above the best known cost failed


def run(mask, pixel, blocks, method, seed, table, options=None, time_budget=None):
    trace = []

    def record(progress):
        trace.append((progress.elapsed, progress.best_cost, progress.fraction))

    result = design.design_fingers(mask, pixel, blocks, num_stiff_top=2, method=method, seed=seed, table=table,
                                   callback=record, options=options, time_budget=time_budget)
    return {
        "method": method, "seed": seed, "blocks": blocks, "solve_time": result.solve_time,
        "cost": result.left.cost + result.right.cost, "left": list(result.left.design_ids),
        "right": list(result.right.design_ids), "collision": result.left.collision or result.right.collision,
        "optimal": result.optimal, "left_trace": [(t, c) for t, c, f in trace if f < 0.5],
        "lower_bound": result.left.result.lower_bound + result.right.result.lower_bound,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="4, 5, 6 blocks and 20 PSO seeds for every case")
    parser.add_argument("--certify", action="store_true", help="also prove the 4-block optima (max_width None)")
    args = parser.parse_args()
    table = load_table()
    catalog = yaml.safe_load(OBJECTS_CATALOG.read_text())
    block_counts = (4, 5, 6) if args.full else (4, 5)
    cases = []
    for name in OBJECTS:
        mask = load_mask(OBJECTS_CATALOG.parent / catalog[name]["file"])
        pixel = float(catalog[name]["pixel_size_m"])
        for blocks in block_counts:
            seeds = range(20) if (args.full or (name == "asymmetric" and blocks == 4)) else range(3)
            runs = [run(mask, pixel, blocks, "exact", 0, table)]
            for seed in seeds:
                runs.append(run(mask, pixel, blocks, "pso", seed, table))
                print(f"\r{name} {blocks} blocks: PSO seed {seed}", end="", file=sys.stderr, flush=True)
            certified = None
            if args.certify and blocks == 4:
                certified = run(mask, pixel, blocks, "exact", 0, table, options={"max_width": None}, time_budget=600)
                print(f"\r{name} {blocks} blocks: certified run {certified['cost']:.4f} m in "
                      f"{certified['solve_time']:.0f} s, optimal {certified['optimal']}", file=sys.stderr)
            best = min(r["cost"] for r in runs + ([certified] if certified else []))
            pso = [r for r in runs if r["method"] == "pso"]
            exact = runs[0]
            case = {
                "object": name, "blocks": blocks, "best_known": best,
                "exact": {k: exact[k] for k in ("cost", "solve_time", "left", "right", "optimal", "lower_bound")},
                "pso_costs": [r["cost"] for r in pso],
                "pso_median_time": float(np.median([r["solve_time"] for r in pso])),
                "pso_failure_rate": float(np.mean([r["cost"] > (1 + FAILURE_MARGIN) * best for r in pso])),
                "pso_collision_rate": float(np.mean([r["collision"] for r in pso])),
                "traces": {"exact": exact["left_trace"], "pso": pso[0]["left_trace"]},
            }
            if certified:
                case["certified"] = {k: certified[k] for k in ("cost", "solve_time", "optimal", "lower_bound", "left",
                                                               "right")}
            cases.append(case)
            print(f"\r{name} {blocks} blocks: exact {exact['cost']:.4f} m in {exact['solve_time']:.1f} s; PSO median "
                  f"{np.median(case['pso_costs']):.4g} m in {case['pso_median_time']:.1f} s, failure rate "
                  f"{case['pso_failure_rate']:.0%} ({len(pso)} seeds)", file=sys.stderr)
    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "finger_optimizers.json").write_text(json.dumps({"cases": cases}, indent=1))
    plot(cases)


def plot(cases) -> None:
    fig, (trace_ax, spread_ax) = plt.subplots(1, 2, figsize=(12, 4.5))
    for case, colour in zip(cases, plt.cm.tab10.colors):
        label = f"{case['object']} {case['blocks']}"
        for method, style in (("exact", "-"), ("pso", ":")):
            trace = np.array([p for p in case["traces"][method] if p[1] < 1e10])
            if len(trace):
                trace_ax.step(trace[:, 0], trace[:, 1], style, where="post", color=colour,
                              label=f"{label} {method}")
    trace_ax.set_xscale("log")
    trace_ax.set_xlabel("wall time [s] (left finger)")
    trace_ax.set_ylabel("best cost so far [m]")
    trace_ax.set_title("cost vs time: exact (solid), PSO seed 0 (dotted)")
    trace_ax.legend(fontsize=6, ncol=2)
    labels = [f"{c['object'][:5]} {c['blocks']}" for c in cases]
    ratios = [np.minimum(np.array(c["pso_costs"]) / c["best_known"], 3.0) for c in cases]
    spread_ax.boxplot(ratios, tick_labels=labels)
    spread_ax.scatter(range(1, len(cases) + 1), [c["exact"]["cost"] / c["best_known"] for c in cases],
                      marker="*", color="k", zorder=3, label="exact")
    proven = [(i + 1, c["certified"]["cost"] / c["best_known"]) for i, c in enumerate(cases)
              if c.get("certified", {}).get("optimal")]
    if proven:
        spread_ax.scatter(*zip(*proven), marker="D", facecolor="none", edgecolor="g", s=60, zorder=4,
                          label="certified optimum")
    spread_ax.axhline(1 + FAILURE_MARGIN, color="r", lw=0.8, ls="--", label="failure threshold (+5 %)")
    spread_ax.set_ylabel("cost / best known (capped at 3; collisions at 3)")
    spread_ax.set_title("PSO over seeds (left + right finger)")
    spread_ax.tick_params(axis="x", labelrotation=45, labelsize=7)
    spread_ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(FIGURES / "finger_optimizers.png", dpi=110)


if __name__ == "__main__":
    main()
