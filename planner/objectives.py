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
finger body is the tube of the block radius around the centerline; it overlaps the object when a
centerline sample is closer to the object than the radius (less one pixel, so touching is allowed), which
is checked on a distance transform of the object mask (``ClearanceMap``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from planner.kinematics import BLOCK_RADIUS

COLLISION_PENALTY = 1e11  # k of eq. (3)


def _finite_points(points, name: str) -> np.ndarray:
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2:
        raise ValueError(f"{name} must be an (n, 3) array of at least 2 points [m], got shape {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{name} contains NaN or infinite coordinates")
    return points


@dataclass(frozen=True)
class ClearanceMap:
    """Distance from points of a finger's plane to the object [m] (y of the points is ignored).

    Built on the object frame of ``planner.contours`` (x right, z up, origin at the top centre of the
    object): a finger-frame point (X, Y, Z) lies at x = base_x + side * X, z = -Z (the finger hangs down
    from the object's top edge and bends toward the object). The mask is padded by more than the block
    radius, so points outside the padded image are farther than the radius from the object.
    """

    distance: np.ndarray  # (rows, cols) distance of each padded pixel centre to the nearest object pixel [m]
    pixel_size: float
    pad: int
    origin_pixel: tuple[float, float]  # (column, row) of the object-frame origin in pixel-edge coordinates
    base_x: float  # finger base in the object frame [m] (at z = 0)
    side: float  # +1: finger X along object +x (left finger); -1: mirrored (right finger)

    @classmethod
    def from_contours(cls, contours, base_x: float, side: float, radius: float = BLOCK_RADIUS) -> ClearanceMap:
        pad = int(np.ceil(radius / contours.pixel_size)) + 2
        padded = np.pad(np.asarray(contours.mask, dtype=bool), pad)
        distance = ndimage.distance_transform_edt(~padded) * contours.pixel_size
        return cls(distance, float(contours.pixel_size), pad, tuple(contours.origin_pixel), float(base_x), float(side))

    def to_object(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) object-frame x, z [m] of finger-frame points (..., 3)."""
        return np.stack([self.base_x + self.side * points[..., 0], -points[..., 2]], axis=-1)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Distances [m] at finger-frame points (..., 3); inf outside the padded image."""
        column0, row0 = self.origin_pixel
        x = self.base_x + self.side * points[..., 0]
        col = np.floor(x / self.pixel_size + column0).astype(np.int64) + self.pad
        row = np.floor(row0 + points[..., 2] / self.pixel_size).astype(np.int64) + self.pad
        rows, cols = self.distance.shape
        inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
        result = np.full(points.shape[:-1], np.inf)
        result[inside] = self.distance[row[inside], col[inside]]
        return result


@dataclass(frozen=True)
class ShapeTarget:
    """What a chain's centerline is compared with, in the chain base frame [m].

    ``offset`` is subtracted from each centerline distance (0 for a path, the block radius for a finger
    conforming with its periphery); ``tip_offset`` moves the tip point along the tip's bending normal (the
    finger's periphery point on the object side). ``clearance`` (fingers only) gives the collision term.
    """

    points: np.ndarray  # (P, 3) target points: path points or contour points
    end_point: np.ndarray  # (3,) target of the chain tip
    offset: float = 0.0
    tip_offset: float = 0.0
    start_error: float = 0.0  # E0, fixed because the chain base is fixed
    clearance: ClearanceMap | None = None
    collision_tolerance: float = 0.0  # overlap allowed before C = 1 [m]
    bases: np.ndarray = field(default_factory=lambda: np.zeros((1, 3)))  # (K, 3) base positions to choose from

    @property
    def collision_distance(self) -> float:
        """Centerline samples closer than this to the object mean C = 1 [m]."""
        return self.offset - self.collision_tolerance


def path_target(points) -> ShapeTarget:
    """Eq. (1) target: a 3D path (n, 3) in the chain base frame, base first."""
    points = _finite_points(points, "path")
    return ShapeTarget(points=points, end_point=points[-1], start_error=float(np.linalg.norm(points[0])))


def finger_target(contour, clearance: ClearanceMap, base_offsets, radius: float = BLOCK_RADIUS) -> ShapeTarget:
    """Eq. (3) target: contour points (n, 3) in the finger frame, top to bottom, the object's clearance and
    the candidate base offsets [m] away from the object (along finger-frame -x)."""
    contour = _finite_points(contour, "contour")
    offsets = np.asarray(base_offsets, dtype=float).reshape(-1)
    return ShapeTarget(
        bases=np.stack([-offsets, np.zeros_like(offsets), np.zeros_like(offsets)], axis=1),
        points=contour,
        end_point=contour[-1],
        offset=radius,
        tip_offset=radius,
        clearance=clearance,
        collision_tolerance=clearance.pixel_size,
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


def evaluate(target: ShapeTarget, samples: np.ndarray, tip_rotation: np.ndarray, tip_position: np.ndarray) -> Cost:
    """Objective of chains given their centerline samples (..., M, 3) and tip frames (..., 3, 3)/(..., 3)."""
    gaps = np.abs(nearest_distances(target.points, samples) - target.offset)
    end_error = np.linalg.norm(tip_point(target, tip_rotation, tip_position) - target.end_point, axis=-1)
    error = target.start_error + end_error + gaps.sum(axis=-1)
    collision = colliding(target, samples)
    return Cost(total=error + COLLISION_PENALTY * collision, error=error, collision=collision)


def colliding(target: ShapeTarget, samples: np.ndarray) -> np.ndarray:
    """(...,) True where any centerline sample of (..., M, 3) is too close to the object."""
    if target.clearance is None:
        return np.zeros(samples.shape[:-2], dtype=bool)
    return np.any(target.clearance(samples) < target.collision_distance, axis=-1)
