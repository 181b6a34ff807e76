"""`python -m planner ogden-fit DATA.csv`: fit Ogden constants to uniaxial + pure-shear tests."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def register(subparsers) -> None:
    parser = subparsers.add_parser("ogden-fit", help="fit N-term Ogden constants to uniaxial + pure-shear test data")
    parser.add_argument("data", type=Path, help="CSV with columns mode, stretch, nominal_stress_Pa")
    parser.add_argument("--terms", type=int, default=3, help="Ogden terms N (default: %(default)s)")
    parser.add_argument("--method", choices=("pso", "least_squares"), default="least_squares")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    parser.set_defaults(handler=run)


def run(args) -> int:
    from planner.ogden_fit import fit_ogden, load_test_data

    result = fit_ogden(load_test_data(args.data), args.terms, args.method, rng=np.random.default_rng(args.seed))
    print(json.dumps({
        "method": result.method,
        "mu_Pa": result.mu.tolist(),
        "alpha": result.alpha.tolist(),
        "cost": result.cost,
        "evaluations": result.n_evaluations,
        "elapsed_s": round(result.elapsed, 4),
        "message": result.message,
    }, indent=2))
    return 0 if result.success else 1
