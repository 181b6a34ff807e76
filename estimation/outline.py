"""Forward model: the outline of a chain's side-view silhouette, sampled, from the planner's kinematics.

The body is a tube of radius r around the piecewise-constant-curvature centreline (caps included). Seen
from the side (orthographic projection onto the chain's x-z plane) each cross-section disc projects to
an ellipse whose half-width across the projected centreline is exactly r, so the silhouette is the band
of half-width r around the projected centreline, closed at the base and at the tip by the projected end
discs (segments for a planar chain, half ellipses for a chain leaving the plane). Samples, all in the
chain frame (x, z) [m], one pair per kinematics centreline sample:

    [+r side along the centreline | -r side | base face | tip face]

Planar chains (every phi 0 or pi) are sampled in closed form (``planar_centreline``: the samples of
``planner.kinematics.planar_chain``, cheaper for the estimator's many small batches); others by
``planner.kinematics.chain_shape``. The sampling depends on the block structure only, so one
``OutlineLayout`` serves every set of angles. A layout of blocks k.. of a chain, placed at block k's start
frame, gives those blocks' samples alone.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from planner.kinematics import BLOCK_RADIUS, CAP_LENGTH, chain_frames, chain_shape

HIDDEN_TOLERANCE = 0.02  # a side sample closer than (1 - this) r to another part of the centreline is hidden
UNCROSSABLE_BEND = math.radians(150.0)  # a planar chain bending less than this in all cannot reach itself


@dataclass(frozen=True)
class OutlineLayout:
    """How one block structure's outline is sampled, and which block each sample belongs to."""

    length: np.ndarray  # (N,) rod length of each block [m]
    phi: np.ndarray  # (N,) rotation about the local z axis [rad]
    planar: bool
    samples_per_block: int  # kinematics centreline samples per block
    face: np.ndarray  # (F,) position across an end face, -1..1
    block: np.ndarray  # (M,) block index of each outline sample, M = 2 P + 2 F
    fraction: np.ndarray  # (M,) how far along its block a sample lies, 0..1
    radius: float
    cap_length: float = CAP_LENGTH

    @property
    def blocks(self) -> int:
        return len(self.length)

    @property
    def centreline_samples(self) -> int:
        return 1 + self.blocks * self.samples_per_block

    @property
    def polylines(self) -> tuple[slice, ...]:
        """Slices of the outline samples: +r side, -r side, base face, tip face (each an open polyline)."""
        p, f = self.centreline_samples, len(self.face)
        return slice(0, p), slice(p, 2 * p), slice(2 * p, 2 * p + f), slice(2 * p + f, 2 * p + 2 * f)


def is_planar(phi) -> bool:
    turns = np.asarray(phi, dtype=float) / math.pi
    return bool(np.all(np.abs(turns - np.round(turns)) < 1e-9))


def outline_layout(length, phi, spacing: float, radius: float = BLOCK_RADIUS) -> OutlineLayout:
    """Sampling of a chain's outline with about ``spacing`` [m] between arc samples."""
    length = np.asarray(length, dtype=float)
    phi = np.asarray(phi, dtype=float)
    if length.ndim != 1 or length.size == 0 or phi.shape != length.shape:
        raise ValueError("length and phi need one value per block")
    if not spacing > 0:
        raise ValueError(f"spacing must be positive, got {spacing!r}")
    per_block = max(1, math.ceil(length.max() / spacing)) + 2
    index = np.arange(1 + len(length) * per_block)
    block = np.maximum(index - 1, 0) // per_block
    fraction = np.where(index == 0, 0.0, ((index - 1) % per_block + 1) / per_block)
    face_count = max(3, math.ceil(2 * radius / spacing) + 1)
    last = len(length) - 1
    return OutlineLayout(
        length=length,
        phi=phi,
        planar=is_planar(phi),
        samples_per_block=per_block,
        face=np.linspace(-1.0, 1.0, face_count),
        block=np.concatenate([block, block, np.zeros(face_count, int), np.full(face_count, last)]),
        fraction=np.concatenate([fraction, fraction, np.zeros(face_count), np.ones(face_count)]),
        radius=float(radius),
    )


