"""3D path design: recover the paper's 17-block elephant trunk (config/assemblies/trunk.yaml) from its own
centerline with the widening beam ("exact") and PSO; cost versus wall time. Writes
docs/figures/path_optimizers.{json,png}.

    scripts/with_env.sh python benchmarks/path_optimizers.py          # ~3 min
    scripts/with_env.sh python benchmarks/path_optimizers.py --full   # wider beams, 10 PSO seeds
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

from planner import design  # noqa: E402
from planner.assembly import load_assembly  # noqa: E402
from planner.kinematics import chain_blocks, chain_shape  # noqa: E402
from planner.table import load_table  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
FIGURES = ROOT / "docs" / "figures"


def trunk_path(table, blocks: int) -> tuple[np.ndarray, tuple]:
    chain = load_assembly(ROOT / "config" / "assemblies" / "trunk.yaml").chain("trunk")
    theta, length, phi, _ = chain_blocks(chain, table)
    points = chain_shape(theta[:blocks], length[:blocks], phi[:blocks]).points
    return np.vstack([points[:-1:3], points[-1:]]), chain.design_ids[:blocks]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true")
    args = parser.parse_args()
    table = load_table()
    widths = (8, 64, 256) if args.full else (8, 64)
    seeds = range(10) if args.full else range(3)
    runs = []
    for blocks in (8, 17):
        path, truth = trunk_path(table, blocks)
        for label, kwargs in [(f"exact w={w}", {"method": "exact", "options": {"max_width": w}}) for w in widths] + [
            (f"pso seed {s}", {"method": "pso", "seed": s}) for s in seeds
        ]:
            trace = []
            result = design.design_path(path, blocks, table=table,
                                        callback=lambda p: trace.append((p.elapsed, p.best_cost)), **kwargs)
            runs.append({"blocks": blocks, "label": label, "cost": result.cost, "solve_time": result.solve_time,
                         "recovered": result.design_ids == truth, "optimal": result.optimal,
                         "design_ids": list(result.design_ids), "rotation_steps": list(result.rotation_steps),
                         "trace": trace})
            print(f"{blocks} blocks {label}: cost {result.cost:.4g} m in {result.solve_time:.1f} s, "
                  f"recovered {result.design_ids == truth}", file=sys.stderr)
    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "path_optimizers.json").write_text(json.dumps({"runs": runs}, indent=1))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, blocks in zip(axes, (8, 17)):
        for run in (r for r in runs if r["blocks"] == blocks):
            trace = np.array(run["trace"])
            style = "-" if run["label"].startswith("exact") else ":"
            ax.step(trace[:, 0], np.maximum(trace[:, 1], 1e-9), style, where="post", label=run["label"])
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel("best cost so far [m]")
        ax.set_title(f"trunk path, first {blocks} blocks, 12 rotations per block")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(FIGURES / "path_optimizers.png", dpi=110)


if __name__ == "__main__":
    main()
