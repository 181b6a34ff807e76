"""Seeded synthetic side views for the estimation tests (drawn by the independent reference renderer)."""
import numpy as np

from estimation.render import render_chain, to_binary
from planner.assembly import Chain, PlacedBlock

PIXEL = 0.25e-3  # [m / pixel], the resolution the accuracy goal is stated at


def make_chain(ids, steps=None, serials=None, name="finger") -> Chain:
    steps = steps or [0] * len(ids)
    serials = serials or [""] * len(ids)
    return Chain(name, "main", tuple(PlacedBlock(int(i), int(k), s) for i, k, s in zip(ids, steps, serials)))


def scene(table, ids, steps=None, *, offsets_deg=None, seed=0, pixel_size=PIXEL, voltage=0.0, binary=True):
    """A rendered side view of a chain with a random growth direction and mirror state.

    Returns (image, pose, theta drawn [rad]); image is uint8 binary, or the coverage in [0, 1] if not binary.
    """
    rng = np.random.default_rng(seed)
    steps = steps or [0] * len(ids)
    offsets = np.zeros(len(ids)) if offsets_deg is None else np.radians(offsets_deg)
    coverage, pose, theta = render_chain(ids, steps, table, pixel_size, offsets=offsets, voltage=voltage,
                                         angle=rng.uniform(0, 2 * np.pi), mirrored=bool(rng.integers(2)))
    return (to_binary(coverage) if binary else coverage), pose, theta
