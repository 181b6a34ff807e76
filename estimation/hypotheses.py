"""Block structures the estimator compares: the chain the user believes was built, and that chain with
one assembly mistake more (a wrong design, a wrong rotation step, a missing or an extra block).

What a side view can tell about rotations: the image plane is the chain's x-z plane and the projection
is orthographic, so mirroring the chain through that plane changes nothing in the image. Mirroring turns
every snap-fit step k into 12 - k, so steps k and 12 - k of a block look the same, and only seven classes
are distinguishable: 0, 6 (the 180 degree flip, which keeps a chain planar and bends it the other way),
and the out-of-plane pairs {1, 11}, {2, 10}, {3, 9}, {4, 8}, {5, 7}. A wrong rotation is reported with
both steps of its class.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from enum import Enum

import numpy as np

from planner.assembly import ROTATION_STEP, SNAP_FITS, Chain, PlacedBlock
from planner.geometry import ROD_LENGTH_VALUES


class MistakeKind(str, Enum):
    WRONG_DESIGN = "wrong_design"
    WRONG_ROTATION = "wrong_rotation"
    MISSING_BLOCK = "missing_block"
    EXTRA_BLOCK = "extra_block"


def rotation_class(step: int) -> tuple[int, ...]:
    """The snap-fit steps a side view cannot tell apart from ``step``: (k,) for 0 and 6, else (k, 12 - k)."""
    step %= SNAP_FITS
    mirror = (SNAP_FITS - step) % SNAP_FITS
    return (step,) if mirror == step else tuple(sorted((step, mirror)))


@dataclass(frozen=True)
class DesignBook:
    """Angle [rad] and rod length [m] of every table design at one voltage."""

    ids: np.ndarray
    length: np.ndarray
    theta: np.ndarray

    @classmethod
    def at(cls, table, voltage: float) -> DesignBook:
        theta, _ = table.angle_at(table.ids, voltage)
        return cls(ids=np.asarray(table.ids), length=np.asarray(table.rod_length, dtype=float), theta=np.asarray(theta, dtype=float))

    def row(self, design_id: int) -> int:
        rows = np.flatnonzero(self.ids == design_id)
        if rows.size == 0:
            raise ValueError(f"unknown design ID {design_id}")
        return int(rows[0])

    def with_length(self, length: float) -> tuple[int, ...]:
        return tuple(int(i) for i in self.ids[np.isclose(self.length, length)])


@dataclass(frozen=True)
class BlockSpec:
    """One block of a hypothesis: the designs it may be (one for a believed block) and where it sits."""

    designs: tuple[int, ...]
    rotation_steps: int
    length: float  # [m], shared by all its designs
    angles: tuple[float, ...]  # expected angle of each design [rad] (table at the voltage + calibration)
    serial: str = ""
    believed: int | None = None  # index of the believed block it stands for; None for an extra block


@dataclass(frozen=True)
class Change:
    """One assembly mistake in a hypothesis, relative to the believed chain."""

    kind: MistakeKind
    position: int  # believed block index (EXTRA_BLOCK: inserted before it; the block count: at the tip)
    block: int | None  # index of the affected block in the hypothesis (None for a missing block)
    rotation_steps: tuple[int, ...] = ()  # WRONG_ROTATION: the steps of the class seen


@dataclass(frozen=True)
class Hypothesis:
    blocks: tuple[BlockSpec, ...]
    changes: tuple[Change, ...] = ()
    start: int = 0  # first block whose shape differs from the hypothesis this one was derived from

    @property
    def length(self) -> np.ndarray:
        return np.array([b.length for b in self.blocks])

    @property
    def phi(self) -> np.ndarray:
        return np.array([b.rotation_steps * ROTATION_STEP for b in self.blocks])

    @property
    def structure(self) -> tuple:
        """What fixes the outline's shape function: lengths and rotation steps."""
        return tuple((round(b.length, 9), b.rotation_steps) for b in self.blocks)

    def prior(self, angle_sigma: float, unknown_sigma: float) -> tuple[np.ndarray, np.ndarray]:
        """Mean and width of each block's weak Gaussian prior in the fits: a known design's angle with
        ``angle_sigma``, or the middle of the candidate designs' angles with ``unknown_sigma`` when the design
        is open. It only keeps a fit well posed; the verdict is the tolerance's (``bounds``)."""
        mean = np.array([b.angles[0] if len(b.designs) == 1 else 0.5 * (min(b.angles) + max(b.angles)) for b in self.blocks])
        sigma = np.array([angle_sigma if len(b.designs) == 1 else unknown_sigma for b in self.blocks])
        return mean, sigma

    def bounds(self, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
        """Lowest and highest angle [rad] each block may take as built: its designs' angles +- ``tolerance``
        (the manufacturing spread of a block about its design)."""
        lower = np.array([min(b.angles) - tolerance for b in self.blocks])
        upper = np.array([max(b.angles) + tolerance for b in self.blocks])
        return lower, upper

    def nearest_designs(self, theta) -> tuple[int, ...]:
        """Each block's design whose angle lies nearest to ``theta``."""
        return tuple(b.designs[int(np.argmin(np.abs(np.array(b.angles) - angle)))] for b, angle in zip(self.blocks, theta))

    def ranked_designs(self, block: int, theta: float, reach: float) -> tuple[int, ...]:
        """The designs of a block whose angle lies within ``reach`` [rad] of ``theta`` (at least the nearest),
        nearest first: the designs the measured angle cannot tell apart."""
        spec = self.blocks[block]
        distance = np.abs(np.array(spec.angles) - theta)
        order = np.argsort(distance, kind="stable")
        return tuple(spec.designs[i] for i in order if i == order[0] or distance[i] <= reach)

    def to_chain(self, believed: Chain, theta) -> Chain:
        """The chain this hypothesis says was built (each open design resolved to the nearest in angle)."""
        blocks = tuple(
            PlacedBlock(design_id=int(design), rotation_steps=int(b.rotation_steps), serial=b.serial if len(b.designs) == 1 else "")
            for b, design in zip(self.blocks, self.nearest_designs(theta))
        )
        return Chain(believed.name, believed.hv_channel, blocks, believed.base_position, believed.base_orientation)


def believed_hypothesis(chain: Chain, book: DesignBook, offsets: dict[str, float]) -> Hypothesis:
    """The chain as the user believes it was built; ``offsets``: block serial -> calibrated angle offset [rad]."""
    blocks = []
    for i, placed in enumerate(chain.blocks):
        row = book.row(placed.design_id)
        offset = offsets.get(placed.serial, 0.0) if placed.serial else 0.0
        blocks.append(BlockSpec(
            designs=(placed.design_id,), rotation_steps=placed.rotation_steps, length=float(book.length[row]),
            angles=(float(book.theta[row]) + offset,), serial=placed.serial, believed=i,
        ))
    return Hypothesis(tuple(blocks))


def _open_block(book: DesignBook, length: float, rotation_steps: int, believed: int | None, exclude: int | None = None) -> BlockSpec | None:
    designs = tuple(d for d in book.with_length(length) if d != exclude)
    if not designs:
        return None
    angles = tuple(float(book.theta[book.row(d)]) for d in designs)
    return BlockSpec(designs=designs, rotation_steps=rotation_steps, length=float(length), angles=angles, believed=believed)


def alternatives(hypothesis: Hypothesis, believed_count: int, book: DesignBook, *, out_of_plane: bool = True,
                 last_position: int | None = None) -> list[Hypothesis]:
    """Every hypothesis with one mistake more than ``hypothesis``, at believed positions up to
    ``last_position`` (a mistake further along cannot explain a misfit that starts earlier)."""
    changed = {c.position for c in hypothesis.changes}
    limit = believed_count if last_position is None else min(last_position, believed_count)
    blocks = hypothesis.blocks
    found = []

    def derive(new_blocks, change: Change, start: int) -> None:
        grown = len(new_blocks) - len(blocks)  # +1 inserted at start, -1 removed at start, 0 replaced
        earlier = tuple(
            c if c.block is None or c.block < start or grown == 0 else replace(c, block=c.block + grown)
            for c in hypothesis.changes
        )
        found.append(Hypothesis(tuple(new_blocks), earlier + (change,), start))

    for j, spec in enumerate(blocks):
        position = spec.believed
        if position is None or position in changed or position > limit:
            continue
        believed_design = spec.designs[0]
        for length in ROD_LENGTH_VALUES:
            same = abs(length - spec.length) < 1e-9
            open_block = _open_block(book, length, spec.rotation_steps, position, exclude=believed_design if same else None)
            if open_block is not None:
                derive(blocks[:j] + (open_block,) + blocks[j + 1:], Change(MistakeKind.WRONG_DESIGN, position, j), j)
        seen = rotation_class(spec.rotation_steps)
        choices = range(SNAP_FITS // 2 + 1) if out_of_plane else [(spec.rotation_steps + SNAP_FITS // 2) % SNAP_FITS]
        for step in choices:
            steps = rotation_class(step)
            if steps == seen:
                continue
            turned = replace(spec, rotation_steps=steps[0])
            derive(blocks[:j] + (turned,) + blocks[j + 1:], Change(MistakeKind.WRONG_ROTATION, position, j, steps), j)
        if len(blocks) > 1:
            derive(blocks[:j] + blocks[j + 1:], Change(MistakeKind.MISSING_BLOCK, position, None), j)
    insert_points = [(j, b.believed) for j, b in enumerate(blocks) if b.believed is not None] + [(len(blocks), believed_count)]
    for j, position in insert_points:
        if position in changed or position > limit or (position == believed_count and believed_count in changed):
            continue
        for length in ROD_LENGTH_VALUES:
            extra = _open_block(book, length, 0, None)
            derive(blocks[:j] + (extra,) + blocks[j:], Change(MistakeKind.EXTRA_BLOCK, position, j), j)
    return found
