"""Ogden fitting: particle swarm (as in the paper) vs multi-start least squares on the same data.

Test data are synthesised from the paper's 3-term ELASTOSIL constants with 1 % noise (one data
set per seed); each method fits a 3-term model. Quoted: median wall time, objective evaluations
and the largest relative stress error against the true curves over the tested stretch range.
Writes docs/figures/ogden_fit.{json,png}.

    scripts/with_env.sh python benchmarks/ogden_fit.py [--seeds 5]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from planner.materials import ELASTOSIL_2030 as PAPER  # noqa: E402
from planner.ogden import pure_shear_nominal_stress, uniaxial_nominal_stress  # noqa: E402
from planner.ogden_fit import fit_ogden, synthesize_test_data  # noqa: E402

FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
METHODS = {"pso": "particle swarm", "least_squares": "multi-start least squares"}


def max_relative_error(fit, data) -> float:
    errors = []
    for mode, stretch, truth in (
        ("uniaxial", data.uniaxial_stretch, uniaxial_nominal_stress),
        ("pure_shear", data.shear_stretch, pure_shear_nominal_stress),
    ):
        dense = np.linspace(stretch.min(), stretch.max(), 400)
        errors.append(np.max(np.abs(fit.stress(mode, dense) / truth(PAPER.mu, PAPER.alpha, dense) - 1.0)))
    return float(max(errors))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5, help="synthetic data sets (median quoted)")
    args = parser.parse_args()

    runs = {method: [] for method in METHODS}
    first = {}
    for seed in range(args.seeds):
        data = synthesize_test_data(PAPER.mu, PAPER.alpha, np.random.default_rng(seed))
        for method in METHODS:
            fit = fit_ogden(data, 3, method, rng=np.random.default_rng(100 + seed))
            runs[method].append({"seed": seed, "elapsed_s": fit.elapsed, "evaluations": fit.n_evaluations,
                                 "cost": fit.cost, "max_relative_error": max_relative_error(fit, data),
                                 "mu_Pa": fit.mu.tolist(), "alpha": fit.alpha.tolist()})
            first.setdefault(method, (fit, data))
            print(f"seed {seed} {method:13s} {fit.elapsed:.3f} s, {fit.n_evaluations} evaluations, "
                  f"max stress error {100 * runs[method][-1]['max_relative_error']:.2f} %", flush=True)

    summary = {
        method: {
            "median_elapsed_s": statistics.median(r["elapsed_s"] for r in rows),
            "median_evaluations": statistics.median(r["evaluations"] for r in rows),
            "worst_max_relative_error": max(r["max_relative_error"] for r in rows),
            "runs": rows,
        }
        for method, rows in runs.items()
    }
    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "ogden_fit.json").write_text(json.dumps(
        {"true_mu_Pa": list(PAPER.mu), "true_alpha": list(PAPER.alpha), "noise": 0.01, "terms": 3,
         "methods": summary}, indent=2) + "\n")

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    data = first["pso"][1]
    for ax, mode, stretch, stress, title in (
        (axes[0], "uniaxial", data.uniaxial_stretch, data.uniaxial_stress, "uniaxial (eq 5)"),
        (axes[1], "pure_shear", data.shear_stretch, data.shear_stress, "pure shear (eq 7)"),
    ):
        dense = np.linspace(stretch.min(), stretch.max(), 200)
        ax.plot(stretch, stress / 1e6, "k.", label="synthetic test data (paper constants + 1 % noise)")
        for method, style in (("pso", "-"), ("least_squares", "--")):
            fit = first[method][0]
            s = summary[method]
            ax.plot(dense, fit.stress(mode, dense) / 1e6, style,
                    label=f"{METHODS[method]}: {s['median_elapsed_s']:.2f} s, "
                          f"max err {100 * s['worst_max_relative_error']:.2f} %")
        ax.set_title(title)
        ax.set_xlabel("stretch [-]")
        ax.set_ylabel("nominal stress [MPa]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"3-term Ogden fit to ELASTOSIL test curves (median of {args.seeds} data sets)", fontsize=10)
    fig.tight_layout()
    fig.savefig(FIGURES / "ogden_fit.png", dpi=120)
    print(f"wrote {FIGURES / 'ogden_fit.json'} and .png")


if __name__ == "__main__":
    main()
