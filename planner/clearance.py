"""Exact clearance between a finger's body and an object's pixels: the collision term C of eq. (2).

The object is the union of its closed pixel squares. The finger body is the tube of radius r around the
whole continuous centerline (the cap segments and arcs of every block, base to tip, round ends
included). The body enters the object by more than ``contact_tolerance_m`` exactly when the centerline
comes closer than ``r - contact_tolerance_m`` to a pixel square; the clearance reported is the smallest
centerline-to-object distance minus r (negative: overlap).

Distances come from two exact sources:

- a lattice of nodes every ``pixel / SUBDIVISION``. The point of a union of closed pixel squares nearest
  to a lattice node is itself a lattice node (clamping a multiple of 1/f into [i, i + 1] keeps it one), so
  the Euclidean distance transform of the nodes the object covers is exact at every node, and anywhere
  else the distance lies within the nearest node's distance +- the offset to that node (1-Lipschitz);
- per pixel row, the nearest object column left and right of every column, which give the exact
  distance of any point (nearest square row by row, outward until the rows are farther than the best)
  where the lattice cannot decide.

Along the centerline the distance changes by at most the arc length travelled, so a stretch of arc
length ds whose end distances are at least a and b stays at least (a + b - ds) / 2 away. A block's
centerline is checked at ``DENSE_SAMPLES`` points; stretches this cannot decide are halved, with exact
end distances, until they are decided to within ``RESOLUTION`` (1 um, 1/250 of a 0.25 mm pixel).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage

from planner.kinematics import BLOCK_RADIUS, CAP_LENGTH

SUBDIVISION = 2  # lattice nodes per pixel side
DENSE_SAMPLES = 48  # centerline points per block checked against the lattice before any refinement
RESOLUTION = 1e-6  # [m] the rule is decided to within this (overlaps smaller than 1 um count as touching)
_STACK = 256  # pending stretches per block check (twice the halving depth, about 20, is far below this)


@dataclass(frozen=True)
class ObjectDistance:
    """Exact distance from object-frame points (x right, z up) [m] to an object's pixel squares.

    ``lattice[a, b]`` is the exact distance of the node at x = x0 + b * spacing, z = z0 - a * spacing.
    The lattice reaches ``reach`` beyond the object on every side; points outside it are farther than that.
    """

    lattice: np.ndarray
    spacing: float
    x0: float
    z0: float
    reach: float
    left: np.ndarray  # (rows, cols) int: nearest object column <= this one in the row, -1 if none
    right: np.ndarray  # (rows, cols) int: nearest object column >= this one in the row, cols if none
    mask: np.ndarray  # (rows, cols) bool, the object's pixels
    pixel_size: float
    origin_pixel: tuple[float, float]  # (column, row) of the object-frame origin in pixel-edge units

    @classmethod
    def from_contours(cls, contours, reach: float = BLOCK_RADIUS + 1e-3) -> ObjectDistance:
        """Lattice and edges of ``contours.mask`` (a ``planner.contours.ObjectContours``); ``reach`` [m]."""
        mask = np.asarray(contours.mask, dtype=bool)
        pixel = float(contours.pixel_size)
        pad = int(np.ceil(reach / pixel)) + 1
        padded = np.pad(mask, pad)
        rows, cols = padded.shape
        f = SUBDIVISION
        covered = np.zeros((f * rows + 1, f * cols + 1), dtype=bool)
        for da in range(f + 1):  # node (f j + da, f i + db) lies in the closed square of pixel (j, i)
            for db in range(f + 1):
                covered[da : da + f * rows : f, db : db + f * cols : f] |= padded
        lattice = ndimage.distance_transform_edt(~covered) * (pixel / f)
        column0, row0 = contours.origin_pixel
        return cls(
            lattice=lattice,
            spacing=pixel / f,
            x0=(-pad - column0) * pixel,
            z0=(row0 + pad) * pixel,
            reach=(pad - 1) * pixel,
            left=_nearest_columns(mask, from_left=True),
            right=_nearest_columns(mask, from_left=False),
            mask=mask,
            pixel_size=pixel,
            origin_pixel=(float(column0), float(row0)),
        )

    @property
    def kernel_args(self) -> tuple:
        """The fields in the order the compiled kernels take them."""
        return (self.lattice, self.spacing, self.x0, self.z0, self.reach, self.left, self.right, self.mask,
                self.pixel_size, self.origin_pixel[0], self.origin_pixel[1])

    def exact(self, points) -> np.ndarray:
        """Exact distance [m] of object-frame points (..., 2) to the object (0 inside)."""
        points = np.asarray(points, dtype=float)
        flat = points.reshape(-1, 2)
        out = np.empty(len(flat))
        _exact_many(self.kernel_args, flat, out)
        return out.reshape(points.shape[:-1])


def _nearest_columns(mask: np.ndarray, from_left: bool) -> np.ndarray:
    """Per row, the nearest object column at or left of (``from_left``) / right of each column."""
    columns = np.arange(mask.shape[1])
    if from_left:
        return np.maximum.accumulate(np.where(mask, columns, -1), axis=1)
    flipped = np.where(mask, columns, mask.shape[1])[:, ::-1]
    return np.minimum.accumulate(flipped, axis=1)[:, ::-1]


# ------------------------------------------------------------------------------------------ kernels
@njit(cache=True, nogil=True)
def exact_distance(field, x, z):
    """Exact distance of one object-frame point to the pixel squares (0 inside one)."""
    left, right, mask, pixel, column0, row0 = field[5], field[6], field[7], field[8], field[9], field[10]
    rows, cols = mask.shape
    u = x / pixel + column0  # pixel-edge units: column i spans [i, i + 1], row j spans [j, j + 1]
    v = row0 - z / pixel
    column = min(max(int(np.floor(u)), 0), cols - 1)
    start = min(max(int(np.floor(v)), 0), rows - 1)
    best = np.inf  # squared, in pixels
    for direction in (1, -1):
        j = start if direction == 1 else start - 1
        while 0 <= j < rows:
            dv = max(j - v, v - (j + 1), 0.0)
            if dv * dv >= best:
                break
            du = np.inf
            before, after = left[j, column], right[j, column]
            if before >= 0:
                du = max(u - (before + 1), before - u, 0.0) if before == column else u - (before + 1)
            if after < cols:
                du = min(du, max(after - u, u - (after + 1), 0.0) if after == column else after - u)
            du = max(du, 0.0)
            best = min(best, du * du + dv * dv)
            j += direction
    return np.sqrt(best) * pixel


@njit(cache=True, nogil=True)
def _exact_many(field, points, out):
    for i in range(points.shape[0]):
        out[i] = exact_distance(field, points[i, 0], points[i, 1])


@njit(cache=True, nogil=True)
def lattice_bounds(field, x, z):
    """(lower, upper) bounds of the distance at an object-frame point from the nearest lattice node."""
    lattice, spacing, x0, z0, reach = field[0], field[1], field[2], field[3], field[4]
    b = int(np.round((x - x0) / spacing))
    a = int(np.round((z0 - z) / spacing))
    if a < 0 or b < 0 or a >= lattice.shape[0] or b >= lattice.shape[1]:
        return reach, np.inf
    offset = np.hypot(x - (x0 + b * spacing), z - (z0 - a * spacing))
    value = lattice[a, b]
    return value - offset, value + offset


@njit(cache=True, nogil=True)
def block_point(theta, length, cap, s):
    """Centerline point (lateral x, axial z) of a block in its start frame at arc length s from its start."""
    if s <= cap:
        return 0.0, s
    if abs(theta) < 1e-12:
        return 0.0, s
    curvature = theta / length
    t = min(s - cap, length)
    x = (1.0 - np.cos(curvature * t)) / curvature
    z = cap + np.sin(curvature * t) / curvature
    rest = s - cap - length
    if rest > 0.0:
        x += rest * np.sin(theta)
        z += rest * np.cos(theta)
    return x, z


@njit(cache=True, nogil=True)
def _to_object(frame, pose_x, pose_z, heading, x, z):
    """Object-frame point of a block-local point (x, z) at finger-frame pose; frame = (base_x, side)."""
    cos, sin = np.cos(heading), np.sin(heading)
    finger_x = pose_x + x * cos + z * sin
    finger_z = pose_z - x * sin + z * cos
    return frame[0] + frame[1] * finger_x, -finger_z


@njit(cache=True, nogil=True)
def block_min_distance(field, frame, pose_x, pose_z, heading, theta, length, cap, threshold, report):
    """Smallest distance from one block's centerline (start pose in the finger frame) to the object.

    ``report`` False: a search check. Returns a value < ``threshold - RESOLUTION`` as soon as the centerline
    is proven to come that close, otherwise a value >= that (proven: nowhere closer than
    ``threshold - 2 RESOLUTION``). ``report`` True: the minimum itself to within RESOLUTION (``threshold``
    is an upper bound already known, e.g. from other blocks: stretches that cannot go below it are skipped).
    """
    total = 2.0 * cap + length
    n = DENSE_SAMPLES
    s_values = np.empty(n)
    lower = np.empty(n)
    best = np.inf
    for i in range(n):
        s = total * i / (n - 1)
        x, z = block_point(theta, length, cap, s)
        ox, oz = _to_object(frame, pose_x, pose_z, heading, x, z)
        lo, hi = lattice_bounds(field, ox, oz)
        s_values[i] = s
        lower[i] = lo
        best = min(best, hi)
        if not report and best < threshold - RESOLUTION:
            return best
    # stretches (s_a, s_b, lower_a, lower_b, exact flags) still to decide
    stack = np.empty((_STACK, 6))
    top = 0
    for i in range(n - 1):
        stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3] = s_values[i], s_values[i + 1], lower[i], lower[i + 1]
        stack[top, 4], stack[top, 5] = 0.0, 0.0
        top += 1
        while top > 0:
            top -= 1
            s_a, s_b, lo_a, lo_b, exact_a, exact_b = stack[top]
            if report and best <= 0.0:  # the centerline is inside the object: nothing is closer
                return 0.0
            limit = (min(best, threshold) if report else threshold) - RESOLUTION
            if 0.5 * (lo_a + lo_b - (s_b - s_a)) >= limit:
                continue
            if exact_a == 0.0 or exact_b == 0.0:  # replace lattice bounds by exact distances, then retry
                for end in range(2):
                    if stack[top, 4 + end] == 0.0:
                        x, z = block_point(theta, length, cap, stack[top, end])
                        ox, oz = _to_object(frame, pose_x, pose_z, heading, x, z)
                        value = exact_distance(field, ox, oz)
                        stack[top, 2 + end], stack[top, 4 + end] = value, 1.0
                        best = min(best, value)
                if not report and best < threshold - RESOLUTION:
                    return best
                top += 1
                continue
            if s_b - s_a <= RESOLUTION:
                continue
            if top + 2 > _STACK:  # cannot happen (depth-first halving); if it did, never call it clear
                return best if report else min(best, threshold - 2.0 * RESOLUTION)
            middle = 0.5 * (s_a + s_b)
            x, z = block_point(theta, length, cap, middle)
            ox, oz = _to_object(frame, pose_x, pose_z, heading, x, z)
            value = exact_distance(field, ox, oz)
            best = min(best, value)
            if not report and best < threshold - RESOLUTION:
                return best
            stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3] = s_a, middle, lo_a, value
            stack[top, 4], stack[top, 5] = 1.0, 1.0
            stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2], stack[top + 1, 3] = middle, s_b, value, lo_b
            stack[top + 1, 4], stack[top + 1, 5] = 1.0, 1.0
            top += 2
    return best


@njit(cache=True, nogil=True)
def chains_min_distance(field, frame, theta, length, base_x, cap, threshold, report, out):
    """Smallest centerline-to-object distance of planar chains (n, N) based at (base_x[i], 0), heading 0.

    ``report`` True: the minima (to within RESOLUTION). False: a collision check against ``threshold`` (see
    ``block_min_distance``); a chain stops at its first colliding block.
    """
    for i in range(theta.shape[0]):
        pose_x, pose_z, heading = base_x[i], 0.0, 0.0
        best = np.inf
        for k in range(theta.shape[1]):
            limit = best if report else threshold
            best = min(best, block_min_distance(field, frame, pose_x, pose_z, heading, theta[i, k], length[i, k],
                                                cap, limit, report))
            if not report and best < threshold - RESOLUTION:
                break
            end_x, end_z = block_point(theta[i, k], length[i, k], cap, 2.0 * cap + length[i, k])
            cos, sin = np.cos(heading), np.sin(heading)
            pose_x, pose_z = pose_x + end_x * cos + end_z * sin, pose_z - end_x * sin + end_z * cos
            heading += theta[i, k]
        out[i] = best


@dataclass(frozen=True)
class FingerBody:
    """The collision rule of one finger: its object, its placement and the tolerated overlap [m].

    A finger-frame point (X, Z) lies at object-frame x = base_x + side * X, z = -Z (the finger hangs down
    from the object's top edge and bends toward the object).
    """

    distance: ObjectDistance
    base_x: float
    side: float  # +1: finger X along object +x (left finger); -1: mirrored (right finger)
    radius: float = BLOCK_RADIUS
    contact_tolerance_m: float = 0.0
    cap_length: float = CAP_LENGTH

    @property
    def frame(self) -> tuple[float, float]:
        return (self.base_x, self.side)

    @property
    def threshold(self) -> float:
        """Centerline-to-object distances below this are a collision [m] (decided to within RESOLUTION)."""
        return self.radius - self.contact_tolerance_m

    def to_object(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) object-frame x, z [m] of finger-frame points (..., 3) or (..., 2) given as x, (y,) z."""
        return np.stack([self.base_x + self.side * points[..., 0], -points[..., -1]], axis=-1)

    def _chains(self, theta, length, base_x, report: bool) -> np.ndarray:
        theta = np.asarray(theta, dtype=float)
        length = np.broadcast_to(np.asarray(length, dtype=float), theta.shape)
        batch = theta.shape[:-1]
        flat_base = np.ascontiguousarray(np.broadcast_to(np.asarray(base_x, dtype=float), batch).reshape(-1))
        out = np.empty(flat_base.size)
        blocks = theta.shape[-1]
        chains_min_distance(self.distance.kernel_args, self.frame, np.ascontiguousarray(theta.reshape(-1, blocks)),
                            np.ascontiguousarray(length.reshape(-1, blocks)), flat_base, self.cap_length,
                            self.threshold, report, out)
        return out.reshape(batch)

    def clearance(self, theta, length, base_x) -> np.ndarray:
        """Minimum clearance [m] (centerline distance to the object minus r; negative: overlap, down to -r)
        of planar chains theta, length (..., N) whose base sits at finger-frame (base_x (...), 0)."""
        return self._chains(theta, length, base_x, True) - self.radius

    def colliding(self, theta, length, base_x) -> np.ndarray:
        """C of eq. (2) for the same chains: the body enters the object by more than the tolerance."""
        return self._chains(theta, length, base_x, False) < self.threshold - RESOLUTION
