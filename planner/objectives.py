"""Design objectives of the paper's shape optimization (section 2.3, eqs. 1-3).

Both objectives compare a chain's centerline with target points, all in the chain's base frame [m]:

- Path following, eq. (1): ``E0 + Ef + sum_n En``. E0 = distance from the chain base (the origin) to the
  first path point, Ef = distance from the chain tip to the last path point, En = distance from path
  point n to the centerline point whose normal passes through it.
- Finger conforming, eqs. (2)-(3): ``k C + Ef + sum_n En`` with k = 1e11. En = distance from contour
  point n to the finger's periphery along that normal (centerline distance minus the block radius),
  Ef = distance from the tip's periphery point on the object side to the contour's end point, and
  C = 1 when the finger body overlaps the object.

"The centerline point whose normal passes through p" is taken as the centerline sample closest to p: on a
smooth curve the closest point is a foot of the normal (and the nearest one when there are several). The
finger body is the tube of the block radius around the whole continuous centerline; C is decided exactly
against the object's pixel squares by ``planner.clearance.FingerBody`` (touching is allowed, and so is an
overlap up to its ``contact_tolerance_m``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.clearance import FingerBody

COLLISION_PENALTY = 1e11  # k of eq. (3)


def _finite_points(points, name: str) -> np.ndarray:
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2:
        raise ValueError(f"{name} must be an (n, 3) array of at least 2 points [m], got shape {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{name} contains NaN or infinite coordinates")
    return points


@dataclass(frozen=True)
class ShapeTarget:
    """What a chain's centerline is compared with, in the chain base frame [m].

    ``offset`` is subtracted from each centerline distance (0 for a path, the block radius for a finger
    conforming with its periphery); ``tip_offset`` moves the tip point along the tip's bending normal (the
    finger's periphery point on the object side). ``body`` (fingers only) decides the collision term.
    """

    points: np.ndarray  # (P, 3) target points: path points or contour points
    end_point: np.ndarray  # (3,) target of the chain tip
    offset: float = 0.0
    tip_offset: float = 0.0
    start_error: float = 0.0  # E0, fixed because the chain base is fixed
    body: FingerBody | None = None
    bases: np.ndarray = field(default_factory=lambda: np.zeros((1, 3)))  # (K, 3) base positions to choose from


def path_target(points) -> ShapeTarget:
    """Eq. (1) target: a 3D path (n, 3) in the chain base frame, base first."""
    points = _finite_points(points, "path")
    return ShapeTarget(points=points, end_point=points[-1], start_error=float(np.linalg.norm(points[0])))


def finger_target(contour, body: FingerBody, base_offsets) -> ShapeTarget:
    """Eq. (3) target: contour points (n, 3) in the finger frame, top to bottom, the finger's collision rule
    and the candidate base offsets [m] away from the object (along finger-frame -x)."""
    contour = _finite_points(contour, "contour")
    offsets = np.asarray(base_offsets, dtype=float).reshape(-1)
    return ShapeTarget(
        bases=np.stack([-offsets, np.zeros_like(offsets), np.zeros_like(offsets)], axis=1),
        points=contour,
        end_point=contour[-1],
        offset=body.radius,
        tip_offset=body.radius,
        body=body,
    )


def nearest_distances(targets: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """(..., P) distance from each target point (P, 3) to the nearest of the samples (..., M, 3)."""
    squared = (
        np.einsum("...mk,...mk->...m", samples, samples)[..., None]
        - 2.0 * samples @ targets.T
        + np.einsum("pk,pk->p", targets, targets)
    )
    return np.sqrt(np.maximum(squared.min(axis=-2), 0.0))


def tip_point(target: ShapeTarget, tip_rotation: np.ndarray, tip_position: np.ndarray) -> np.ndarray:
    """The point of the chain tip compared with ``target.end_point``: centerline tip, moved to the
    periphery on the bending side (frame x axis) for fingers."""
    return tip_position + target.tip_offset * tip_rotation[..., :, 0]


@dataclass(frozen=True)
class Cost:
    """Objective value of a batch of chains; ``total = k * collision + error``."""

    total: np.ndarray  # (...,) [m] (plus k where colliding)
    error: np.ndarray  # (...,) E0 + Ef + sum En [m]
    collision: np.ndarray  # (...,) bool, C of eq. (2)


def shape_error(target: ShapeTarget, samples: np.ndarray, tip_rotation: np.ndarray,
                tip_position: np.ndarray) -> np.ndarray:
    """(...,) E0 + Ef + sum En [m] of chains given their centerline samples (..., M, 3) and tip frames
    (..., 3, 3)/(..., 3): the objective without its collision term."""
    gaps = np.abs(nearest_distances(target.points, samples) - target.offset)
    end_error = np.linalg.norm(tip_point(target, tip_rotation, tip_position) - target.end_point, axis=-1)
    return target.start_error + end_error + gaps.sum(axis=-1)


def evaluate(target: ShapeTarget, samples: np.ndarray, tip_rotation: np.ndarray, tip_position: np.ndarray,
             blocks=None) -> Cost:
    """Objective of chains given their centerline samples (..., M, 3) and tip frames (..., 3, 3)/(..., 3).

    ``blocks`` = (theta, length, base_x): the planar chains' blocks (..., N) and base positions (...), which
    finger targets need for the collision term (None for paths).
    """
    error = shape_error(target, samples, tip_rotation, tip_position)
    if target.body is None:
        collision = np.zeros(error.shape, dtype=bool)
    elif blocks is None:
        raise ValueError("a finger target needs the chains' blocks (theta, length, base_x) for the collision term")
    else:
        collision = target.body.colliding(*blocks)
    return Cost(total=error + COLLISION_PENALTY * collision, error=error, collision=collision)
