"""`python -m planner calibrate`: refit the block model's constants to the paper's points."""
from __future__ import annotations

import math


def register(subparsers) -> None:
    parser = subparsers.add_parser("calibrate", help="fit film thickness and NiTi modulus to the paper")
    parser.set_defaults(handler=run)


def run(args) -> int:
    from planner.model_calibration import calibrate

    result = calibrate()
    c, m, p = result.constants, result.mass, result.predictions
    print(f"{result.message} (success={result.success})")
    print(f"ModelConstants(film_thickness={c.film_thickness:.4e}, rod_modulus={c.rod_modulus:.4e})"
          f"  # {c.mechanics.label}")
    print(f"MassConstants(fixed={m.fixed:.4e}, per_length={m.per_length:.4e})")
    print(f"ID 15: theta0 {math.degrees(p['id15_theta0']):.2f} deg (paper 32.15), "
          f"stroke at 2.4 kV {math.degrees(p['id15_stroke']):.2f} deg (paper 5.29)")
    pairs = ", ".join(f"{math.degrees(a):.1f}/{math.degrees(b):.1f}" for a, b in p["similar_pairs"])
    print(f"IDs 5-7 / 40-42 theta0 [deg]: {pairs}")
    low, high = (math.degrees(v) for v in p["range"])
    print(f"theta0 range IDs 64..21: {low:.1f}..{high:.1f} deg (paper ~3..40)")
    return 0 if result.success else 1
