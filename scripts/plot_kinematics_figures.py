"""Figures of docs/kinematics.md: conventions, Figure 2 B-D at rest and actuated, the sample objects.

    scripts/with_env.sh python scripts/plot_kinematics_figures.py
"""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from planner.assembly import load_assembly  # noqa: E402
from planner.contours import load_catalog_object  # noqa: E402
from planner.kinematics import BLOCK_RADIUS, CAP_LENGTH, assembly_centerlines, planar_chain  # noqa: E402
from planner.table import load_table  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
FIGURES = ROOT / "docs" / "figures"
ACTUATION_VOLTAGE = 2000.0  # [V], below the safe voltage of ID 15


def conventions(path: Path) -> None:
    """One block and a two-block worm in the x-z plane: caps, arc, theta, periphery, frames."""
    figure, (single, worm) = plt.subplots(1, 2, figsize=(8.0, 4.2))
    theta, length = math.radians(60), 15e-3
    for axes, shape, title in (
        (single, planar_chain([theta], [length], samples_per_block=20),
         f"one block: caps {CAP_LENGTH * 1e3:g} mm, arc L = {length * 1e3:g} mm,\ntheta = 60 deg, phi = 0"),
        (worm, planar_chain([theta, theta], [length, length], [0.0, math.pi], samples_per_block=20),
         "two such blocks, phi = (0, 180 deg):\nthe second bends the other way"),
    ):
        plus, minus = (side * 1e3 for side in shape.periphery())
        points = shape.points * 1e3
        axes.plot(points[:, 0], points[:, 1], "k-", label="centerline")
        axes.plot(plus[:, 0], plus[:, 1], "C0-", linewidth=0.8, label="periphery +normal")
        axes.plot(minus[:, 0], minus[:, 1], "C1-", linewidth=0.8, label="periphery -normal")
        ends = shape.ends * 1e3
        axes.plot(ends[:, 0], ends[:, 1], "ko", markersize=4)
        for end, heading in zip(ends, shape.end_headings):  # frame axes at the base and each block end
            z_axis = 6 * np.array([math.sin(heading), math.cos(heading)])
            x_axis = 6 * np.array([math.cos(heading), -math.sin(heading)])
            axes.annotate("", end + z_axis, end, arrowprops={"arrowstyle": "->", "color": "C2"})
            axes.annotate("", end + x_axis, end, arrowprops={"arrowstyle": "->", "color": "C3"})
        axes.set(xlabel="x [mm]", ylabel="z [mm]", aspect="equal")
        axes.set_title(title, fontsize=9)
        axes.grid(alpha=0.3)
    single.plot([], [], "C3-", label="frame x axis")
    single.plot([], [], "C2-", label="frame z axis")
    single.legend(fontsize=7, loc="upper left")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def figure2(path: Path) -> None:
    """Figure 2 B-D: the same four ID-15 blocks as arc, helix and worm; at 0 V and actuated."""
    table = load_table()
    figure = plt.figure(figsize=(10.5, 3.8))
    for k, name in enumerate(("figure2_arc", "figure2_helix", "figure2_worm")):
        assembly = load_assembly(ROOT / "config" / "assemblies" / f"{name}.yaml")
        axes = figure.add_subplot(1, 3, k + 1, projection="3d")
        every = []
        for volts, style in ((0.0, "-"), (ACTUATION_VOLTAGE, "--")):
            for shape in assembly_centerlines(assembly, table, {"main": volts}).values():
                points = shape.points * 1e3
                axes.plot(*points.T, style, color="C0" if volts == 0 else "C3", label=f"{volts:.0f} V")
                axes.scatter(*(shape.positions.T * 1e3), color="k", s=6)
                every.append(points)
        points = np.concatenate(every)
        centre, half = points.mean(axis=0), 0.5 * np.ptp(points, axis=0).max() + BLOCK_RADIUS * 1e3
        axes.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half),
                 zlim=(centre[2] - half, centre[2] + half), title=name, xlabel="x [mm]", ylabel="y [mm]", zlabel="z [mm]")
        axes.set_box_aspect((1, 1, 1))
        axes.legend(fontsize=7, loc="upper left")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def sample_objects(path: Path) -> None:
    """The sample objects' left and right contours in the object frame."""
    figure, axes_row = plt.subplots(1, 3, figsize=(8.0, 4.2))
    for axes, name in zip(axes_row, ("asymmetric", "strawberry", "gingerbread")):
        contours = load_catalog_object(name)
        axes.imshow(contours.mask, cmap="Greys", alpha=0.25, extent=_extent(contours))
        axes.plot(*(contours.left.T * 1e3), "C0-", label="left")
        axes.plot(*(contours.right.T * 1e3), "C3-", label="right")
        axes.plot(*(np.array([contours.top, contours.bottom]).T * 1e3), "ko", markersize=3, label="cut points")
        axes.plot(0, 0, "g+", markersize=10, label="origin")
        axes.set(title=f"{name}\n{contours.height * 1e3:.0f} x {contours.width * 1e3:.0f} mm", xlabel="x [mm]", aspect="equal")
    axes_row[0].set_ylabel("z [mm]")
    axes_row[0].legend(fontsize=7, loc="lower left")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _extent(contours) -> tuple[float, float, float, float]:
    """imshow extent [mm] of the mask in the object frame."""
    rows, columns = contours.mask.shape
    column0, row0 = contours.origin_pixel
    size = contours.pixel_size * 1e3
    return (-column0 * size, (columns - column0) * size, (row0 - rows) * size, row0 * size)


def main() -> None:
    FIGURES.mkdir(parents=True, exist_ok=True)
    for name, plot in (("kinematics_conventions", conventions), ("kinematics_figure2", figure2), ("sample_objects", sample_objects)):
        plot(FIGURES / f"{name}.png")
        print(f"wrote {FIGURES / name}.png")


if __name__ == "__main__":
    main()
