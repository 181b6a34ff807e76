"""Reference renderer: side-view silhouettes of block chains, and the image faults tests inflict on them.

Deliberately independent of the estimator's forward model (``estimation.outline``, which builds on
``planner.kinematics``): the chain is composed here from 4x4 homogeneous transforms in a plain loop, the
body is the tube of radius r swept along the centreline (caps included), and the silhouette is the union
of the convex hulls of consecutive cross-section discs projected onto the chain's x-z plane, filled
exactly on a supersampled grid (matplotlib's point-in-polygon test). A bug shared with the estimator
would have to be made twice, in different code.
"""
from __future__ import annotations

import math

import numpy as np
from matplotlib.path import Path as PolygonPath
from scipy import ndimage
from scipy.spatial import ConvexHull

from estimation.view import ImagePose
from planner.geometry import PAPER_GEOMETRY

DISC_VERTICES = 32  # vertices of each projected cross-section disc
MAX_STEP = 0.5e-3  # largest step between cross-sections along the centreline [m]


def _rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _translation_z(distance: float) -> np.ndarray:
    frame = np.eye(4)
    frame[2, 3] = distance
    return frame


def _arc(theta: float, length: float, travelled: float) -> np.ndarray:
    """Frame after ``travelled`` metres along an arc of ``length`` bent by ``theta`` about +y (toward +x)."""
    angle = theta * travelled / length
    frame = np.eye(4)
    c, s = math.cos(angle), math.sin(angle)
    frame[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    if abs(theta) < 1e-12:
        frame[2, 3] = travelled
    else:
        radius = length / theta
        frame[0, 3], frame[2, 3] = radius * (1 - c), radius * s
    return frame


def cross_section_frames(theta, length, phi, cap_length: float = PAPER_GEOMETRY.cap_length,
                         step: float = MAX_STEP) -> list[np.ndarray]:
    """4x4 frames (z = tangent) along the centreline of a chain, base first, at most ``step`` apart."""
    frames = []
    frame = np.eye(4)
    for bend, rod, turn in zip(theta, length, phi):
        frame = frame @ _rotation_z(float(turn))
        cap_steps = max(1, math.ceil(cap_length / step))
        arc_steps = max(1, math.ceil(rod / step))
        frames += [frame @ _translation_z(cap_length * k / cap_steps) for k in range(cap_steps)]
        frame = frame @ _translation_z(cap_length)
        frames += [frame @ _arc(float(bend), float(rod), rod * k / arc_steps) for k in range(arc_steps)]
        frame = frame @ _arc(float(bend), float(rod), float(rod))
        frames += [frame @ _translation_z(cap_length * k / cap_steps) for k in range(cap_steps)]
        frame = frame @ _translation_z(cap_length)
    frames.append(frame)
    return frames


def _rims(theta, length, phi, cap_length: float, radius: float) -> list[np.ndarray]:
    """Rim of every cross-section disc projected onto the chain's x-z plane: (DISC_VERTICES, 2) each [m]."""
    around = np.linspace(0.0, 2.0 * np.pi, DISC_VERTICES, endpoint=False)
    rims = []
    for frame in cross_section_frames(theta, length, phi, cap_length):
        rim = frame[:3, 3] + radius * (np.cos(around)[:, None] * frame[:3, 0] + np.sin(around)[:, None] * frame[:3, 1])
        rims.append(rim[:, [0, 2]])
    return rims


def framing(theta, length, phi, pixel_size: float, *, angle: float = 0.5 * np.pi, mirrored: bool = False,
            margin: float = 5e-3, radius: float = PAPER_GEOMETRY.radius,
            cap_length: float = PAPER_GEOMETRY.cap_length) -> tuple[ImagePose, tuple[int, int]]:
    """A base pose and an image shape (rows, cols) that show the whole chain with ``margin`` [m] around it."""
    probe = ImagePose(0.0, 0.0, angle, mirrored)
    rims = probe.to_image(np.concatenate(_rims(theta, length, phi, cap_length, radius)))
    low, high = rims.min(axis=0) - margin, rims.max(axis=0) + margin
    columns, rows = np.ceil((high - low) / pixel_size).astype(int)
    return ImagePose(float(-low[0]), float(-low[1]), angle, mirrored), (int(rows), int(columns))


def render_silhouette(theta, length, phi, pose: ImagePose, pixel_size: float, shape: tuple[int, int], *,
                      radius: float = PAPER_GEOMETRY.radius, cap_length: float = PAPER_GEOMETRY.cap_length,
                      supersample: int = 4) -> np.ndarray:
    """Fraction of each pixel (rows, cols) covered by the chain's side view, in [0, 1].

    theta [rad], length [m], phi [rad]: one value per block, base first (phi: rotation about the local z
    axis relative to the previous block). The chain's x-z plane is the image plane; ``pose`` places it.
    """
    theta, length, phi = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (theta, length, phi))
    if not (theta.shape == length.shape == phi.shape) or theta.ndim != 1 or theta.size == 0:
        raise ValueError("theta, length and phi need one value per block each")
    rows, columns = shape
    fine = pixel_size / supersample
    canvas = np.zeros((rows * supersample, columns * supersample), dtype=bool)
    discs = [pose.to_image(rim) / fine for rim in _rims(theta, length, phi, cap_length, radius)]  # fine pixels
    for first, second in zip(discs[:-1], discs[1:]):
        points = np.concatenate([first, second])
        hull = points[ConvexHull(points).vertices]
        low = np.maximum(np.floor(hull.min(axis=0)).astype(int), 0)
        high = np.minimum(np.ceil(hull.max(axis=0)).astype(int), [canvas.shape[1], canvas.shape[0]])
        if np.any(high <= low):
            continue
        columns_, rows_ = np.meshgrid(np.arange(low[0], high[0]), np.arange(low[1], high[1]))
        centres = np.column_stack([columns_.ravel() + 0.5, rows_.ravel() + 0.5])
        inside = PolygonPath(hull).contains_points(centres).reshape(columns_.shape)
        canvas[low[1]:high[1], low[0]:high[0]] |= inside
    return canvas.reshape(rows, supersample, columns, supersample).mean(axis=(1, 3))


