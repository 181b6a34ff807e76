"""The image frame and where the chain's base sits in it.

Image frame (metres): origin at the top-left corner of the image, x along the columns (to the right),
y along the rows (down); pixel (row i, column j) covers x in [j s, (j + 1) s] and y in [i s, (i + 1) s]
for a pixel size s. The side view looks perpendicular to the chain's x-z plane, so the chain's base
frame maps into the image by a rotation (and, seen from the other side, a mirror image):

    image point = position + x * bend_axis + z * growth_axis

growth_axis = (cos angle, sin angle) is the chain's +z (the direction it grows from its base);
bend_axis is the chain's +x (the side it bends to at phi = 0): growth_axis turned by +90 degrees
(from image +x toward image +y), or by -90 degrees when ``mirrored``. A camera looking along the
chain's +y axis sees it unmirrored.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ImagePose:
    """The chain base in the image: centre of the base face [m], growth direction [rad], mirror flag."""

    x: float  # [m] image frame
    y: float  # [m] image frame
    angle: float  # [rad] growth axis, from image +x toward image +y (pi/2: the chain grows downward)
    mirrored: bool = False

    def __post_init__(self) -> None:
        for name in ("x", "y", "angle"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) or not math.isfinite(value):
                raise ValueError(f"image pose {name} must be a finite number, got {value!r}")
        if not isinstance(self.mirrored, (bool, np.bool_)):
            raise ValueError(f"image pose mirrored must be True or False, got {self.mirrored!r}")

    @property
    def position(self) -> np.ndarray:
        return np.array([self.x, self.y], dtype=float)

    def axes(self, turn: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(bend_axis, growth_axis) unit vectors in the image frame, the base turned by ``turn`` [rad]."""
        angle = self.angle + turn
        growth = np.array([math.cos(angle), math.sin(angle)])
        side = -1.0 if self.mirrored else 1.0
        return side * np.array([-growth[1], growth[0]]), growth

    def to_image(self, points, shift=(0.0, 0.0), turn: float = 0.0) -> np.ndarray:
        """Chain-frame points (..., 2) = (x, z) [m] -> image frame (..., 2) [m].

        ``shift`` [m] and ``turn`` [rad] move the base (a correction found by the estimator).
        """
        bend, growth = self.axes(turn)
        points = np.asarray(points, dtype=float)
        return self.position + np.asarray(shift, dtype=float) + points[..., :1] * bend + points[..., 1:2] * growth

    def directions_to_image(self, vectors, turn: float = 0.0) -> np.ndarray:
        """Chain-frame directions (..., 2) -> image frame (the linear part of ``to_image``)."""
        bend, growth = self.axes(turn)
        vectors = np.asarray(vectors, dtype=float)
        return vectors[..., :1] * bend + vectors[..., 1:2] * growth

    def to_chain(self, points) -> np.ndarray:
        """Image-frame points (..., 2) [m] -> chain-frame (x, z) [m] (inverse of ``to_image``)."""
        bend, growth = self.axes()
        relative = np.asarray(points, dtype=float) - self.position
        return np.stack([relative @ bend, relative @ growth], axis=-1)

    def corrected(self, shift, turn: float) -> ImagePose:
        """The pose moved by ``shift`` [m] and turned by ``turn`` [rad]."""
        return ImagePose(self.x + float(shift[0]), self.y + float(shift[1]), self.angle + float(turn), self.mirrored)
