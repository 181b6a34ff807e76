"""Finger design: time to the certified optimum of the exact search, per object and block count, against
brute force (2 and 3 blocks: every design, the objective in numpy, the collision rule from the cheapest up) and
the paper's PSO over seeds (cost ratio to the optimum, collision rate), and the search's block-placement kernel
against a plain numpy implementation of the same work.
Writes docs/figures/finger_optimizers.{json,png}.

    scripts/with_env.sh python benchmarks/finger_optimizers.py          # ~15 min on the 2-core machine
    scripts/with_env.sh python benchmarks/finger_optimizers.py --quick  # 2 and 4 blocks, 5 PSO seeds
    scripts/with_env.sh python benchmarks/finger_optimizers.py --blocks 2,4,5 --seeds 10

Objects: the three samples and three generated asymmetric ones (planner.generated_objects, seeds 11-13).
Fingers as in the paper's front fingers: the top two blocks stiff (both, with 2 blocks).
"""
from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

from planner import design  # noqa: E402
from planner.contours import OBJECTS_CATALOG, extract_contours, load_mask  # noqa: E402
from planner.generated_objects import PIXEL_SIZE, lumpy_object  # noqa: E402
from planner.kinematics import CAP_LENGTH, chain_shape  # noqa: E402
from planner.objectives import shape_error  # noqa: E402
from planner.optimize import design_costs, design_space  # noqa: E402
from planner.optimize import finger_search  # noqa: E402
from planner.optimize.lookahead import block_shapes  # noqa: E402
from planner.table import load_table  # noqa: E402

FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
SAMPLES = ("asymmetric", "strawberry", "gingerbread")
GENERATED_SEEDS = (11, 12, 13)
BUDGET = 30.0  # [s] per finger pair for the exact search
REPEATS = 3  # exact runs per case (median time) when a run takes under 5 s


def objects():
    catalog = yaml.safe_load(OBJECTS_CATALOG.read_text())
    for name in SAMPLES:
        yield name, load_mask(OBJECTS_CATALOG.parent / catalog[name]["file"]), float(catalog[name]["pixel_size_m"])
    for seed in GENERATED_SEEDS:
        yield f"generated {seed}", lumpy_object(seed), PIXEL_SIZE


def exact_runs(mask, pixel, blocks, table):
    runs = []
    for _ in range(REPEATS):
        result = design.design_fingers(mask, pixel, blocks, num_stiff_top=min(2, blocks), table=table,
                                       time_budget=BUDGET)
        runs.append(result)
        if result.solve_time > 5.0:
            break
    best = runs[-1]
    return {
        "times": [r.solve_time for r in runs], "time": float(np.median([r.solve_time for r in runs])),
        "certified": best.optimal, "cost": best.left.cost + best.right.cost,
        "lower_bound": best.left.lower_bound_m + best.right.lower_bound_m,
        "left": list(best.left.design_ids), "right": list(best.right.design_ids),
        "min_clearance": min(best.left.min_clearance_m, best.right.min_clearance_m),
        "placements": best.left.result.nfev + best.right.result.nfev,
    }


def brute_force(mask, pixel, blocks, table, chunk: int = 8000):
    """Every (base, blocks) design of both fingers: the objective without its collision term for all of
    them (numpy, ``chunk`` designs at a time), then the exact collision rule from the cheapest up until one
    is collision-free: that one is the optimum."""
    problems = design.finger_problems(extract_contours(mask, pixel))
    space = design_space(table, blocks, stiff_positions=range(min(2, blocks)))
    combos = np.array(list(itertools.product(*space.choices)))
    total, started = 0.0, time.perf_counter()
    for side in ("left", "right"):
        target = problems[side][0]
        shapes = np.repeat(combos, len(target.bases), axis=0)
        bases = np.tile(np.arange(len(target.bases)), len(combos))
        errors = np.empty(len(shapes))
        for start in range(0, len(shapes), chunk):
            part = slice(start, start + chunk)
            theta, length = space.theta[shapes[part]], space.length[shapes[part]]
            shape = chain_shape(theta, length, 0.0)
            offset = target.bases[bases[part]]
            errors[part] = shape_error(target, shape.points + offset[:, None, :], shape.rotations[:, -1],
                                       shape.positions[:, -1] + offset)
        cheapest_first = np.argsort(errors)
        for start in range(0, len(shapes), chunk):
            order = cheapest_first[start:start + chunk]
            theta, length = space.theta[shapes[order]], space.length[shapes[order]]
            clear = ~target.body.colliding(theta, length, target.bases[bases[order], 0])
            if clear.any():
                total += float(errors[order][np.argmax(clear)])
                break
        else:
            total += np.inf
    return {"cost": total, "time": time.perf_counter() - started,
            "designs": 2 * len(combos) * len(problems["left"][0].bases)}


