"""Observed silhouette: a bounded image -> cleaned mask, outline in the image frame, signed distances.

The mask comes from the planner's object-image code (``planner.contours``: threshold, specks removed,
errors for an empty image, several objects or an object touching the border). The outline is the
iso-line of the image at the threshold (contourpy), so a blurred grey image gives sub-pixel edges; every
loop that is not a speck is kept, including the background a chain encloses when it touches itself.
Distances to the outline are point-to-line distances to the nearest outline vertex (scipy's KD-tree),
positive outside the object.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import contourpy
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from estimation.view import ImagePose
from planner.contours import DEFAULT_SPECK_FRACTION, GREY_MODES, clean_mask, load_mask
from planner.image_file import open_image

MAX_IMAGE_PIXELS = 25_000_000  # 5000 x 5000: far beyond any useful side view; bounds memory and time
MIN_IMAGE_SIDE = 8
COARSE_CELLS = 40_000  # the coarse distance map has at most about this many cells
BINARY_SMOOTHING = 0.7  # [pixels] Gaussian blur before tracing a binary mask: sub-pixel edges from the staircase
CROP_MARGIN = 4  # [pixels] kept around the objects' bounding box
COARSE_MARGIN = 4  # [cells] of the coarse distance map around the crop
OCCLUSION_MARGIN = 2  # [pixels] image outline this close to an occluder is its edge, not the chain's


def read_image(source) -> np.ndarray:
    """A 2D grey array from a path (PNG, PGM, ... via Pillow) or an array, size checked before decoding."""
    if isinstance(source, (str, Path)):
        with open_image(source) as image:
            _check_size(image.size[::-1], f"image {source}")
            grey = np.asarray(image if image.mode in GREY_MODES else image.convert("L"))
    else:
        grey = np.asarray(source)
        if grey.ndim != 2:
            raise ValueError(f"image must be a 2D (grey) array, got shape {grey.shape}")
        _check_size(grey.shape, "image")
    if grey.dtype != bool and not np.issubdtype(grey.dtype, np.number):
        raise ValueError(f"image must hold numbers, got dtype {grey.dtype}")
    if not np.all(np.isfinite(grey)):
        raise ValueError("image holds non-finite values")
    return grey


def _check_size(shape, what: str) -> None:
    rows, columns = shape
    if rows * columns > MAX_IMAGE_PIXELS:
        raise ValueError(f"{what} has {rows} x {columns} pixels, more than the limit of {MAX_IMAGE_PIXELS}")
    if min(rows, columns) < MIN_IMAGE_SIDE:
        raise ValueError(f"{what} is {rows} x {columns} pixels; a side view needs at least {MIN_IMAGE_SIDE} per side")


def _loop_area(loop: np.ndarray) -> float:
    x, y = loop[:, 0], loop[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


@dataclass(frozen=True)
class Silhouette:
    """The observed chain: cleaned mask and its outline in the image frame (see ``estimation.view``)."""

    mask: np.ndarray  # (rows, cols) bool, the single object, holes filled
    pixel_size: float  # [m / pixel]
    outline: np.ndarray  # (K, 2) outline vertices [m]
    normals: np.ndarray  # (K, 2) unit normals pointing out of the object
    lengths: np.ndarray  # (K,) outline length each vertex stands for [m]
    tree: cKDTree
    coarse: np.ndarray  # signed distance map [m] on cells of coarse_factor x coarse_factor pixels
    coarse_factor: int
    coarse_origin: np.ndarray  # (2,) image point [m] of the coarse map's first cell's corner
    occlusion: np.ndarray | None = None  # (rows, cols) bool: pixels where something may hide the chain
    outline_occluded: np.ndarray | None = None  # (K,) outline vertices at the edge of the occlusion

    @property
    def shape(self) -> tuple[int, int]:
        return self.mask.shape

    def signed_distance(self, points, limit: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Distance [m] of image points (..., 2) from the outline, positive outside, and the outline normal
        used. Points farther than ``limit`` [m] from every outline vertex get ``limit`` and a zero normal
        (a bounded search is much faster for far points)."""
        points = np.asarray(points, dtype=float)
        flat = points.reshape(-1, 2)
        gap, nearest = self.tree.query(flat, distance_upper_bound=limit)
        near = np.isfinite(gap)
        normals = np.zeros_like(flat)
        normals[near] = self.normals[nearest[near]]
        distance = np.full(len(flat), float(limit))
        distance[near] = np.sum((flat[near] - self.outline[nearest[near]]) * normals[near], axis=1)
        return distance.reshape(points.shape[:-1]), normals.reshape(points.shape)

    def coarse_distance(self, points) -> np.ndarray:
        """Signed distance [m] of image points (..., 2) from the coarse map: fast, accurate to about a cell."""
        points = np.asarray(points, dtype=float)
        cell = self.coarse_factor * self.pixel_size
        index = (points.reshape(-1, 2) - self.coarse_origin)[:, ::-1].T / cell - 0.5  # (row, column), cell centres at integers
        return ndimage.map_coordinates(self.coarse, index, order=1, mode="nearest").reshape(points.shape[:-1])

    def inside(self, points) -> np.ndarray:
        """Which image points (..., 2) [m] fall on an object pixel of the cleaned mask."""
        return _lookup(self.mask, points, self.pixel_size)

    def occluded(self, points) -> np.ndarray:
        """Which image points (..., 2) [m] fall where the chain may be hidden (False without an occlusion)."""
        points = np.asarray(points, dtype=float)
        if self.occlusion is None:
            return np.zeros(points.shape[:-1], dtype=bool)
        return _lookup(self.occlusion, points, self.pixel_size)


