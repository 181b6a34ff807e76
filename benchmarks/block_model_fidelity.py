"""Speed-accuracy ladder of the block model: angle error against the reference vs time per evaluation.

Every fidelity solves all 84 table designs at 0, 1.2 and 2.4 kV; the error is the absolute angle
difference to the reference (chord fibres, 1024 strips). Time per evaluation is the median wall
time of one solve of one design (scalar call) and of all 84 at once (per design). Also times a
full table regeneration. Writes docs/figures/block_model_fidelity.{json,png}.

    scripts/with_env.sh python benchmarks/block_model_fidelity.py [--repeats 7]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from planner.block_model import REFERENCE_FIDELITY, TABLE_FIDELITY, BlockModel, Fidelity  # noqa: E402
from planner.table_builder import build_table, grid_designs  # noqa: E402

FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
VOLTAGES = (0.0, 1200.0, 2400.0)
LADDER = (
    [Fidelity("closed_form")]
    + [Fidelity("arc", n) for n in (4, 8, 16, 32, 64, 128)]
    + [Fidelity("chord", n) for n in (4, 8, 16, 32, 64, 128, 256)]
)


def median_time(function, repeats: int) -> float:
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        samples.append(time.perf_counter() - start)
    return statistics.median(samples)


def angles(model: BlockModel) -> np.ndarray:
    return np.concatenate([model.solve(v).theta for v in VOLTAGES])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="timing repeats per fidelity (median quoted)")
    args = parser.parse_args()

    _, designs = grid_designs()
    reference = angles(BlockModel(designs, REFERENCE_FIDELITY))
    one_design = designs.select([14])  # ID 15
    rows = []
    for k, fidelity in enumerate(LADDER, start=1):
        model = BlockModel(designs, fidelity)
        error = np.degrees(np.abs(angles(model) - reference))
        batch = median_time(lambda: model.solve(2400.0), args.repeats) / designs.size
        scalar_model = BlockModel(one_design, fidelity)
        scalar = median_time(lambda: scalar_model.solve(2400.0), args.repeats)
        rows.append({
            "fidelity": fidelity.label,
            "kind": fidelity.kind,
            "n_strips": None if fidelity.kind == "closed_form" else fidelity.n_strips,
            "max_error_deg": float(np.nanmax(error)),
            "median_error_deg": float(np.nanmedian(error)),
            "time_per_design_batch_s": batch,
            "time_single_design_s": scalar,
        })
        print(f"[{k}/{len(LADDER)}] {fidelity.label:16s} max error {rows[-1]['max_error_deg']:.4f} deg, "
              f"{1e6 * batch:8.1f} us/design (batch of 84), {1e3 * scalar:6.2f} ms single", flush=True)

    table_time = median_time(build_table, max(3, args.repeats // 2))
    print(f"full table regeneration ({TABLE_FIDELITY.label}): median {table_time:.2f} s")
    result = {
        "reference": REFERENCE_FIDELITY.label,
        "table_fidelity": TABLE_FIDELITY.label,
        "voltages_V": list(VOLTAGES),
        "designs": int(designs.size),
        "repeats": args.repeats,
        "table_regeneration_median_s": table_time,
        "ladder": rows,
    }
    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "block_model_fidelity.json").write_text(json.dumps(result, indent=2) + "\n")

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for kind, marker in (("closed_form", "s"), ("arc", "o"), ("chord", "^")):
        chosen = [r for r in rows if r["kind"] == kind]
        x = [1e6 * r["time_per_design_batch_s"] for r in chosen]
        y = [max(r["max_error_deg"], 1e-6) for r in chosen]
        ax.plot(x, y, marker=marker, label={"closed_form": "closed form (small angle)",
                                            "arc": "strips, arc fibres", "chord": "strips, chord fibres"}[kind])
        for r, xi, yi in zip(chosen, x, y):
            if r["n_strips"]:
                ax.annotate(str(r["n_strips"]), (xi, yi), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time per design evaluation, batch of 84 [us] (median)")
    ax.set_ylabel("max |angle error| vs reference [deg]")
    ax.set_title(f"Block model fidelity ladder (reference: {REFERENCE_FIDELITY.label}; 84 designs x 0/1.2/2.4 kV)",
                 fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(FIGURES / "block_model_fidelity.png", dpi=120)
    print(f"wrote {FIGURES / 'block_model_fidelity.json'} and .png")


if __name__ == "__main__":
    main()
