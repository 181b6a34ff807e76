"""The shipped look-up table against the paper: published points, trends and the angle-voltage curves.

Reads config/block_table.csv (regenerate with `python -m planner table`) and writes
docs/figures/block_table.{json,png}: theta_0 over lambda_1 for every (L, D) as in the paper's
Figure 3E, and theta(V) up to each design's safe voltage for the paper's IDs 15, 36 and 57.

    scripts/with_env.sh python benchmarks/block_table_overview.py
"""
from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from planner.block_model import BlockModel, Status  # noqa: E402
from planner.geometry import PRESTRETCH_AXIAL_VALUES, ROD_DIAMETER_VALUES, ROD_LENGTH_VALUES  # noqa: E402
from planner.materials import ELASTOSIL_2030  # noqa: E402
from planner.table import load_table  # noqa: E402
from planner.table_builder import grid_designs  # noqa: E402

FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"


def deg(value) -> float:
    return round(float(np.degrees(value)), 2)


def main() -> None:
    table = load_table()
    row15 = table.design(15)
    at_2400, _ = table.angle_at([15], 2400.0)
    limit = BlockModel(grid_designs()[1]).voltage_limit()
    # The mechanical limit behind breakdown: the same film with an unreachable dielectric strength.
    unbreakable = dataclasses.replace(ELASTOSIL_2030, breakdown_field=1e12)
    mechanical = BlockModel(grid_designs(material=unbreakable)[1]).voltage_limit(v_max=20e3)
    comparison = {
        "id15_theta0_deg": {"model": deg(row15.theta0), "paper_fe": 32.15, "paper_experiment": 30.70},
        "id15_stroke_2400V_deg": {"model": deg(row15.theta0 - at_2400[0]), "paper_fe": 5.29, "paper_experiment": 5.5},
        "four_id15_in_series_deg": {"model": deg(4 * row15.theta0), "paper_model": 130.92, "paper_experiment": 122.80},
        "four_id15_in_series_2400V_deg": {
            "model": deg(4 * at_2400[0]), "paper_model": 100.8, "paper_experiment": 107.4,
        },
        "theta0_range_deg": {"model": [deg(table.theta0.min()), deg(table.theta0.max())], "paper": [3, 40]},
        "ids_5_7_vs_40_42_theta0_deg": {
            "ids_5_7": [deg(v) for v in table.theta0[table.index_of([5, 6, 7])]],
            "ids_40_42": [deg(v) for v in table.theta0[table.index_of([40, 41, 42])]],
        },
        "safe_voltage_V": {"min": float(table.safe_voltage.min()), "max": float(table.safe_voltage.max()),
                           "limited_by": sorted({Status(s).name for s in limit.limited_by})},
        "limit_without_breakdown_V": {"min": float(mechanical.voltage.min()), "max": float(mechanical.voltage.max()),
                                      "limited_by": sorted({Status(s).name for s in mechanical.limited_by})},
        "mass_g": {"min": round(1e3 * float(table.mass.min()), 3), "max": round(1e3 * float(table.mass.max()), 3),
                   "paper": [0.9, 1.1]},
        "stiffness_mNm_per_rad": {"min": round(1e3 * float(table.stiffness.min()), 3),
                                  "max": round(1e3 * float(table.stiffness.max()), 3)},
    }
    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "block_table.json").write_text(json.dumps(comparison, indent=2) + "\n")
    print(json.dumps(comparison, indent=2))

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    theta0 = np.degrees(table.theta0).reshape(len(ROD_DIAMETER_VALUES), len(ROD_LENGTH_VALUES), -1)
    colours = plt.cm.viridis(np.linspace(0.0, 0.85, len(ROD_DIAMETER_VALUES)))
    for i_d, (diameter, colour) in enumerate(zip(ROD_DIAMETER_VALUES, colours)):
        for i_l, (length, style) in enumerate(zip(ROD_LENGTH_VALUES, (":", "--", "-"))):
            left.plot(PRESTRETCH_AXIAL_VALUES, theta0[i_d, i_l], style, color=colour, marker=".",
                      label=f"D {1e3 * diameter:.3g} mm" if i_l == 2 else None)
    left.plot([], [], "k:", label="L 10 mm")
    left.plot([], [], "k--", label="L 12.5 mm")
    left.plot([], [], "k-", label="L 15 mm")
    left.set_xlabel("axial prestretch lambda_1")
    left.set_ylabel("theta_0 [deg]")
    left.set_title("Initial bending angle of the 84 designs")
    left.grid(alpha=0.3)
    left.legend(fontsize=7, ncol=2)

    for design in (15, 36, 57):
        index = table.index_of([design])[0]
        volts = np.linspace(0.0, table.safe_voltage[index], 60)
        angles, _ = table.angle_at([design] * volts.size, volts)
        right.plot(volts / 1e3, np.degrees(angles), label=f"ID {design} (safe up to {table.safe_voltage[index]:.0f} V)")
    right.plot([0.0, 2.4], [32.15, 32.15 - 5.29], "kx", markersize=8, label="paper FE, ID 15 (0 and 2.4 kV)")
    right.set_xlabel("voltage [kV]")
    right.set_ylabel("theta [deg]")
    right.set_title("Angle vs voltage up to the safe voltage")
    right.grid(alpha=0.3)
    right.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(FIGURES / "block_table.png", dpi=120)
    print(f"wrote {FIGURES / 'block_table.json'} and .png")


if __name__ == "__main__":
    main()
