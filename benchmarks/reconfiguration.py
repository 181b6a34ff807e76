"""Reconfiguration plans and multi-object finger design, timed against the two goals of the plan.

1. Pareto fronts (block swaps against the objective) of the gripper's front finger pair (4 blocks, top 2
   stiff; as built: config/assemblies/gripper.yaml, IDs 57 57 1 11) for each sample object, from a shelf
   of SHELF_COUNTS[k] blocks of every design (2: the fingers compete for blocks; 8: they do not): 0-8
   swaps, median time per plan, budgets certified. Goal: every budget certified in <= 5 s.
2. The front pair designed for two objects at once (weights 1 and 1, shelf of 8 per design), for 2-4
   blocks: median time to the certified optimum (capped; then the proven bound). Goal: <= 2 s.
3. A trunk: the first 4 blocks of config/assemblies/trunk.yaml (57 57 57 57) rebuilt to follow the path of
   the trunk's soft part (36 36 15 15, one turned by 30 degrees), from a small shelf: its Pareto front.

The first plan of each kind in the process loads the prepared lookahead fields and compiled kernels; one
warm-up plan runs before the timed ones. Writes docs/figures/reconfiguration.{json,png}.

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
import numpy as np  # noqa: E402

from planner.assembly import Assembly, Chain, PlacedBlock, load_assembly  # noqa: E402
from planner.contours import load_catalog_object  # noqa: E402
from planner.kinematics import chain_blocks, chain_shape  # noqa: E402
from planner.reconfigure import FingerSlot, TargetObject, plan_reconfiguration  # noqa: E402
from planner.reconfigure_path import plan_path_reconfiguration  # noqa: E402
from planner.table import load_table  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
FIGURES = ROOT / "docs" / "figures"
OBJECTS = ("strawberry", "gingerbread", "asymmetric")
PAIRS = (("strawberry", "gingerbread"), ("strawberry", "asymmetric"))
FRONT = (FingerSlot("front_left", "left", 2), FingerSlot("front_right", "right", 2))
SHELF_COUNTS = (2, 8)
FRONT_GOAL_S, MULTI_GOAL_S = 5.0, 2.0
TRUNK_SHELF = {15: 2, 36: 2, 22: 1, 40: 1}


def timed(repeats: int, plan):
    runs = []
    for _ in range(repeats):
        started = time.perf_counter()
        result = plan()
        runs.append((time.perf_counter() - started, result))
    return [t for t, _ in runs], runs[-1][1]


def points_json(result) -> list[dict]:
    return [{"max_swaps": p.max_swaps, "swaps": p.swaps, "objective_m": p.objective, "lower_bound_m": p.lower_bound,
             "optimal": p.optimal} for p in result.points]


def fronts(robot, shelves: dict, repeats: int, cap: float) -> dict:
    out = {}
    for count, shelf in shelves.items():
        for name in OBJECTS:
            target = [TargetObject(name, load_catalog_object(name))]
            times, result = timed(repeats, lambda: plan_reconfiguration(robot, shelf, target, slots=FRONT,
                                                                       time_budget=cap))
            certified = sum(p.optimal for p in result.points)
            key = f"{name}, shelf {count}"
            out[key] = {"time_s": times, "median_time_s": statistics.median(times), "status": result.status.name,
                        "certified_budgets": certified, "budgets": len(result.points),
                        "goal_met": certified == len(result.points) and statistics.median(times) <= FRONT_GOAL_S,
                        "points": points_json(result)}
            print(f"{key}: {statistics.median(times):.2f} s (median of {repeats}), {certified}/{len(result.points)} "
                  "certified, " + ", ".join(f"{p.swaps}:{p.objective:.3f}" for p in result.pareto), flush=True)
    return out


def pair_robot(blocks: int) -> Assembly:
    ids = (57, 57, 1, 11)[:blocks] if blocks > 2 else (57, 57)
    return Assembly("front", tuple(Chain(name, "front", tuple(PlacedBlock(i) for i in ids))
                                   for name in ("front_left", "front_right")))


def multi_object(shelf, repeats: int, cap: float) -> dict:
    out = {}
    for pair in PAIRS:
        objects = [TargetObject(name, load_catalog_object(name)) for name in pair]
        for blocks in (2, 3, 4):
            slots = tuple(FingerSlot(s.chain, s.side, min(s.num_stiff_top, blocks)) for s in FRONT)
            times, result = timed(repeats, lambda: plan_reconfiguration(pair_robot(blocks), shelf, objects,
                                                                       slots=slots, time_budget=cap))
            best = result.points[-1]
            key = f"{'+'.join(pair)} {blocks} blocks"
            out[key] = {"time_s": times, "median_time_s": statistics.median(times), "optimal": best.optimal,
                        "objective_m": best.objective, "lower_bound_m": best.lower_bound,
                        "status": result.status.name, "goal_met": best.optimal and statistics.median(times)
                        <= MULTI_GOAL_S, "object_costs_m": {f.chain: list(f.object_costs) for f in best.fingers},
                        "design_ids": {f.chain: list(f.design_ids) for f in best.fingers}}
            print(f"{key}: {statistics.median(times):.2f} s, {'certified' if best.optimal else 'bound'} "
                  f"{best.objective:.4f} m (bound {best.lower_bound:.4f})", flush=True)
    return out


def trunk(table, repeats: int, cap: float) -> dict:
    built = load_assembly(ROOT / "config" / "assemblies" / "trunk.yaml")
    chain = built.chain("trunk")
    soft = Chain("soft", "trunk", chain.blocks[4:8])
    theta, length, phi, _ = chain_blocks(soft, table)
    points = chain_shape(theta, length, phi).points
    path = np.vstack([points[:-1:3], points[-1:]])
    robot = Assembly("trunk", (Chain("trunk", "trunk", chain.blocks[:4]),))
    times, result = timed(repeats, lambda: plan_path_reconfiguration(robot, "trunk", TRUNK_SHELF, path, table=table,
                                                                    time_budget=cap))
    print(f"trunk: {statistics.median(times):.2f} s, {sum(p.optimal for p in result.points)}/{len(result.points)} "
          "certified, " + ", ".join(f"{p.swaps}:{p.objective:.4f}" for p in result.pareto), flush=True)
    return {"built": list(robot.chain("trunk").design_ids), "path_of": [b.design_id for b in soft.blocks],
            "shelf": TRUNK_SHELF, "time_s": times, "median_time_s": statistics.median(times),
            "status": result.status.name, "points": points_json(result)}


def figure(front_results: dict, multi: dict, trunk_result: dict) -> None:
    fig, (left, middle, right) = plt.subplots(1, 3, figsize=(16, 4.5), gridspec_kw={"width_ratios": [1.3, 1.2, 0.8]})
    for name, data in front_results.items():
        points = data["points"]
        line, = left.step([p["max_swaps"] for p in points], [p["objective_m"] for p in points], where="post",
                          label=f"{name} ({data['median_time_s']:.1f} s, "
                                f"{data['certified_budgets']}/{data['budgets']} certified)")
        left.step([p["max_swaps"] for p in points], [p["lower_bound_m"] for p in points], ":", where="post", lw=0.8,
                  color=line.get_color())
    left.set(xlabel="block swaps allowed", ylabel="objective, both fingers [m]",
             title="front pair from the built gripper (dotted: proven bound)")
    left.legend(fontsize=7)
    labels = [f"pair: {k}" for k in front_results] + [f"2 objects: {k}" for k in multi]
    times = [d["median_time_s"] for d in front_results.values()] + [d["median_time_s"] for d in multi.values()]
    certified = ([d["certified_budgets"] == d["budgets"] for d in front_results.values()]
                 + [d["optimal"] for d in multi.values()])
    goals = [FRONT_GOAL_S] * len(front_results) + [MULTI_GOAL_S] * len(multi)
    rows = np.arange(len(labels))
    middle.barh(rows, times, color=["tab:green" if c else "tab:red" for c in certified])
    middle.scatter(goals, rows, marker="|", s=200, color="k", label="goal")
    middle.set_yticks(rows, labels, fontsize=7)
    middle.invert_yaxis()
    middle.set(xlabel="median time per plan [s] (green: certified, red: stopped with a bound)",
               title="time per plan against the goals")
    middle.legend(fontsize=7)
    points = trunk_result["points"]
    right.step([p["max_swaps"] for p in points], [p["objective_m"] for p in points], where="post", label="objective")
    right.step([p["max_swaps"] for p in points], [p["lower_bound_m"] for p in points], "k:", where="post", lw=0.8,
               label="bound")
    right.set(xlabel="block swaps allowed", ylabel="path objective (eq. 1) [m]",
              title=f"trunk along a path ({trunk_result['median_time_s']:.1f} s)")
    right.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(FIGURES / "reconfiguration.png", dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cap", type=float, default=30.0, help="time budget per plan [s]")
    args = parser.parse_args()
    table = load_table()
    shelves = {count: {int(i): count for i in table.ids} for count in SHELF_COUNTS}
    robot = load_assembly(ROOT / "config" / "assemblies" / "gripper.yaml")
    started_load = os.getloadavg()[0]
    plan_reconfiguration(robot, shelves[8], [TargetObject("s", load_catalog_object("strawberry"))], slots=FRONT)
    front_results = fronts(robot, shelves, args.repeats, args.cap)
    multi = multi_object(shelves[SHELF_COUNTS[-1]], args.repeats, args.cap)
    trunk_result = trunk(table, args.repeats, args.cap)
    summary = {"shelf_blocks_per_design": SHELF_COUNTS, "multi_object_shelf": SHELF_COUNTS[-1], "cap_s": args.cap,
               "repeats": args.repeats, "load_average_1min": [started_load, os.getloadavg()[0]],
               "cpu_count": os.cpu_count(), "goals_s": {"pareto_front_4_block_pair": FRONT_GOAL_S,
                                                        "two_object_design": MULTI_GOAL_S},
               "pareto_fronts": front_results, "multi_object": multi, "trunk": trunk_result}
    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "reconfiguration.json").write_text(json.dumps(summary, indent=1))
    figure(front_results, multi, trunk_result)
    met = sum(d["goal_met"] for d in front_results.values()), sum(d["goal_met"] for d in multi.values())
    print(f"goal met: Pareto fronts {met[0]}/{len(front_results)}, two objects {met[1]}/{len(multi)}")
    print(f"wrote {FIGURES / 'reconfiguration.json'} and .png")


if __name__ == "__main__":
    main()