def start_frame(theta, length, phi, block: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and position (3,) of the start of ``block`` (before its own phi turn) in the base frame."""
    if block == 0:
        return np.eye(3), np.zeros(3)
    rotations, positions = chain_frames(theta[:block], length[:block], phi[:block])
    return rotations[-1], positions[-1]


def centreline(layout: OutlineLayout, theta) -> tuple[np.ndarray, np.ndarray]:
    """Centreline samples (..., P, 3) [m] and unit tangents (..., P, 3) in the chain's base frame."""
    theta = np.asarray(theta, dtype=float)
    if layout.planar:
        flat, heading = planar_centreline(layout, theta)
        points = np.stack([flat[..., 0], np.zeros_like(heading), flat[..., 1]], axis=-1)
        tangent = np.stack([np.sin(heading), np.zeros_like(heading), np.cos(heading)], axis=-1)
        return points, tangent
    shape = chain_shape(theta, layout.length, layout.phi, samples_per_block=layout.samples_per_block,
                        cap_length=layout.cap_length)
    return shape.points, shape.sample_rotations()[..., :, 2]


@dataclass(frozen=True)
class _PlanarSteps:
    """The steps between consecutive centreline samples of a planar layout (the same as
    ``planner.kinematics.planar_chain`` samples): each runs along its block's arc from fraction ``begin`` to
    ``end`` (a cap: begin = end, 0 or 1, plus the cap's straight length)."""

    block: np.ndarray  # (P - 1,) block of each step
    begin: np.ndarray  # (P - 1,) arc fraction at the step's start
    end: np.ndarray  # (P - 1,) arc fraction at its end
    straight: np.ndarray  # (P - 1,) straight length added [m] (caps)
    side: np.ndarray  # (N,) bending side of each block in the base frame (+1: toward +x)


def _planar_steps(layout: OutlineLayout) -> _PlanarSteps:
    flips = tuple(int(turns) % 2 for turns in np.round(layout.phi / np.pi))
    return _steps_of(layout.samples_per_block, float(layout.cap_length), flips)


@functools.lru_cache(maxsize=256)
def _steps_of(per_block: int, cap_length: float, flips: tuple[int, ...]) -> _PlanarSteps:
    arc = per_block - 2
    begin = np.concatenate([[0.0], np.arange(arc) / arc, [1.0]])
    end = np.concatenate([[0.0], np.arange(1, arc + 1) / arc, [1.0]])
    straight = np.zeros(per_block)
    straight[[0, -1]] = cap_length
    blocks = len(flips)
    return _PlanarSteps(
        block=np.repeat(np.arange(blocks), per_block), begin=np.tile(begin, blocks), end=np.tile(end, blocks),
        straight=np.tile(straight, blocks), side=np.cumprod(np.where(np.array(flips) == 0, 1.0, -1.0)),
    )


def planar_centreline(layout: OutlineLayout, theta) -> tuple[np.ndarray, np.ndarray]:
    """Planar chain (every phi 0 or pi): centreline samples (..., P, 2) = (x, z) [m] and headings (..., P)
    [rad, from +z toward +x], in closed form: each step between samples is a cap (straight) or a piece of
    arc, whose chord is its length x sin(a) / a along the mean heading (a: half its turn)."""
    steps = _planar_steps(layout)
    signed = np.asarray(theta, dtype=float) * steps.side
    start = np.cumsum(signed, axis=-1) - signed  # heading at each block's start
    bend = signed[..., steps.block]
    begin = start[..., steps.block] + bend * steps.begin
    turn = bend * (steps.end - steps.begin)
    length = steps.straight + layout.length[steps.block] * (steps.end - steps.begin)
    chord = length * np.sinc(turn / (2.0 * np.pi))  # numpy's sinc(x) = sin(pi x) / (pi x)
    middle = begin + 0.5 * turn
    shape = signed.shape[:-1] + (layout.centreline_samples,)
    points = np.zeros(shape + (2,))
    np.cumsum(chord * np.sin(middle), axis=-1, out=points[..., 1:, 0])
    np.cumsum(chord * np.cos(middle), axis=-1, out=points[..., 1:, 1])
    heading = np.zeros(shape)
    heading[..., 1:] = begin + turn
    return points, heading


def outline_from_centreline(layout: OutlineLayout, points: np.ndarray, tangent: np.ndarray, frame=None,
                            normals: bool = False):
    """Outline samples (..., M, 2) [m] from centreline samples and tangents (..., P, 3), optionally first
    moved by ``frame`` = (rotation (3, 3), position (3,)) (blocks placed at their start frame). With
    ``normals``, also the outward unit normal of each sample (faces: along the end tangent)."""
    if frame is not None:
        rotation, position = frame
        points = points @ rotation.T + position
        tangent = tangent @ rotation.T
    points = points[..., [0, 2]]  # orthographic projection onto the x-z plane
    in_plane = np.maximum(np.hypot(tangent[..., 0], tangent[..., 2]), 1e-9)[..., None]
    across = np.stack([tangent[..., 2], -tangent[..., 0]], axis=-1) / in_plane  # half-width direction
    along = np.stack([tangent[..., 0], tangent[..., 2]], axis=-1) / in_plane  # projected tangent
    tilt = np.abs(tangent[..., 1:2])  # how far an end disc faces the camera (0 in a planar chain)
    r, s = layout.radius, layout.face[:, None]
    bulge = np.sqrt(1.0 - s**2)

    def face(i: int, outward: float) -> np.ndarray:
        end = [i]
        return points[..., end, :] + r * s * across[..., end, :] + outward * r * tilt[..., end, :] * bulge * along[..., end, :]

    outline = np.concatenate([points + r * across, points - r * across, face(0, -1.0), face(-1, 1.0)], axis=-2)
    if not normals:
        return outline
    count = len(layout.face)
    ends = [np.repeat(-along[..., :1, :], count, axis=-2), np.repeat(along[..., -1:, :], count, axis=-2)]
    return outline, np.concatenate([across, -across] + ends, axis=-2)


def planar_outline(layout: OutlineLayout, theta, normals: bool = False):
    """``outline_from_centreline`` for a planar layout, straight from the planar centreline (the end faces
    are segments across the end tangent)."""
    points, heading = planar_centreline(layout, theta)
    cos, sin = np.cos(heading), np.sin(heading)
    across = np.stack([cos, -sin], axis=-1)  # the half-width direction, the tangent (sin, cos) turned
    r, s = layout.radius, layout.face[:, None]
    ends = [points[..., end, None, :] + r * s * across[..., end, None, :] for end in (0, -1)]
    outline = np.concatenate([points + r * across, points - r * across, *ends], axis=-2)
    if not normals:
        return outline
    count = len(layout.face)
    along = np.stack([sin, cos], axis=-1)
    faces = [np.repeat(-along[..., :1, :], count, axis=-2), np.repeat(along[..., -1:, :], count, axis=-2)]
    return outline, np.concatenate([across, -across] + faces, axis=-2)


def outline_points(layout: OutlineLayout, theta, frame=None, normals: bool = False):
    """Outline samples (..., M, 2) [m] in the chain frame for bending angles ``theta`` (..., N) [rad]
    (``frame``, ``normals``: see ``outline_from_centreline``)."""
    if layout.planar and frame is None:
        return planar_outline(layout, theta, normals)
    return outline_from_centreline(layout, *centreline(layout, theta), frame, normals)


def visible(layout: OutlineLayout, theta) -> np.ndarray:
    """(M,) False for outline samples inside another part of the body's side view (a chain touching or,
    out of plane, crossing itself). An end face is judged against the centreline farther than one body
    diameter along the chain from its own end."""
    if layout.planar and np.sum(np.abs(theta)) <= UNCROSSABLE_BEND:
        return np.ones(len(layout.block), dtype=bool)
    points, tangent = centreline(layout, theta)
    outline = outline_from_centreline(layout, points, tangent)
    flat = points[..., [0, 2]]
    limit = (1.0 - HIDDEN_TOLERANCE) * layout.radius
    p, f = layout.centreline_samples, len(layout.face)
    shown = np.ones(len(layout.block), dtype=bool)
    distance, _ = cKDTree(flat).query(outline[: 2 * p])
    shown[: 2 * p] = distance >= limit
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    for face, far in ((slice(2 * p, 2 * p + f), along > 2 * layout.radius), (slice(2 * p + f, None), along < along[-1] - 2 * layout.radius)):
        if far.any():
            distance, _ = cKDTree(flat[far]).query(outline[face])
            shown[face] = distance >= limit
    return shown
