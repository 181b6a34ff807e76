"""Designed fingers over their object: at rest and at 2.4 kV (the demo's finger figure), or a design result
(``python -m planner design-finger --png``)."""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from planner.assembly import Chain  # noqa: E402
from planner.contours import load_catalog_object  # noqa: E402
from planner.kinematics import BLOCK_RADIUS, chain_shape, design_parameters  # noqa: E402
from planner.table import load_table  # noqa: E402

ACTUATED_VOLTAGE = 2400.0  # [V] the paper's grasp voltage
SIDE_COLOURS = {"left": "tab:blue", "right": "tab:red"}


def finger_centerline(chain: Chain, table, voltage: float | None) -> np.ndarray:
    """(P, 2) x-z centerline of a designed finger chain (base pose in the object frame)."""
    theta, length, _ = design_parameters(table, list(chain.design_ids), voltage)
    shape = chain_shape(theta, length).transformed(Rotation.from_quat(chain.base_orientation).as_matrix(),
                                                   chain.base_position)
    return shape.points[:, [0, 2]]


def draw_object(axis, contours) -> None:
    """The object's mask and its left and right contours on ``axis``, object frame in mm."""
    height, width = contours.mask.shape
    ox, oz = contours.origin_pixel  # object-frame origin in pixel coordinates (column, row)
    extent = np.array([-ox, width - ox, oz - height, oz]) * contours.pixel_size
    axis.imshow(contours.mask, cmap="Greys", alpha=0.35, extent=extent * 1e3, origin="upper")
    for contour in (contours.left, contours.right):
        axis.plot(*(1e3 * contour.T), color="k", lw=1)
    axis.set_aspect("equal")
    axis.set_xlabel("x [mm]")
    axis.set_ylabel("z [mm]")


def draw_finger(axis, centerline: np.ndarray, colour, label: str, body: bool = True, **line) -> None:
    """A finger's (P, 2) centerline [m] on ``axis`` in mm; ``body``: also the tube of radius r around it."""
    axis.plot(*(1e3 * centerline.T), color=colour, label=label, **({"lw": 2} | line))
    if body:
        for point in centerline:
            axis.add_patch(plt.Circle(1e3 * point, 1e3 * BLOCK_RADIUS, color=colour, alpha=0.03, lw=0))


def plot_fingers(fingers: Mapping[str, Mapping[str, tuple[Chain, float]]], object_name: str, path: Path) -> None:
    """One panel per finger set: the object, its contours and the set's ``left``/``right`` (chain, objective [m])."""
    table = load_table()
    contours = load_catalog_object(object_name)
    fig, axes = plt.subplots(1, len(fingers), figsize=(4.5 * len(fingers), 5.5), squeeze=False)
    for axis, (finger_set, sides) in zip(axes[0], fingers.items()):
        draw_object(axis, contours)
        for side, colour in SIDE_COLOURS.items():
            chain = sides[side][0]
            draw_finger(axis, finger_centerline(chain, table, None), colour, f"{side} {list(chain.design_ids)} at 0 V")
            draw_finger(axis, finger_centerline(chain, table, ACTUATED_VOLTAGE), colour, f"{side} at 2.4 kV",
                        body=False, lw=1, ls="--")
        axis.set_title(f"{finger_set} fingers (objective {sides['left'][1]:.3f} / {sides['right'][1]:.3f} m)",
                       fontsize=9)
        axis.legend(fontsize=6, loc="lower center")
    fig.suptitle(f"designed fingers for the {object_name} object (object frame)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_designed_fingers(result, contours, path: Path) -> None:
    """A ``planner.design.FingerDesignResult`` over its object (``planner.contours.ObjectContours``), at rest."""
    fig, axis = plt.subplots(figsize=(5, 6))
    draw_object(axis, contours)
    for side, colour in SIDE_COLOURS.items():
        finger = getattr(result, side)
        draw_finger(axis, finger.centerline, colour, f"{side} {list(finger.design_ids)}, cost {finger.cost:.3f} m")
    axis.legend(fontsize=7, loc="lower center")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