def _lookup(mask: np.ndarray, points, pixel_size: float) -> np.ndarray:
    points = np.asarray(points, dtype=float)
    column = np.floor(points[..., 0] / pixel_size).astype(int)
    row = np.floor(points[..., 1] / pixel_size).astype(int)
    rows, columns = mask.shape
    within = (column >= 0) & (column < columns) & (row >= 0) & (row < rows)
    result = np.zeros(points.shape[:-1], dtype=bool)
    result[within] = mask[row[within], column[within]]
    return result


def silhouette_from_image(image, pixel_size: float, threshold: float | None = None,
                          speck_fraction: float = DEFAULT_SPECK_FRACTION, occlusion=None) -> Silhouette:
    """The silhouette of one chain in ``image`` (path or 2D array; object brighter than background).

    A binary image needs no ``threshold``; a grey one does (pixels brighter than it are the chain).
    ``occlusion``: optional boolean array of the image's shape, True where something in front may hide
    the chain (the estimator then ignores model outline there and image outline along its edge).
    ValueError naming the problem for an unreadable, oversized, empty or non-binary image without
    threshold, several objects, or an object touching the image border.
    """
    if isinstance(pixel_size, bool) or not (isinstance(pixel_size, (int, float)) and np.isfinite(pixel_size) and pixel_size > 0):
        raise ValueError(f"pixel_size must be a positive number of m/pixel, got {pixel_size!r}")
    grey = read_image(image)
    raw = load_mask(grey, threshold)
    if occlusion is not None:
        occlusion = np.asarray(occlusion, dtype=bool)
        if occlusion.shape != grey.shape:
            raise ValueError(f"occlusion mask has shape {occlusion.shape}, the image {grey.shape}")
    # Work on the objects' bounding box and a margin (clean_mask's checks come out the same: whatever
    # touches the image border still touches the crop's); coordinates are shifted back at the end.
    rows, columns = np.flatnonzero(raw.any(axis=1)), np.flatnonzero(raw.any(axis=0))
    if rows.size == 0:
        clean_mask(raw, speck_fraction)  # raises: empty image
    top, left = max(rows[0] - CROP_MARGIN, 0), max(columns[0] - CROP_MARGIN, 0)
    crop = (slice(top, rows[-1] + CROP_MARGIN + 1), slice(left, columns[-1] + CROP_MARGIN + 1))
    mask = np.zeros(raw.shape, dtype=bool)
    mask[crop] = clean_mask(raw[crop], speck_fraction)
    if threshold is None or grey.dtype == bool:
        field, level = ndimage.gaussian_filter(raw[crop].astype(float), BINARY_SMOOTHING), 0.5
    else:
        field, level = grey[crop].astype(float), float(threshold)
    loops = [loop[:-1] for loop in contourpy.contour_generator(z=field, line_type="Separate").lines(level) if len(loop) > 3]
    areas = np.array([_loop_area(loop) for loop in loops])
    keep = [loop for loop, area in zip(loops, areas) if area >= speck_fraction * areas.max()]
    outline, normals, lengths = [], [], []
    for loop in keep:
        tangent = np.roll(loop, -1, axis=0) - np.roll(loop, 1, axis=0)  # central differences on the closed loop
        size = np.linalg.norm(tangent, axis=1)
        outline.append((loop + [left + 0.5, top + 0.5]) * pixel_size)  # contourpy puts pixel centres at integers
        normals.append(np.column_stack([tangent[:, 1], -tangent[:, 0]]) / np.maximum(size, 1e-12)[:, None])
        lengths.append(0.5 * size * pixel_size)
    outline = np.concatenate(outline)
    factor, coarse, origin = _coarse_distance_map(raw, crop, pixel_size)
    outline_occluded = None
    if occlusion is not None:
        near = ndimage.binary_dilation(occlusion, iterations=OCCLUSION_MARGIN)  # the occluder's edge is no outline
        outline_occluded = _lookup(near, outline, pixel_size)
    return Silhouette(
        mask=mask,
        pixel_size=float(pixel_size),
        outline=outline,
        normals=np.concatenate(normals),
        lengths=np.concatenate(lengths),
        tree=cKDTree(outline),
        coarse=coarse,
        coarse_factor=factor,
        coarse_origin=origin,
        occlusion=occlusion,
        outline_occluded=outline_occluded,
    )