def pso_runs(mask, pixel, blocks, table, seeds):
    runs = [design.design_fingers(mask, pixel, blocks, num_stiff_top=min(2, blocks), method="pso", seed=seed,
                                  table=table) for seed in seeds]
    return {"costs": [r.left.cost + r.right.cost for r in runs],
            "collisions": [bool(r.left.collision or r.right.collision) for r in runs],
            "median_time": float(np.median([r.solve_time for r in runs]))}


def kernel_throughput(table, repeats: int = 7):
    """Block placements evaluated per second: the search's compiled expansion (contour distances, bounds of
    every next block) against numpy doing the exact contour-distance update and objective sum per
    placement, on the same nodes (asymmetric object, left finger, 4 blocks, after 2 blocks)."""
    catalog = yaml.safe_load(OBJECTS_CATALOG.read_text())["asymmetric"]
    contours = extract_contours(load_mask(OBJECTS_CATALOG.parent / catalog["file"]), float(catalog["pixel_size_m"]))
    target = design.finger_problems(contours)["left"][0]
    space = design_space(table, 4, stiff_positions=range(2))
    shapes = block_shapes(space, CAP_LENGTH)
    rng = np.random.default_rng(0)
    nodes = []
    contour = target.points[:, [0, 2]]
    for _ in range(64):
        pose = np.array([-rng.uniform(0, 0.012), 0.0, 0.0])
        alpha = np.hypot(contour[:, 0] - pose[0], contour[:, 1])
        for s in rng.choice(space.choices[0], 2):
            cos, sin = np.cos(pose[2]), np.sin(pose[2])
            world = pose[:2] + shapes.samples[s] @ np.array([[cos, -sin], [sin, cos]])
            alpha = np.minimum(alpha, np.linalg.norm(contour[:, None] - world[None], axis=-1).min(axis=1))
            end = pose[:2] + shapes.ends[s, :2] @ np.array([[cos, -sin], [sin, cos]])
            pose = np.array([end[0], end[1], pose[2] + shapes.ends[s, 2]])
        nodes.append((pose, alpha))
    options = space.choices[2]

    def numpy_pass():
        for pose, alpha in nodes:
            cos, sin = np.cos(pose[2]), np.sin(pose[2])
            rotation = np.array([[cos, -sin], [sin, cos]])
            world = pose[:2] + shapes.samples[options] @ rotation  # (C, M, 2)
            distance = np.linalg.norm(contour[None, :, None] - world[:, None], axis=-1).min(axis=2)
            np.abs(np.minimum(alpha, distance) - target.offset).sum(axis=1)

    problem = finger_search.search_problem(target, space)
    width = len(options)
    buffers = (np.zeros(width), np.zeros(width, np.int64), np.zeros(width, np.int64), np.zeros((width, 3)))
    path, counts = np.full(5, -1, np.int64), np.zeros(len(space.theta), np.int64)
    acc, limits = np.zeros(width), np.array([np.inf, np.inf])

    def compiled_pass():
        for pose, alpha in nodes:
            finger_search._expand(problem, 2, pose, alpha, np.inf, limits, *buffers, 0, 0, path, counts, acc)

    compiled_pass()
    result = {}
    for name, run in (("numpy", numpy_pass), ("compiled search", compiled_pass)):
        times = []
        for _ in range(repeats):
            started = time.perf_counter()
            run()
            times.append(time.perf_counter() - started)
        result[name] = len(nodes) * width / float(np.median(times))
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 and 4 blocks, 5 PSO seeds")
    parser.add_argument("--blocks", type=lambda text: tuple(int(b) for b in text.split(",")),
                        help="block counts, e.g. 2,4,5 (default 2,3,4,5)")
    parser.add_argument("--seeds", type=int, help="PSO seeds per case (default 20)")
    args = parser.parse_args()
    table = load_table()
    block_counts = args.blocks or ((2, 4) if args.quick else (2, 3, 4, 5))
    seeds = range(args.seeds or (5 if args.quick else 20))
    design.prepare_finger_search(tuple((blocks, min(2, blocks)) for blocks in block_counts), table)
    cases = []
    load = os.getloadavg()[0]
    for name, mask, pixel in objects():
        for blocks in block_counts:
            exact = exact_runs(mask, pixel, blocks, table)
            reference = brute_force(mask, pixel, blocks, table) if blocks <= 3 else None
            pso = pso_runs(mask, pixel, blocks, table, seeds)
            best = min([exact["cost"]] + pso["costs"])
            case = {"object": name, "blocks": blocks, "exact": exact, "brute_force": reference, "pso": pso,
                    "best_known": best,
                    "pso_cost_ratio": [c / best for c in pso["costs"]],
                    "pso_collision_rate": float(np.mean(pso["collisions"])),
                    "pso_worse_than_exact": int(sum(c < exact["cost"] - 1e-9 for c in pso["costs"]))}
            cases.append(case)
            print(f"{name} {blocks} blocks: exact {exact['cost']:.4f} m in {exact['time']:.2f} s "
                  f"({'certified' if exact['certified'] else 'lower bound %.4f' % exact['lower_bound']}); "
                  + (f"brute force {reference['cost']:.4f} m; " if reference else "")
                  + f"PSO median ratio {np.median(case['pso_cost_ratio']):.3f}, collisions "
                  f"{case['pso_collision_rate']:.0%}", file=sys.stderr, flush=True)
    throughput = kernel_throughput(table)
    print(f"placements/s: {throughput}", file=sys.stderr)
    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "finger_optimizers.json").write_text(json.dumps(
        {"cases": cases, "placements_per_second": throughput, "budget_s": BUDGET, "load_average_1min": load,
         "command": " ".join(sys.argv),
         "load_average_1min_end": os.getloadavg()[0], "cpu_count": os.cpu_count()}, indent=1))
    plot(cases, throughput)


