"""A chain's frames as a transform tree (as TF holds them): each frame in the frame before it.

``planner.kinematics`` gives the base and block end frames of a chain in one common frame (the chain base's,
or the assembly's after ``ChainShape.transformed``); a transform tree stores each frame relative to its parent
instead, so that a viewer composes them back. Pure math, no ROS.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def link_transforms(rotations, positions) -> tuple[np.ndarray, np.ndarray]:
    """Frame k in frame k - 1, for k = 1..N, from N + 1 frames in a common frame.

    ``rotations`` (N + 1, 3, 3) and ``positions`` (N + 1, 3) [m], as ``ChainShape`` holds them (index 0 the
    base, index k the end of block k). Returns rotations (N, 3, 3) and translations (N, 3) [m].
    """
    rotations, positions = np.asarray(rotations, dtype=float), np.asarray(positions, dtype=float)
    parents = np.swapaxes(rotations[:-1], -1, -2)  # the inverse of each parent's rotation
    return parents @ rotations[1:], np.einsum("kij,kj->ki", parents, positions[1:] - positions[:-1])


def quaternions(rotations) -> np.ndarray:
    """(..., 4) unit quaternions (x, y, z, w), the order of geometry_msgs and of ``Chain.base_orientation``."""
    rotations = np.asarray(rotations, dtype=float)
    if rotations.shape[:-2] == (0,):
        return np.empty((0, 4))
    return Rotation.from_matrix(rotations).as_quat()
