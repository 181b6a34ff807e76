"""A second, independent renderer of side-view silhouettes: the chain as a thick polyline (capsule).

Written apart from ``estimation.render`` (which fills convex hulls of projected cross-section discs on a
supersampled grid) and from the estimator's forward model (``estimation.outline``), so that neither the
estimator nor its tests see only images drawn the way the estimator thinks: the centreline is integrated
here step by step (a 3x3 frame turned by each small piece of cap or arc), projected onto the chain's x-z
plane, and a point of the image is inside the body when it lies within one body radius of the projected
centreline and not beyond either end face (seen from the side, the end faces are line segments for a
planar chain and ellipses for a block turned out of the plane). Pixel coverage is exact to 1/16 on the
outline (4 x 4 samples per pixel) and 0 or 1 elsewhere.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from estimation.view import ImagePose
from planner.geometry import PAPER_GEOMETRY

# [m] between the polyline's vertices (each step along the arc is exact): a point's distance to the nearest
# vertex exceeds its distance to the curve by at most step^2 / (8 radius), 2.5e-6 m here
STEP = 5e-4
SAMPLES = 4  # per pixel side on the outline, by default


def _centreline(theta, length, steps, cap: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centreline points (K, 3) in the chain's base frame (+z: growth, bends toward +x at step 0), and the
    frames (3 x 3, columns = local x, y, z) at its two ends."""
    frame, position = np.eye(3), np.zeros(3)
    points = [position]
    first = None
    for bend, rod, step in zip(theta, length, steps):
        turn = step * math.pi / 6.0  # snap-fit steps of 30 degrees about the local z axis
        c, s = math.cos(turn), math.sin(turn)
        frame = frame @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        first = frame if first is None else first
        for piece, curvature in ((cap, 0.0), (rod, bend / rod), (cap, 0.0)):
            count = max(1, math.ceil(piece / STEP))
            h = piece / count
            a = curvature * h  # turn of one step about the local y axis
            if a == 0.0:
                move, pitch = np.array([0.0, 0.0, h]), np.eye(3)
            else:
                move = np.array([(1.0 - math.cos(a)) / curvature, 0.0, math.sin(a) / curvature])
                pitch = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
            for _ in range(count):
                position = position + frame @ move
                frame = frame @ pitch
                points.append(position)
    return np.array(points), first, frame


def _image_map(angle: float, mirrored: bool) -> np.ndarray:
    """(2, 2): chain (x, z) -> image direction (columns right, rows down). The chain grows along ``angle``
    (from image +x toward +y); its +x lies a quarter turn further that way, or back when mirrored."""
    growth = np.array([math.cos(angle), math.sin(angle)])
    side = np.array([-growth[1], growth[0]]) * (-1.0 if mirrored else 1.0)
    return np.column_stack([side, growth])


def capsule_silhouette(theta, length, rotation_steps, pixel_size: float, *, angle: float = 0.5 * math.pi,
                       mirrored: bool = False, margin: float = 5e-3, frame: tuple[ImagePose, tuple[int, int]] | None = None,
                       samples: int = SAMPLES, radius: float = PAPER_GEOMETRY.radius,
                       cap: float = PAPER_GEOMETRY.cap_length) -> tuple[np.ndarray, ImagePose]:
    """Coverage image (rows, cols) in [0, 1] of a chain (one theta [rad], rod length [m] and snap-fit step per
    block, base first) and its base pose; the image holds the chain with ``margin`` [m] around it, or is
    ``frame`` = (base pose, (rows, cols)) (then the pose's angle and mirror flag are used). Pixels on the
    outline are sampled ``samples`` x ``samples`` times (1: every pixel by its centre, 0 or 1)."""
    points, first, last = _centreline(theta, length, rotation_steps, cap)
    if frame is not None:
        angle, mirrored = frame[0].angle, frame[0].mirrored
    to_image = _image_map(angle, mirrored)
    flat = points[:, [0, 2]] @ to_image.T
    if frame is None:
        low = flat.min(axis=0) - radius - margin
        origin = -low  # the base centre in the image [m]
        columns, rows = (int(v) for v in np.ceil((flat.max(axis=0) + radius + margin - low) / pixel_size))
    else:
        origin = np.array([frame[0].x, frame[0].y])
        rows, columns = frame[1]
    flat = flat + origin
    ends = []
    for index, frame, outward in ((0, first, -1.0), (len(flat) - 1, last, 1.0)):
        axis = to_image @ frame[[0, 2], 2]  # the end's tangent, projected
        disc = np.column_stack([to_image @ frame[[0, 2], 0], to_image @ frame[[0, 2], 1]]) * radius
        ends.append((index, flat[index], outward * axis, disc))
    tree = cKDTree(flat)

    def inside(query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        distance, nearest = tree.query(query, distance_upper_bound=radius + 2 * pixel_size)
        result = distance <= radius
        for index, centre, outward, disc in ends:
            beyond = result & (nearest == index) & ((query - centre) @ outward > 0.0)
            result &= ~beyond  # past an end face: not the body (the face's own projection is added below)
            if abs(np.linalg.det(disc)) > 1e-12 * radius**2:  # the end disc seen at a slant: an ellipse
                coefficients = np.linalg.solve(disc, (query - centre).T)
                result |= np.sum(coefficients**2, axis=0) <= 1.0
        return result, distance

    grid_columns, grid_rows = np.meshgrid(np.arange(columns) + 0.5, np.arange(rows) + 0.5)
    centres = np.column_stack([grid_columns.ravel(), grid_rows.ravel()]) * pixel_size
    covered, distance = inside(centres)
    coverage = covered.astype(float)
    if samples <= 1:
        return coverage.reshape(rows, columns), ImagePose(float(origin[0]), float(origin[1]), float(angle), bool(mirrored))
    near_end = np.min([np.hypot(*(centres - end[1]).T) for end in ends], axis=0) <= radius + 2 * pixel_size
    edge = np.flatnonzero((np.abs(distance - radius) <= pixel_size) | near_end)
    offsets = ((np.arange(samples) + 0.5) / samples - 0.5) * pixel_size
    sub = np.stack(np.meshgrid(offsets, offsets), axis=-1).reshape(-1, 2)
    fine = (centres[edge][:, None, :] + sub[None]).reshape(-1, 2)
    coverage[edge] = inside(fine)[0].reshape(len(edge), -1).mean(axis=1)
    return coverage.reshape(rows, columns), ImagePose(float(origin[0]), float(origin[1]), float(angle), bool(mirrored))


def capsule_chain(design_ids, rotation_steps, table, pixel_size: float, *, offsets=None, voltage: float = 0.0,
                  angle: float = 0.5 * math.pi, mirrored: bool = False,
                  frame: tuple[ImagePose, tuple[int, int]] | None = None) -> tuple[np.ndarray, ImagePose, np.ndarray]:
    """Coverage image of a chain of table designs (angles at ``voltage`` plus ``offsets`` [rad]), its base
    pose and the angles drawn [rad]; ``frame`` as for ``capsule_silhouette``."""
    rows = table.index_of(np.asarray(design_ids))
    theta = np.asarray(table.angle_at(np.asarray(design_ids), voltage)[0], dtype=float)
    theta = theta + (0.0 if offsets is None else np.asarray(offsets, dtype=float))
    length = np.asarray(table.rod_length, dtype=float)[rows]
    steps = np.zeros(len(rows), int) if rotation_steps is None else np.asarray(rotation_steps, int)
    coverage, pose = capsule_silhouette(theta, length, steps, pixel_size, angle=angle, mirrored=mirrored, frame=frame)
    return coverage, pose, theta
