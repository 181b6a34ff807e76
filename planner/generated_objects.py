"""Asymmetric test objects made from a seed: the union of a few random ellipses (object True), padded so
that it never touches the image border. Tests and benchmarks use them as objects the designer has not
seen; the pixel size they are meant for is ``PIXEL_SIZE``."""
from __future__ import annotations

import numpy as np

PIXEL_SIZE = 2.5e-4  # [m / pixel]


def lumpy_object(seed: int) -> np.ndarray:
    """(320, 200) bool mask of a lumpy object, different on its left and right."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[:320, :200]
    mask = np.zeros(rows.shape, dtype=bool)
    for _ in range(4):
        row, col = 110 + rng.uniform(-20, 60), 100 + rng.uniform(-25, 25)
        half_height, half_width = rng.uniform(35, 70), rng.uniform(20, 45)
        mask |= ((rows - row) / half_height) ** 2 + ((cols - col) / half_width) ** 2 < 1.0
    return mask
