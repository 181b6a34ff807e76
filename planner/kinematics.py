"""Piecewise-constant-curvature kinematics of chains of building blocks (paper section 2.2.2).

Each block is a straight linking cap (``CAP_LENGTH``), a circular arc of length L and angle theta (the
bent NiTi rods), and a second straight cap. Block i is turned by phi_i about its local z axis relative to
block i-1 (the snap-fit index times 30 degrees). Convention (as in ``Chain.msg``): a chain grows along its
base frame's +z and, at phi = 0 and theta > 0, bends toward +x; the planar model lives in the x-z plane.

All functions are vectorised: ``theta``, ``length`` and ``phi`` broadcast to a common shape ``(..., N)``
(N blocks, base first, any batch dimensions in front), so thousands of candidate designs are evaluated at
once. theta -> 0 is exact (chord = L sin(theta/2) / (theta/2), no division by zero).

Three paths:
- ``planar_chain`` for phi in {0, pi}: headings add up with ``cumsum``; no loop over blocks.
- ``chain_frames`` for any phi: base and block end frames only, composed block by block.
- ``chain_shape`` for any phi: frames plus centerline samples (and tube, frames per sample on demand).
Internally the batch is flattened and put last in memory so every array operation runs over one long
contiguous axis; results are returned batch-first.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from planner.geometry import PAPER_GEOMETRY

CAP_LENGTH = PAPER_GEOMETRY.cap_length  # length of one linking cap [m]
BLOCK_RADIUS = PAPER_GEOMETRY.radius  # outer radius of a block [m]
DEFAULT_SAMPLES_PER_BLOCK = 10
CHUNK = 2048  # chains per internal pass


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


def _batch_last(array: np.ndarray) -> np.ndarray:
    """(..., N) -> contiguous (N, M) with the batch flattened to M."""
    return np.ascontiguousarray(np.moveaxis(array, -1, 0).reshape(array.shape[-1], -1))


def _in_chunks(inner, arrays, batch: tuple[int, ...]) -> list[np.ndarray]:
    """Run ``inner`` on (N, m) slices of the internal layout, ``CHUNK`` chains at a time (so the working
    arrays stay in cache), and return its outputs (..., m) joined and batch-first: (*batch, ...)."""
    total = arrays[0].shape[-1]
    starts = range(0, max(total, 1), CHUNK)  # an empty batch still gets one (empty) pass
    pieces = [inner(*(a[:, start : start + CHUNK] for a in arrays)) for start in starts]
    joined = []
    for outputs in zip(*pieces):
        flat = np.concatenate([np.moveaxis(o, -1, 0) for o in outputs])
        joined.append(flat.reshape(batch + flat.shape[1:]))
    return joined


def _sin_over(half_angle: np.ndarray, sin_half: np.ndarray) -> np.ndarray:
    """sin(a) / a, exactly 1 at a = 0 (no division by zero)."""
    return np.divide(sin_half, half_angle, out=np.ones_like(half_angle), where=half_angle != 0.0)


def _sample_fractions(samples_per_block: int) -> np.ndarray:
    """Arc fraction of each sample of a block: first cap end (0), equal arc steps, second cap end (1)."""
    steps = samples_per_block - 2
    return np.concatenate(([0.0], np.arange(1, steps + 1) / steps, [1.0]))


def _local_samples(theta: np.ndarray, length: np.ndarray, samples_per_block: int, cap_length: float):
    """Centerline samples of each block in its own start frame (after the phi turn), internal layout.

    theta, length: (N, M). Per block: end of the first cap, ``samples_per_block - 2`` equal steps along
    the arc (last = arc end), end of the second cap. Returns x, z (N, S, M) and half the bend angle
    reached at the arc samples, (N, S - 2, M).
    """
    steps = samples_per_block - 2
    n, m = theta.shape
    half_step = theta * (0.5 / steps)  # half the bend angle of one arc step
    # e^(i j a) for j = 1..steps by repeated multiplication: one complex exponential per block, not per sample.
    turns = np.empty((n, steps, m), dtype=complex)
    turns[:] = np.exp(1j * half_step)[:, None, :]
    np.cumprod(turns, axis=1, out=turns)
    cos_half, sin_half = turns.real, turns.imag
    j = np.arange(1, steps + 1)[:, None]
    half = half_step[:, None, :] * j  # half the bend angle reached at each arc sample
    # The chord of an arc of length s and angle 2a has length s sin(a)/a and points along angle a.
    chord = length[:, None, :] * (j / steps) * _sin_over(half, sin_half)
    x = np.empty((n, samples_per_block, m))
    z = np.empty((n, samples_per_block, m))
    x[:, 0], z[:, 0] = 0.0, cap_length
    np.multiply(chord, sin_half, out=x[:, 1:-1])
    np.multiply(chord, cos_half, out=z[:, 1:-1])
    z[:, 1:-1] += cap_length
    end_sin, end_cos = sin_half[:, -1], cos_half[:, -1]  # the second cap continues along the end tangent
    x[:, -1] = x[:, -2] + cap_length * 2.0 * end_sin * end_cos
    z[:, -1] = z[:, -2] + cap_length * (1.0 - 2.0 * end_sin**2)
    return x, z, half


def block_end_offsets(theta, length, cap_length: float = CAP_LENGTH) -> tuple[np.ndarray, np.ndarray]:
    """End point (x, z) of single blocks in their start frame: cap + arc + cap, any shape."""
    half = 0.5 * np.asarray(theta, dtype=float)
    sin_half, cos_half = np.sin(half), np.cos(half)
    chord = np.asarray(length, dtype=float) * _sin_over(half, sin_half)
    x = chord * sin_half + cap_length * 2.0 * sin_half * cos_half
    z = cap_length + chord * cos_half + cap_length * (1.0 - 2.0 * sin_half**2)
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
    side = np.cumprod(np.where(np.round(_batch_last(turns)) % 2 == 0, 1.0, -1.0), axis=0)
    signed = side * _batch_last(theta)  # bending angle toward the base's +x, (N, M)

    def inner(signed, length):
        n, m = signed.shape
        end_headings = np.zeros((n + 1, m))
        np.cumsum(signed, axis=0, out=end_headings[1:])
        start = end_headings[:-1, None, :]  # heading at each block start, (N, 1, M)
        x, z, half = _local_samples(signed, length, samples_per_block, cap_length)
        angle = np.concatenate([np.zeros((n, 1, m)), 2.0 * half, signed[:, None, :]], axis=1)  # bend reached
        cos, sin = np.cos(start), np.sin(start)
        offsets = np.stack([x * cos + z * sin, z * cos - x * sin], axis=2)  # turned to the start heading
        ends = np.zeros((n + 1, 2, m))
        np.cumsum(offsets[:, -1], axis=0, out=ends[1:])
        points = np.concatenate([ends[:1], (ends[:-1, None] + offsets).reshape(n * samples_per_block, 2, m)])
        headings = np.concatenate([end_headings[:1], (start + angle).reshape(n * samples_per_block, m)])
        return points, headings, ends, end_headings

    points, headings, ends, end_headings = _in_chunks(inner, (signed, _batch_last(length)), theta.shape[:-1])
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
def _turn_then_bend(phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rz(phi) @ Ry(theta), shape (..., 3, 3): turn about the local z axis, then bend toward the new +x."""
    phi, theta = np.broadcast_arrays(phi, theta)
    cos_phi, sin_phi, cos_theta, sin_theta = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)
    rotation = np.empty(theta.shape + (3, 3))
    rotation[..., 0, 0] = cos_phi * cos_theta
    rotation[..., 0, 1] = -sin_phi
    rotation[..., 0, 2] = cos_phi * sin_theta
    rotation[..., 1, 0] = sin_phi * cos_theta
    rotation[..., 1, 1] = cos_phi
    rotation[..., 1, 2] = sin_phi * sin_theta
    rotation[..., 2, 0] = -sin_theta
    rotation[..., 2, 1] = 0.0
    rotation[..., 2, 2] = cos_theta
    return rotation


