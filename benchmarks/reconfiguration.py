"""Reconfiguration plans and multi-object finger design, timed.

1. Pareto fronts (block swaps against the objective) of the gripper's front finger pair (4 blocks, top 2
   stiff; as built: config/assemblies/gripper.yaml, IDs 57 57 1 11) for each sample object, from a shelf
   of SHELF_COUNTS[k] blocks of every design (2: the stock limit bites; 8: it does not): 0-8 swaps, time
   per plan and how many budgets are certified.
2. The front pair designed for two objects at once (weights 1 and 1), for 2-4 blocks: time to the
   certified optimum (capped at CAP seconds; then the proven bound).

Writes docs/figures/reconfiguration.{json,png}.

    scripts/with_env.sh python benchmarks/reconfiguration.py [--repeats 3] [--cap 30]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from planner.assembly import Assembly, Chain, PlacedBlock, load_assembly  # noqa: E402
from planner.contours import load_catalog_object  # noqa: E402
from planner.reconfigure import FingerSlot, TargetObject, plan_reconfiguration  # noqa: E402
from planner.table import load_table  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
FIGURES = ROOT / "docs" / "figures"
OBJECTS = ("strawberry", "gingerbread", "asymmetric")
PAIRS = (("strawberry", "gingerbread"), ("strawberry", "asymmetric"))
FRONT = (FingerSlot("front_left", "left", 2), FingerSlot("front_right", "right", 2))
SHELF_COUNTS = (2, 8)


def plan(robot, shelf, objects, budget):
    started = time.perf_counter()
    result = plan_reconfiguration(robot, shelf, objects, slots=FRONT, time_budget=budget)
    return time.perf_counter() - started, result


def fronts(shelf, repeats: int, cap: float) -> dict:
    robot = load_assembly(ROOT / "config" / "assemblies" / "gripper.yaml")
    out = {}
    for name in OBJECTS:
        target = [TargetObject(name, load_catalog_object(name))]
        runs = [plan(robot, shelf, target, cap) for _ in range(repeats)]
        times, result = [t for t, _ in runs], runs[-1][1]
        out[name] = {
            "time_s": times, "median_time_s": statistics.median(times), "status": result.status.name,
            "certified_budgets": sum(p.optimal for p in result.points), "budgets": len(result.points),
            "points": [{"max_swaps": p.max_swaps, "swaps": p.swaps, "objective_m": p.objective,
                        "lower_bound_m": p.lower_bound, "optimal": p.optimal,
                        "design_ids": {f.chain: list(f.design_ids) for f in p.fingers}} for p in result.points]}
        print(f"{name}: {statistics.median(times):.2f} s (median of {repeats}), "
              f"{out[name]['certified_budgets']}/{len(result.points)} certified, "
              + ", ".join(f"{p.swaps}:{p.objective:.3f}" for p in result.pareto), flush=True)
    return out


def pair_robot(blocks: int) -> Assembly:
    ids = (57, 57, 1, 11)[:blocks] if blocks > 2 else (57, 57)
    return Assembly("front", tuple(Chain(name, "front", tuple(PlacedBlock(i) for i in ids))
                                   for name in ("front_left", "front_right")))


def multi_object(shelf, cap: float) -> dict:
    out = {}
    for pair in PAIRS:
        objects = [TargetObject(name, load_catalog_object(name)) for name in pair]
        for blocks in (2, 3, 4):
            seconds, result = plan(pair_robot(blocks), shelf, objects, cap)
            best = result.points[-1]
            key = f"{'+'.join(pair)} {blocks} blocks"
            out[key] = {"time_s": seconds, "optimal": best.optimal, "objective_m": best.objective,
                        "lower_bound_m": best.lower_bound, "status": result.status.name,
                        "object_costs_m": {f.chain: list(f.object_costs) for f in best.fingers},
                        "design_ids": {f.chain: list(f.design_ids) for f in best.fingers}}
            print(f"{key}: {seconds:.2f} s, {'certified' if best.optimal else 'bound'} "
                  f"{best.objective:.4f} m (bound {best.lower_bound:.4f})", flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cap", type=float, default=30.0, help="time budget per plan [s]")
    args = parser.parse_args()
    shelves = {count: {int(i): count for i in load_table().ids} for count in SHELF_COUNTS}
    started_load = os.getloadavg()[0]
    front_results = {}
    for count, shelf in shelves.items():
        print(f"shelf of {count} blocks per design", flush=True)
        for name, data in fronts(shelf, args.repeats, args.cap).items():
            front_results[f"{name}, shelf {count}"] = data
    multi = multi_object(shelves[SHELF_COUNTS[-1]], args.cap)
    summary = {"shelf_blocks_per_design": SHELF_COUNTS, "multi_object_shelf": SHELF_COUNTS[-1], "cap_s": args.cap,
               "repeats": args.repeats,
               "load_average_1min": [started_load, os.getloadavg()[0]], "cpu_count": os.cpu_count(),
               "pareto_fronts": front_results, "multi_object": multi}
    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "reconfiguration.json").write_text(json.dumps(summary, indent=1))

    figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    for name, data in front_results.items():
        points = data["points"]
        left.step([p["max_swaps"] for p in points], [p["objective_m"] for p in points], where="post",
                  label=f"{name} ({data['median_time_s']:.1f} s, "
                        f"{data['certified_budgets']}/{data['budgets']} certified)")
        left.plot([p["max_swaps"] for p in points], [p["lower_bound_m"] for p in points], "k:", lw=0.8)
    left.set(xlabel="block swaps allowed", ylabel="objective, both fingers [m]",
             title="front pair from the built gripper (dotted: proven bound)")
    left.legend(fontsize=7)
    labels = list(multi)
    right.barh(labels, [multi[k]["time_s"] for k in labels],
               color=["tab:green" if multi[k]["optimal"] else "tab:red" for k in labels])
    right.axvline(2.0, color="k", ls="--", lw=0.8)
    right.set(xlabel="time [s] (green: certified, red: stopped with a bound)", title="two objects, one finger pair")
    right.tick_params(axis="y", labelsize=7)
    figure.tight_layout()
    figure.savefig(FIGURES / "reconfiguration.png", dpi=120)
    print(f"wrote {FIGURES / 'reconfiguration.json'} and .png")


if __name__ == "__main__":
    main()
