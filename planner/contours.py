"""Object image -> left and right contours for the finger design (paper section 2.3.2).

A binary side view of the object (object bright, background dark) is cleaned (specks removed, holes
filled), its outline is traced, and the outline is split into a left and a right contour by cutting it at
its top-most and bottom-most points (the fingers close on the object horizontally, the grasp is vertical).

Object frame (used by every output here, in metres): origin at the top-centre of the object's bounding
box (the top edge of its top-most pixel row, halfway between its left-most and right-most pixel edges),
x to the right in the image, z up. So the object occupies z in [-height, 0] and x in [-width/2, width/2].
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import contourpy
import numpy as np
from scipy import ndimage
from softblock_config import config_file

from .bounded_yaml import load_yaml_file
from .image_file import open_image

OBJECTS_CATALOG = config_file("objects/objects.yaml")
DEFAULT_SPECK_FRACTION = 0.01
GREY_MODES = ("1", "L", "I", "I;16", "F")  # Pillow modes read as they are
# Tracing costs tens of bytes per pixel: 4 megapixels stay within a few hundred MB, and 2000 pixels
# across resolve 0.25 mm over half a metre, far finer than a finger samples its object (1 mm).
MAX_IMAGE_PIXELS = 4_000_000
MIN_OBJECT_PIXELS = 8  # an object must span this many pixels in height and width to have an outline
# Pixel sizes a finger design can use: coarser than 1 cm cannot show a 15 mm block's fit (and the design
# samples the contour every millimetre: 1e300 m per pixel asked for 1e305 samples); finer than 1 um makes
# the object smaller than anything a 25 mm block grasps (1e-300 m per pixel underflowed the outline).
PIXEL_SIZE_RANGE = (1e-6, 0.01)  # [m / pixel]


def load_mask(source, threshold: float | None = None) -> np.ndarray:
    """Boolean mask (rows, cols) of an object image; True = object.

    ``source``: path of an image Pillow reads (PNG, PGM, ...) or a 2D array. A binary image (two grey
    levels at most) needs no ``threshold``: the brighter level is the object. Any other image needs
    ``threshold``: pixels brighter than it are the object. Images above MAX_IMAGE_PIXELS are refused, for a
    file before its pixels are decoded (the size is in its header).
    """
    if isinstance(source, (str, Path)):
        with open_image(source, "object image") as image:
            _check_pixel_count(image.width, image.height, source)
            # single-channel modes keep their values (16-bit PGM included); colour becomes grey
            grey = np.asarray(image if image.mode in GREY_MODES else image.convert("L"))
    else:
        grey = np.asarray(source)
    if grey.ndim != 2 or grey.size == 0:
        raise ValueError(f"object image must be a non-empty 2D array, got shape {grey.shape}")
    _check_pixel_count(grey.shape[1], grey.shape[0], "object image")
    if grey.dtype == bool:
        return grey.copy()
    if threshold is not None:
        return grey > threshold
    low, high = grey.min(), grey.max()
    bright = grey == high
    if not np.all(bright | (grey == low)):  # a third level (counted only for the message)
        raise ValueError(
            f"object image is not binary ({np.unique(grey).size} grey levels); pass threshold= to binarise it"
        )
    return bright if high != 0 else np.zeros(grey.shape, dtype=bool)


def _check_pixel_count(width: int, height: int, name) -> None:
    if width * height > MAX_IMAGE_PIXELS:
        raise ValueError(f"{name} is {width} x {height} pixels, more than the {MAX_IMAGE_PIXELS / 1e6:g} "
                         "megapixels accepted; downscale it (and scale the pixel size with it)")


def clean_mask(mask, speck_fraction: float = DEFAULT_SPECK_FRACTION) -> np.ndarray:
    """The single object of ``mask`` with holes filled.

    Regions smaller than ``speck_fraction`` of the largest region are specks and dropped. ValueError
    for an empty mask, for several objects, for an object touching the image border, and for an object
    smaller than MIN_OBJECT_PIXELS in height or width (too few pixels for an outline).
    """
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 2:
        raise ValueError(f"mask must be 2D, got shape {mask.shape}")
    if not 0.0 <= speck_fraction < 1.0:
        raise ValueError(f"speck_fraction must lie in [0, 1), got {speck_fraction!r}")
    labels, count = ndimage.label(mask)
    if count == 0:
        raise ValueError("object image is empty: no object pixels")
    areas = np.bincount(labels.ravel())[1:]
    objects = np.flatnonzero(areas >= speck_fraction * areas.max()) + 1
    if objects.size > 1:
        raise ValueError(
            f"object image holds {objects.size} objects (areas {sorted(areas[objects - 1].tolist())} pixels); "
            "crop it to one object"
        )
    cleaned = _filled(labels == objects[0])
    height, width = (np.ptp(np.flatnonzero(cleaned.any(axis=axis))) + 1 for axis in (1, 0))
    if min(height, width) < MIN_OBJECT_PIXELS:
        raise ValueError(f"object is only {width} x {height} pixels; it needs at least {MIN_OBJECT_PIXELS} "
                         "in height and width for an outline (use a finer image)")
    if cleaned[0].any() or cleaned[-1].any() or cleaned[:, 0].any() or cleaned[:, -1].any():
        raise ValueError("object touches the image border; pad the image so the whole outline is visible")
    return cleaned


def _filled(region: np.ndarray) -> np.ndarray:
    """``region`` with its holes filled: every background component (4-connected, as
    ``scipy.ndimage.binary_fill_holes``) that does not reach the image border. One labelling pass, several
    times faster than the iterated dilation of ``binary_fill_holes`` on large images."""
    background, count = ndimage.label(~region)
    hole = np.ones(count + 1, dtype=bool)
    hole[0] = False  # the region itself
    hole[np.concatenate([background[0], background[-1], background[:, 0], background[:, -1]])] = False
    return region | hole[background]


@dataclass(frozen=True)
class ObjectContours:
    """Left and right contours of one object in the object frame (see the module docstring)."""

    left: np.ndarray  # (n, 2) x, z [m], top to bottom
    right: np.ndarray  # (m, 2) x, z [m], top to bottom
    top: np.ndarray  # (2,) the cut point at the top [m]
    bottom: np.ndarray  # (2,) the cut point at the bottom [m]
    mask: np.ndarray  # cleaned mask (rows, cols), True = object
    pixel_size: float  # [m / pixel]
    origin_pixel: tuple[float, float]  # (column, row) of the frame origin in pixel-edge coordinates

    @property
    def height(self) -> float:
        return float(self.top[1] - self.bottom[1])

    @property
    def width(self) -> float:
        columns = np.flatnonzero(self.mask.any(axis=0))
        return float((columns[-1] + 1 - columns[0]) * self.pixel_size)


def _extreme_index(outline: np.ndarray, top: bool) -> int:
    """Index of the top-most (or bottom-most) outline vertex; on a flat run, the one nearest its middle."""
    z = outline[:, 1]
    level = z.max() if top else z.min()
    candidates = np.flatnonzero(np.abs(z - level) < 1e-12)
    middle = 0.5 * (outline[candidates, 0].min() + outline[candidates, 0].max())
    return int(candidates[np.argmin(np.abs(outline[candidates, 0] - middle))])


def extract_contours(mask, pixel_size: float, speck_fraction: float = DEFAULT_SPECK_FRACTION) -> ObjectContours:
    """Clean ``mask`` (see ``clean_mask``), trace its outline and split it into left and right contours.

    ``pixel_size`` [m / pixel]. The outline runs along the pixel edges (iso-line 0.5 of the mask), so a
    straight side of k pixels is exactly k * pixel_size long. The top and bottom cut points are left out
    of both contours.
    """
    low, high = PIXEL_SIZE_RANGE
    if not (np.isfinite(pixel_size) and low <= pixel_size <= high):
        raise ValueError(f"pixel_size must be a positive number of m/pixel in {low:g}..{high:g}, got {pixel_size!r}")
    cleaned = clean_mask(mask, speck_fraction)
    lines = contourpy.contour_generator(z=cleaned.astype(float), line_type="Separate").lines(0.5)
    outline_pixels = max(lines, key=len)[:-1]  # closed loop; drop the repeated first vertex
    rows = np.flatnonzero(cleaned.any(axis=1))
    columns = np.flatnonzero(cleaned.any(axis=0))
    # contourpy puts pixel centres at integer (column, row); pixel edges are at half-integers.
    origin = (0.5 * (columns[0] + columns[-1] + 1), float(rows[0]))
    outline = np.column_stack(
        [(outline_pixels[:, 0] + 0.5 - origin[0]) * pixel_size, (origin[1] - outline_pixels[:, 1] - 0.5) * pixel_size]
    )
    top, bottom = _extreme_index(outline, top=True), _extreme_index(outline, top=False)
    loop = np.roll(outline, -top, axis=0)  # start at the top
    bottom = (bottom - top) % len(outline)
    forward = loop[1:bottom]
    backward = loop[:bottom:-1]
    left, right = (forward, backward) if forward[:, 0].mean() < backward[:, 0].mean() else (backward, forward)
    return ObjectContours(
        left=left,
        right=right,
        top=outline[top],
        bottom=loop[bottom],
        mask=cleaned,
        pixel_size=float(pixel_size),
        origin_pixel=origin,
    )


def load_catalog_object(name: str, catalog: str | Path = OBJECTS_CATALOG, threshold: float | None = None) -> ObjectContours:
    """Contours of an object listed in ``catalog`` (YAML: name -> {file, pixel_size_m})."""
    catalog = Path(catalog)
    entries = load_yaml_file(catalog)
    if not isinstance(entries, dict) or name not in entries:
        raise ValueError(f"object {name!r} is not in {catalog}; known: {sorted(entries) if isinstance(entries, dict) else []}")
    entry = entries[name]
    return extract_contours(load_mask(catalog.parent / entry["file"], threshold), float(entry["pixel_size_m"]))