def block_transforms(theta, length, phi, cap_length: float = CAP_LENGTH) -> np.ndarray:
    """(..., N, 4, 4) homogeneous transform of each block: end frame in the previous block's end frame.

    T_i = Rz(phi_i) . Trans(cap) . Arc(theta_i, L_i) . Trans(cap), Arc = bend by theta about +y.
    """
    theta, length, phi = _broadcast_blocks(theta, length, phi)
    x, z = block_end_offsets(theta, length, cap_length)
    transform = np.zeros(theta.shape + (4, 4))
    transform[..., :3, :3] = _turn_then_bend(phi, theta)
    transform[..., :3, 3] = np.stack([np.cos(phi) * x, np.sin(phi) * x, z], axis=-1)
    transform[..., 3, 3] = 1.0
    return transform


def _compose(theta: np.ndarray, length: np.ndarray, phi: np.ndarray, cap_length: float):
    """Chain the block transforms of (N, M) inputs: frame_i = frame_(i-1) . T_i.

    Returns rotations (N+1, 3, 3, M) and positions (N+1, 3, M) of the base and block ends, and
    cos(phi), sin(phi) (N, M) for the caller's block start frames.
    """
    x, z = block_end_offsets(theta, length, cap_length)
    cos_phi, sin_phi = np.cos(phi), np.sin(phi)
    local = np.moveaxis(_turn_then_bend(phi, theta), (-2, -1), (1, 2))  # (N, 3, 3, M)
    translation = np.stack([cos_phi * x, sin_phi * x, z], axis=1)  # (N, 3, M)
    n, m = theta.shape
    rotations = np.empty((n + 1, 3, 3, m))
    positions = np.empty((n + 1, 3, m))
    rotations[0] = np.eye(3)[:, :, None]
    positions[0] = 0.0
    for i in range(n):
        np.einsum("rjm,jcm->rcm", rotations[i], local[i], out=rotations[i + 1])
        np.einsum("rjm,jm->rm", rotations[i], translation[i], out=positions[i + 1])
        positions[i + 1] += positions[i]
    return rotations, positions, cos_phi, sin_phi


