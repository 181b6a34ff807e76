"""Piecewise-constant-curvature kinematics of chains of building blocks (paper section 2.2.2).

Each block is a straight linking cap (``CAP_LENGTH``), a circular arc of length L and angle theta (the
bent NiTi rods), and a second straight cap. Block i is turned by phi_i about its local z axis relative to
block i-1 (the snap-fit index times 30 degrees). Convention (as in ``Chain.msg``): a chain grows along its
base frame's +z and, at phi = 0 and theta > 0, bends toward +x; the planar model lives in the x-z plane.

All functions are vectorised: ``theta``, ``length`` and ``phi`` broadcast to a common shape ``(..., N)``
(N blocks, base first, any batch dimensions in front), so thousands of candidate designs are evaluated at
once. theta -> 0 is exact (sinc form, no division by theta).

Two paths:
- ``planar_chain`` for phi in {0, pi}: headings add up with ``cumsum``; no loop over blocks.
- ``chain_shape`` for any phi: rotation/translation composed block by block, vectorised over the batch.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from planner.geometry import PAPER_GEOMETRY

CAP_LENGTH = PAPER_GEOMETRY.cap_length  # length of one linking cap [m]
BLOCK_RADIUS = PAPER_GEOMETRY.radius  # outer radius of a block [m]
DEFAULT_SAMPLES_PER_BLOCK = 10


def _broadcast_blocks(theta, length, phi) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    arrays = [np.asarray(a, dtype=float) for a in (theta, length, phi)]
    for name, array in zip(("theta", "length", "phi"), arrays):
        if not np.all(np.isfinite(array)):
            raise ValueError(f"{name} must be finite")
    try:
        theta, length, phi = np.broadcast_arrays(*arrays)
    except ValueError:
        shapes = ", ".join(f"{n}{a.shape}" for n, a in zip(("theta", "length", "phi"), arrays))
        raise ValueError(f"theta, length and phi do not broadcast: {shapes}") from None
    if theta.ndim == 0:
        raise ValueError("theta, length and phi are all scalars; give at least one a last axis of blocks")
    if theta.shape[-1] == 0:
        raise ValueError("a chain needs at least one block (the blocks axis is empty)")
    if np.any(length <= 0.0):
        raise ValueError("length (rod length L) must be positive [m]")
    return theta, length, phi


def _check_samples(samples_per_block: int) -> int:
    if not isinstance(samples_per_block, (int, np.integer)) or samples_per_block < 3:
        raise ValueError(f"samples_per_block must be an integer >= 3, got {samples_per_block!r}")
    return int(samples_per_block)


def _local_samples(theta: np.ndarray, length: np.ndarray, samples_per_block: int, cap_length: float):
    """Centerline samples of each block in its own start frame (after the phi turn).

    Per block: end of the first cap, ``samples_per_block - 2`` equal steps along the arc (last = arc end),
    end of the second cap. Returns x, z of shape (..., N, S) and the bend angle reached at each sample.
    """
    steps = samples_per_block - 2
    fraction = np.concatenate(([0.0], np.arange(1, steps + 1) / steps, [1.0]))
    angle = theta[..., None] * fraction  # bend angle reached at each sample
    arc = length[..., None] * fraction
    # Arc from the tangent +z bending toward +x: x = s (1 - cos a) / a, z = s sin(a) / a, in sinc form.
    x = arc * (angle / 2.0) * np.sinc(angle / (2.0 * np.pi)) ** 2
    z = cap_length + arc * np.sinc(angle / np.pi)
    x[..., -1] += cap_length * np.sin(theta)  # the second cap continues along the end tangent
    z[..., -1] += cap_length * np.cos(theta)
    return x, z, angle


def block_end_offsets(theta, length, cap_length: float = CAP_LENGTH) -> tuple[np.ndarray, np.ndarray]:
    """End point (x, z) of single blocks in their start frame: cap + arc + cap, any shape."""
    theta = np.asarray(theta, dtype=float)
    length = np.asarray(length, dtype=float)
    x = length * (theta / 2.0) * np.sinc(theta / (2.0 * np.pi)) ** 2 + cap_length * np.sin(theta)
    z = cap_length + length * np.sinc(theta / np.pi) + cap_length * np.cos(theta)
    return x, z


# --------------------------------------------------------------------------------------------- planar
@dataclass(frozen=True)
class PlanarShape:
    """A chain in the x-z plane. Batch dimensions ``...`` as given; N blocks; P = 1 + N * S samples.

    points[..., 0, :] is the base (origin); block i (0-based) owns samples 1 + i*S ... (i+1)*S, the last
    of which is its end. ``headings`` is the tangent angle from +z toward +x [rad].
    """

    points: np.ndarray  # (..., P, 2) centerline x, z [m]
    headings: np.ndarray  # (..., P) [rad]
    ends: np.ndarray  # (..., N + 1, 2) base and block end points [m]
    end_headings: np.ndarray  # (..., N + 1) [rad]
    theta: np.ndarray  # (..., N) bending angle used [rad], sign as given
    length: np.ndarray  # (..., N) rod length L [m]
    phi: np.ndarray  # (..., N) rotation about local z, 0 or pi [rad]
    samples_per_block: int

    @property
    def normals(self) -> np.ndarray:
        """(..., P, 2) unit normals: the tangent turned toward +x (the bending side at phi = 0)."""
        return np.stack([np.cos(self.headings), -np.sin(self.headings)], axis=-1)

    def periphery(self, radius: float = BLOCK_RADIUS) -> tuple[np.ndarray, np.ndarray]:
        """The two radial points of each centerline sample on the body surface.

        Returns (plus, minus), each (..., P, 2): ``points + radius * normals`` and
        ``points - radius * normals``; centerline sample and both radial points are collinear.
        """
        offset = radius * self.normals
        return self.points + offset, self.points - offset

    def to_3d(self) -> np.ndarray:
        """(..., P, 3) centerline with y = 0."""
        x, z = self.points[..., 0], self.points[..., 1]
        return np.stack([x, np.zeros_like(x), z], axis=-1)


def planar_chain(
    theta,
    length,
    phi=0.0,
    *,
    samples_per_block: int = DEFAULT_SAMPLES_PER_BLOCK,
    cap_length: float = CAP_LENGTH,
) -> PlanarShape:
    """Planar (x-z) shape of chains whose rotations are all 0 or pi.

    theta [rad], length [m], phi [rad] broadcast to (..., N). phi = pi flips the bending side relative to
    the previous block (the worm of Figure 2D). ValueError for any other phi (use ``chain_shape``).
    """
    theta, length, phi = _broadcast_blocks(theta, length, phi)
    samples_per_block = _check_samples(samples_per_block)
    turns = phi / np.pi
    if np.any(np.abs(turns - np.round(turns)) > 1e-9):
        raise ValueError("phi must be 0 or pi (mod 2 pi) for the planar model; use chain_shape for 3D")
    side = np.cumprod(np.where(np.round(turns) % 2 == 0, 1.0, -1.0), axis=-1)
    signed = side * theta

    end_headings = np.concatenate([np.zeros_like(signed[..., :1]), np.cumsum(signed, axis=-1)], axis=-1)
    start = end_headings[..., :-1, None]  # heading at each block start, (..., N, 1)
    x, z, angle = _local_samples(signed, length, samples_per_block, cap_length)
    cos, sin = np.cos(start), np.sin(start)
    dx = x * cos + z * sin  # rotate the local samples by the start heading about +y
    dz = -x * sin + z * cos
    block_start = np.cumsum(np.stack([dx[..., -1], dz[..., -1]], axis=-1), axis=-2)
    origin = np.zeros_like(block_start[..., :1, :])
    ends = np.concatenate([origin, block_start], axis=-2)
    samples = ends[..., :-1, None, :] + np.stack([dx, dz], axis=-1)  # (..., N, S, 2)

    batch = samples.shape[:-3]
    points = np.concatenate([origin, samples.reshape(*batch, -1, 2)], axis=-2)
    sample_headings = (start + angle).reshape(*batch, -1)
    headings = np.concatenate([np.zeros_like(sample_headings[..., :1]), sample_headings], axis=-1)
    return PlanarShape(
        points=points,
        headings=headings,
        ends=ends,
        end_headings=end_headings,
        theta=theta,
        length=length,
        phi=phi,
        samples_per_block=samples_per_block,
    )


# ------------------------------------------------------------------------------------------------- 3D
def _rot_z(phi: np.ndarray) -> np.ndarray:
    c, s = np.cos(phi), np.sin(phi)
    zero, one = np.zeros_like(phi), np.ones_like(phi)
    return np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)


def _rot_y(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    zero, one = np.zeros_like(angle), np.ones_like(angle)
    return np.stack([np.stack([c, zero, s], -1), np.stack([zero, one, zero], -1), np.stack([-s, zero, c], -1)], -2)


def block_transforms(theta, length, phi, cap_length: float = CAP_LENGTH) -> np.ndarray:
    """(..., N, 4, 4) homogeneous transform of each block: end frame in the previous block's end frame.

    T_i = Rz(phi_i) . Trans(cap) . Arc(theta_i, L_i) . Trans(cap), Arc = bend by theta about +y.
    """
    theta, length, phi = _broadcast_blocks(theta, length, phi)
    x, z = block_end_offsets(theta, length, cap_length)
    transform = np.zeros(theta.shape + (4, 4))
    turn = _rot_z(phi)
    transform[..., :3, :3] = turn @ _rot_y(theta)
    transform[..., :3, 3] = turn[..., :, 0] * x[..., None] + turn[..., :, 2] * z[..., None]
    transform[..., 3, 3] = 1.0
    return transform


def _compose(local_rotation: np.ndarray, local_position: np.ndarray):
    """Chain local (R, p) of shape (..., N, 3, 3)/(..., N, 3) into base-frame frames (..., N + 1, ...)."""
    n = local_rotation.shape[-3]
    rotations = np.empty(local_rotation.shape[:-3] + (n + 1, 3, 3))
    positions = np.empty(local_position.shape[:-2] + (n + 1, 3))
    rotations[..., 0, :, :] = np.eye(3)
    positions[..., 0, :] = 0.0
    for i in range(n):
        previous = rotations[..., i, :, :]
        rotations[..., i + 1, :, :] = previous @ local_rotation[..., i, :, :]
        positions[..., i + 1, :] = positions[..., i, :] + (previous @ local_position[..., i, :, None])[..., 0]
    return rotations, positions


@dataclass(frozen=True)
class ChainShape:
    """A chain in 3D. Batch dimensions ``...``; N blocks; P = 1 + N * S centerline samples.

    ``rotations``/``positions`` are the frames at the base (index 0) and at each block end, expressed in
    the frame the shape was computed in (chain base, or the assembly frame after ``transformed``).
    points[..., 0, :] is the base; block i (0-based) owns samples 1 + i*S ... (i+1)*S.
    """

    points: np.ndarray  # (..., P, 3) centerline [m]
    rotations: np.ndarray  # (..., N + 1, 3, 3)
    positions: np.ndarray  # (..., N + 1, 3) [m]
    theta: np.ndarray  # (..., N) bending angle used [rad]
    length: np.ndarray  # (..., N) rod length L [m]
    phi: np.ndarray  # (..., N) rotation about the local z axis [rad]
    valid: np.ndarray  # (..., N) False where the angle came from beyond the block's safe voltage
    samples_per_block: int

    @property
    def frames(self) -> np.ndarray:
        """(..., N + 1, 4, 4) homogeneous base and block end frames."""
        frames = np.zeros(self.rotations.shape[:-2] + (4, 4))
        frames[..., :3, :3] = self.rotations
        frames[..., :3, 3] = self.positions
        frames[..., 3, 3] = 1.0
        return frames

    def sample_rotations(self) -> np.ndarray:
        """(..., P, 3, 3) frame orientation at each centerline sample (z = tangent)."""
        steps = self.samples_per_block - 2
        fraction = np.concatenate(([0.0], np.arange(1, steps + 1) / steps, [1.0]))
        start = self.rotations[..., :-1, :, :] @ _rot_z(self.phi)  # block start frames (..., N, 3, 3)
        local = _rot_y(self.theta[..., None] * fraction)  # (..., N, S, 3, 3)
        per_sample = start[..., None, :, :] @ local
        batch = per_sample.shape[:-4]
        flat = per_sample.reshape(*batch, -1, 3, 3)
        return np.concatenate([start[..., :1, :, :], flat], axis=-3)

    def tube(self, radius: float = BLOCK_RADIUS, around: int = 16) -> np.ndarray:
        """(..., P, around, 3) points on the body surface: a circle of ``radius`` around each sample."""
        if around < 3:
            raise ValueError(f"around must be >= 3, got {around!r}")
        angle = np.linspace(0.0, 2.0 * np.pi, around, endpoint=False)
        circle = radius * np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=-1)
        return self.points[..., None, :] + np.einsum("...ij,kj->...ki", self.sample_rotations(), circle)

    def transformed(self, rotation: np.ndarray, translation) -> ChainShape:
        """The same shape expressed in a parent frame: x_parent = rotation @ x + translation."""
        rotation = np.asarray(rotation, dtype=float)
        translation = np.asarray(translation, dtype=float)
        return ChainShape(
            points=self.points @ rotation.T + translation,
            rotations=rotation @ self.rotations,
            positions=self.positions @ rotation.T + translation,
            theta=self.theta,
            length=self.length,
            phi=self.phi,
            valid=self.valid,
            samples_per_block=self.samples_per_block,
        )


def chain_shape(
    theta,
    length,
    phi=0.0,
    *,
    valid=True,
    samples_per_block: int = DEFAULT_SAMPLES_PER_BLOCK,
    cap_length: float = CAP_LENGTH,
) -> ChainShape:
    """3D shape of chains in their base frame; theta [rad], length [m], phi [rad] broadcast to (..., N)."""
    theta, length, phi = _broadcast_blocks(theta, length, phi)
    samples_per_block = _check_samples(samples_per_block)
    turn = _rot_z(phi)
    x, z = block_end_offsets(theta, length, cap_length)
    local_rotation = turn @ _rot_y(theta)
    local_position = turn[..., :, 0] * x[..., None] + turn[..., :, 2] * z[..., None]
    rotations, positions = _compose(local_rotation, local_position)

    sx, sz, _ = _local_samples(theta, length, samples_per_block, cap_length)
    start = rotations[..., :-1, :, :] @ turn  # block start frames
    local = start[..., :, None, :, 0] * sx[..., None] + start[..., :, None, :, 2] * sz[..., None]
    samples = positions[..., :-1, None, :] + local  # (..., N, S, 3)
    batch = samples.shape[:-3]
    points = np.concatenate([positions[..., :1, :], samples.reshape(*batch, -1, 3)], axis=-2)
    return ChainShape(
        points=points,
        rotations=rotations,
        positions=positions,
        theta=theta,
        length=length,
        phi=phi,
        valid=np.broadcast_to(np.asarray(valid, dtype=bool), theta.shape),
        samples_per_block=samples_per_block,
    )


# ------------------------------------------------------------------------------ table and assemblies
def design_parameters(table, ids, voltage: float | None = None):
    """Bending angle, rod length and validity of look-up-table designs, vectorised over ``ids`` (any shape).

    ``voltage`` None: the non-actuated angle theta0. Otherwise the angle at that channel voltage from
    ``table.angle_at``; ``valid`` is False where the voltage is beyond a design's safe voltage.
    Returns (theta [rad], length [m], valid), each shaped like ``ids``.
    """
    ids = np.asarray(ids)
    index = table.index_of(ids)
    length = np.asarray(table.rod_length)[index]
    if voltage is None:
        return np.asarray(table.theta0)[index], length, np.ones(ids.shape, dtype=bool)
    theta, valid = table.angle_at(ids.ravel(), voltage)
    return np.reshape(theta, ids.shape).astype(float), length, np.reshape(valid, ids.shape).astype(bool)


def chain_blocks(chain, table, voltage: float | None = None, calibration=None):
    """(theta, length, phi, valid) arrays of shape (N,) for one ``planner.assembly.Chain``.

    ``calibration``: mapping block serial -> measured angle offset [rad] added to the predicted angle;
    blocks without a serial or not in the mapping get no offset.
    """
    theta, length, valid = design_parameters(table, np.array(chain.design_ids), voltage)
    if calibration:
        theta = theta + np.array([float(calibration.get(b.serial, 0.0)) if b.serial else 0.0 for b in chain.blocks])
    phi = np.array([block.rotation for block in chain.blocks])
    return theta, length, phi, valid


def assembly_centerlines(
    assembly,
    table,
    channel_voltages: dict[str, float],
    calibration=None,
    samples_per_block: int = DEFAULT_SAMPLES_PER_BLOCK,
) -> dict[str, ChainShape]:
    """Predicted shape of every chain of ``assembly`` in the assembly frame, keyed by chain name.

    ``channel_voltages``: HV channel name -> voltage [V]; a channel not listed is taken as not actuated
    (theta0). ``calibration``: mapping block serial -> angle offset [rad]. Each ChainShape carries the
    per-block angles used and their validity (False beyond the block's safe voltage).
    """
    shapes = {}
    for chain in assembly.chains:
        theta, length, phi, valid = chain_blocks(chain, table, channel_voltages.get(chain.hv_channel), calibration)
        shape = chain_shape(theta, length, phi, valid=valid, samples_per_block=samples_per_block)
        base = Rotation.from_quat(chain.base_orientation).as_matrix()
        shapes[chain.name] = shape.transformed(base, chain.base_position)
    return shapes