def _coarse_distance_map(mask: np.ndarray, crop: tuple[slice, slice], pixel_size: float) -> tuple[int, np.ndarray, np.ndarray]:
    """Signed Euclidean distance map [m] (positive outside) of the mask on coarse cells (scipy.ndimage), over
    the crop and COARSE_MARGIN cells around it (model outline farther out costs the same as there: its
    residual saturates a few pixels outside), and the image point [m] of its corner."""
    rows, columns = mask.shape
    size = (min(crop[0].stop, rows) - crop[0].start) * (min(crop[1].stop, columns) - crop[1].start)
    factor = max(2, math.ceil(math.sqrt(size / COARSE_CELLS)))
    margin = COARSE_MARGIN * factor
    top, left = max(crop[0].start - margin, 0), max(crop[1].start - margin, 0)
    window = mask[top : min(crop[0].stop + margin, rows), left : min(crop[1].stop + margin, columns)]
    padded = np.zeros((-(-window.shape[0] // factor) * factor, -(-window.shape[1] // factor) * factor))
    padded[: window.shape[0], : window.shape[1]] = window
    cells = padded.reshape(padded.shape[0] // factor, factor, padded.shape[1] // factor, factor).mean(axis=(1, 3)) >= 0.5
    outside = ndimage.distance_transform_edt(~cells) - 0.5
    inside = ndimage.distance_transform_edt(cells) - 0.5
    distance = (np.where(cells, -inside, outside) * factor * pixel_size).astype(np.float32)
    return factor, distance, np.array([left, top], dtype=float) * pixel_size


def check_base(silhouette: Silhouette, pose: ImagePose, radius: float, cap_length: float) -> None:
    """ValueError unless the silhouette starts at the base: the base face on its outline, the first cap inside."""
    rows, columns = silhouette.shape
    width, height = columns * silhouette.pixel_size, rows * silhouette.pixel_size
    if not (0.0 <= pose.x <= width and 0.0 <= pose.y <= height):
        raise ValueError(
            f"the base position ({pose.x:.4g}, {pose.y:.4g}) m lies outside the image ({width:.4g} x {height:.4g} m)"
        )
    across = np.linspace(-0.8, 0.8, 9) * radius
    face = pose.to_image(np.column_stack([across, np.zeros_like(across)]))
    distance = np.abs(silhouette.signed_distance(face)[0])
    ahead = pose.to_image(np.column_stack([0.6 * across, np.full_like(across, 0.5 * cap_length)]))
    covered = silhouette.inside(ahead).mean()
    tolerance = max(4.0 * silhouette.pixel_size, 0.25 * radius)
    if covered < 0.8 or np.median(distance) > tolerance:
        raise ValueError(
            "the chain does not start at the given base: "
            f"{100 * covered:.0f} % of the first cap is inside the silhouette and the base face lies "
            f"{1e3 * np.median(distance):.1f} mm from its outline (tolerance {1e3 * tolerance:.1f} mm); "
            "check the base position, angle and mirrored flag"
        )