def chain_frames(theta, length, phi=0.0, *, cap_length: float = CAP_LENGTH) -> tuple[np.ndarray, np.ndarray]:
    """Frames only (no centerline samples): the fast path for tips and poses.

    theta [rad], length [m], phi [rad] broadcast to (..., N). Returns rotations (..., N + 1, 3, 3) and
    positions (..., N + 1, 3) [m] of the base (index 0) and of each block end, in the chain base frame.
    """
    theta, length, phi = _broadcast_blocks(theta, length, phi)

    def inner(theta, length, phi):
        return _compose(theta, length, phi, cap_length)[:2]

    rotations, positions = _in_chunks(inner, [_batch_last(a) for a in (theta, length, phi)], theta.shape[:-1])
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
        fraction = _sample_fractions(self.samples_per_block)
        local = _turn_then_bend(self.phi[..., None], self.theta[..., None] * fraction)  # (..., N, S, 3, 3)
        per_sample = self.rotations[..., :-1, None, :, :] @ local
        batch = per_sample.shape[:-4]
        # the base sample has the orientation of the first block's start (fraction 0)
        return np.concatenate([per_sample[..., :1, 0, :, :], per_sample.reshape(*batch, -1, 3, 3)], axis=-3)

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
    """3D shape of chains in their base frame; theta [rad], length [m], phi [rad] broadcast to (..., N).

    ``valid`` (broadcast to (..., N)) is carried through for the caller (see ``assembly_centerlines``).
    """
    theta, length, phi = _broadcast_blocks(theta, length, phi)
    samples_per_block = _check_samples(samples_per_block)

    def inner(theta, length, phi):
        rotations, positions, cos_phi, sin_phi = _compose(theta, length, phi, cap_length)
        x, z, _ = _local_samples(theta, length, samples_per_block, cap_length)  # (N, S, M)
        n, count, m = x.shape
        start = rotations[:-1]  # (N, 3, 3, M)
        # Block start frame = previous end frame turned by phi: its x axis, and its z axis (unchanged).
        start_x = cos_phi[:, None] * start[:, :, 0] + sin_phi[:, None] * start[:, :, 1]  # (N, 3, M)
        points = np.empty((1 + n * count, 3, m))
        points[0] = positions[0]
        samples = points[1:].reshape(n, count, 3, m)
        np.multiply(x[:, :, None], start_x[:, None], out=samples)
        samples += z[:, :, None] * start[:, None, :, 2]
        samples += positions[:-1, None]
        return points, rotations, positions

    arrays = [_batch_last(a) for a in (theta, length, phi)]
    points, rotations, positions = _in_chunks(inner, arrays, theta.shape[:-1])
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
    index = table.index_of(ids.ravel()).reshape(ids.shape)
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
