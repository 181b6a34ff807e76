"""Draw the package layers of pyproject.toml's import-linter contract and the imports between the packages
(read from the code with grimp) into docs/figures/layers.png.

    scripts/with_env.sh python scripts/draw_layers.py
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import grimp
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyBboxPatch  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "docs" / "figures" / "layers.png"
ROLE = {"softblock_ros": "ROS 2 nodes, launcher, demo", "sequencing": "sequence schema + engine",
        "recording": "MCAP files, replay timing, analysis", "planner": "block physics, table, kinematics, design",
        "sim_fallback": "simulated supply and arm", "hv_driver": "HV driver + safety supervisor",
        "softblock_config": "shipped data (config/)"}


def layers() -> list[list[str]]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    contract = next(c for c in config["contracts"] if c["type"] == "layers")
    return [[name.strip() for name in layer.split("|")] for layer in contract["layers"]]


def package_imports(packages: list[str]) -> set[tuple[str, str]]:
    graph = grimp.build_graph(*packages)
    edges = set()
    for importer in packages:
        for imported in packages:
            if importer != imported and graph.direct_import_exists(importer=importer, imported=imported,
                                                                    as_packages=True):
                edges.add((importer, imported))
    return edges


def main() -> int:
    rows = layers()
    packages = [name for row in rows for name in row]
    edges = package_imports(packages)
    width, height, step = 3.6, 1.05, 1.45
    fig, ax = plt.subplots(figsize=(9, step * len(rows) + 0.9))
    for level, row in enumerate(rows):
        y = (len(rows) - 1 - level) * step
        for column, name in enumerate(row):
            x = (column - (len(row) - 1) / 2) * (width + 0.5)
            ros = name == "softblock_ros"
            ax.add_patch(FancyBboxPatch((x - width / 2, y - height / 2), width, height, boxstyle="round,pad=0.05",
                                        facecolor="#fde2c8" if ros else "#d6e6f5", edgecolor="k"))
            imports = sorted(imported for importer, imported in edges if importer == name)
            ax.text(x, y + 0.28, name, ha="center", va="center", fontsize=11, weight="bold")
            ax.text(x, y + 0.0, ROLE.get(name, ""), ha="center", va="center", fontsize=8)
            ax.text(x, y - 0.28, "imports " + (", ".join(imports) if imports else "none of these"), ha="center",
                    va="center", fontsize=7.5, color="0.3", style="italic")
        if level < len(rows) - 1:
            ax.annotate("", xy=(-4.3, y - step + height / 2), xytext=(-4.3, y - height / 2),
                        arrowprops={"arrowstyle": "-|>", "color": "0.5"})
    ax.set_xlim(-4.5, 4.5)
    ax.set_ylim(-0.8, (len(rows) - 1) * step + 0.8)
    ax.axis("off")
    ax.set_title("Package layers (import-linter contract in pyproject.toml): a package imports only layers below it,\n"
                 "as found in the code (grimp). Only softblock_ros imports rclpy or message packages.", fontsize=10)
    fig.tight_layout()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT, dpi=110)
    print(f"wrote {OUT} ({len(edges)} package imports)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