def render_chain(design_ids, rotation_steps, table, pixel_size: float, *, offsets=None, voltage: float = 0.0,
                 angle: float = 0.5 * np.pi, mirrored: bool = False, frame: tuple[ImagePose, tuple[int, int]] | None = None,
                 supersample: int = 4) -> tuple[np.ndarray, ImagePose, np.ndarray]:
    """Coverage image of a chain of table designs, its base pose and the angles drawn [rad].

    ``rotation_steps``: snap-fit step of each block (None: all 0).
    ``offsets`` [rad] are added to the designs' angles at ``voltage``; ``frame`` (pose, (rows, cols)) fixes
    the image, otherwise it is fitted around the chain (``framing``).
    """
    design_ids = np.asarray(design_ids)
    theta, _ = table.angle_at(design_ids, voltage)
    theta = np.asarray(theta, dtype=float) + (0.0 if offsets is None else np.asarray(offsets, dtype=float))
    length = np.asarray(table.rod_length)[table.index_of(design_ids)]
    steps = np.zeros(len(design_ids)) if rotation_steps is None else np.asarray(rotation_steps, dtype=float)
    phi = steps * (np.pi / 6.0)  # 30 degree snap-fit steps
    pose, shape = frame if frame is not None else framing(theta, length, phi, pixel_size, angle=angle, mirrored=mirrored)
    return render_silhouette(theta, length, phi, pose, pixel_size, shape, supersample=supersample), pose, theta


def to_binary(coverage: np.ndarray) -> np.ndarray:
    """uint8 silhouette (0 / 255): pixels at least half covered."""
    return np.where(coverage >= 0.5, 255, 0).astype(np.uint8)


def to_grey(coverage: np.ndarray) -> np.ndarray:
    """uint8 grey image, 255 = fully covered."""
    return np.round(np.clip(coverage, 0.0, 1.0) * 255).astype(np.uint8)


def blurred(coverage: np.ndarray, sigma_pixels: float) -> np.ndarray:
    """Gaussian blur of a coverage image (a defocused camera)."""
    return ndimage.gaussian_filter(np.asarray(coverage, dtype=float), sigma_pixels)


def with_pixel_noise(image: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """A binary uint8 image with ``fraction`` of its pixels flipped at random (salt and pepper)."""
    flip = rng.random(image.shape) < fraction
    return np.where(flip, 255 - image, image).astype(np.uint8)


def with_grey_noise(coverage: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """A uint8 grey image with Gaussian noise of ``sigma`` (in units of full coverage) added."""
    return to_grey(coverage + rng.normal(0.0, sigma, coverage.shape))


def occluded(image: np.ndarray, centre_pixels, radius_pixels: float) -> np.ndarray:
    """The image with a disc (column, row centre; radius in pixels) set to background."""
    rows, columns = np.indices(image.shape)
    hidden = (columns + 0.5 - centre_pixels[0]) ** 2 + (rows + 0.5 - centre_pixels[1]) ** 2 <= radius_pixels**2
    return np.where(hidden, 0, image).astype(image.dtype)