def plot(cases, throughput) -> None:
    fig, (time_ax, ratio_ax, kernel_ax) = plt.subplots(1, 3, figsize=(15, 4.8),
                                                        gridspec_kw={"width_ratios": [3, 3, 1]})
    names = list(dict.fromkeys(c["object"] for c in cases))
    for name, colour in zip(names, plt.cm.tab10.colors):
        rows = [c for c in cases if c["object"] == name]
        blocks = [c["blocks"] for c in rows]
        times = [c["exact"]["time"] for c in rows]
        time_ax.plot(blocks, times, "-", color=colour, label=name)
        for c, t in zip(rows, times):
            time_ax.plot(c["blocks"], t, "o" if c["exact"]["certified"] else "x", color=colour, ms=7)
    time_ax.plot([3.8, 4.2], [1.0, 1.0], "g-", lw=2, label="goals: 1 s (4 blocks), 5 s (5 blocks)")
    time_ax.plot([4.8, 5.2], [5.0, 5.0], "g-", lw=2)
    time_ax.axhline(BUDGET, color="r", ls="--", lw=1, label=f"budget {BUDGET:.0f} s (x: not certified)")
    time_ax.set_yscale("log")
    time_ax.set_xlabel("blocks per finger")
    time_ax.set_ylabel("time to certified optimum, finger pair [s]")
    time_ax.set_title("exact search (o certified, x budget ran out)")
    time_ax.legend(fontsize=7)
    labels = [f"{c['object'][:6]} {c['blocks']}" for c in cases]
    ratios = [np.minimum(c["pso_cost_ratio"], 3.0) for c in cases]
    ratio_ax.boxplot(ratios, tick_labels=labels)
    ratio_ax.scatter(range(1, len(cases) + 1), [c["pso_collision_rate"] * 3 for c in cases], marker="s",
                     color="r", s=12, label="PSO collision rate (x 3)")
    ratio_ax.axhline(1.0, color="k", lw=0.8)
    ratio_ax.set_ylabel("PSO cost / best known (capped at 3; collisions at 3)")
    ratio_ax.set_title(f"PSO over {len(cases[0]['pso']['costs'])} seeds (pair)")
    ratio_ax.tick_params(axis="x", labelrotation=60, labelsize=6)
    ratio_ax.legend(fontsize=7)
    kernel_ax.bar(list(throughput), list(throughput.values()), color=["0.6", "tab:blue"])
    kernel_ax.set_yscale("log")
    kernel_ax.set_ylabel("block placements evaluated / s")
    kernel_ax.tick_params(axis="x", labelsize=7)
    fig.tight_layout()
    fig.savefig(FIGURES / "finger_optimizers.png", dpi=110)


if __name__ == "__main__":
    main()
