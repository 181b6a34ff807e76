"""The discrete design space of one chain: which look-up-table shapes (and rotations) each block may take.

Designs with the same shape (rod length L and theta0 within ``shape_tolerance``) bend a chain identically,
so the optimizers search over distinct shapes and the result is mapped back to design IDs afterwards. Ties
between the designs of one shape go to blocks in stock, then to the stiffest. Stiff positions only accept
shapes that have a design with rod diameter >= ``min_stiff_rod_diameter``; an inventory limits how often a
shape may be used (its designs' stock summed; stiff positions drawing on the stiff designs' stock).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.assembly import SNAP_FITS

MAX_BLOCKS = 20
DEFAULT_SHAPE_TOLERANCE = (1e-6, np.radians(0.01))  # (L [m], theta0 [rad])


@dataclass(frozen=True)
class DesignSpace:
    """Per-shape data (index s), per-position choices and inventory limits of one chain."""

    theta: np.ndarray  # (S,) theta0 of each distinct shape [rad]
    length: np.ndarray  # (S,) rod length L [m]
    members: tuple[tuple[int, ...], ...]  # design IDs of each shape, stiffest first
    member_stiff: tuple[tuple[bool, ...], ...]  # whether each member qualifies as stiff
    choices: tuple[np.ndarray, ...]  # per block position: allowed shape indices
    stiff_positions: np.ndarray  # (N,) bool
    rotations: int  # 1 (planar, phi = 0) or 12 snap-fit rotations
    stock: np.ndarray | None  # (S,) blocks available of each shape, None = unlimited
    stiff_stock: np.ndarray | None  # (S,) of those, stiff ones
    inventory: dict[int, int] | None  # design ID -> blocks on the shelf, None = unlimited

    @property
    def num_blocks(self) -> int:
        return len(self.choices)

    def excess(self, shapes: np.ndarray) -> np.ndarray:
        """(...,) number of blocks that the shape choices (..., N) use beyond the inventory (0 if none)."""
        if self.stock is None:
            return np.zeros(shapes.shape[:-1], dtype=np.int64)
        counts = np.zeros(shapes.shape[:-1] + (len(self.theta),), dtype=np.int64)
        stiff_counts = np.zeros_like(counts)
        for position in range(self.num_blocks):
            one_hot = shapes[..., position, None] == np.arange(len(self.theta))
            counts += one_hot
            if self.stiff_positions[position]:
                stiff_counts += one_hot
        over = np.maximum(counts - self.stock, 0)
        stiff_over = np.maximum(stiff_counts - self.stiff_stock, 0)
        return np.maximum(over, stiff_over).sum(axis=-1)

    def design_ids(self, shapes) -> tuple[int, ...]:
        """Design IDs for one choice of shapes (N,): stiff positions first, each takes the first member
        (in stock first, then stiffest) that qualifies and is still on the shelf."""
        left = dict(self.inventory) if self.inventory is not None else None
        ids = [0] * self.num_blocks
        order = sorted(range(self.num_blocks), key=lambda i: not self.stiff_positions[i])
        for position in order:
            shape = int(shapes[position])
            candidates = [
                design_id
                for design_id, stiff in zip(self.members[shape], self.member_stiff[shape])
                if stiff or not self.stiff_positions[position]
            ]
            if left is not None:  # an over-stock design (penalised, infeasible) still gets named
                candidates = [i for i in candidates if left.get(i, 0) > 0] or candidates
                left[candidates[0]] = left.get(candidates[0], 0) - 1
            ids[position] = candidates[0]
        return tuple(ids)


def _shape_groups(length: np.ndarray, theta: np.ndarray, tolerance) -> np.ndarray:
    """Group index per design: same L within tolerance[0] and theta0 within tolerance[1] (chained)."""
    order = np.lexsort((theta, np.round(length / max(tolerance[0], 1e-12))))
    group = np.empty(len(length), dtype=np.int64)
    current = -1
    previous = None
    for index in order:
        if (
            previous is None
            or abs(length[index] - length[previous]) > tolerance[0]
            or abs(theta[index] - theta[previous]) > tolerance[1]
        ):
            current += 1
        group[index] = current
        previous = index
    return group


def design_space(
    table,
    num_blocks: int,
    *,
    stiff_positions=(),
    min_stiff_rod_diameter: float = 0.62e-3,
    inventory: dict[int, int] | None = None,
    allow_rotation: bool = False,
    shape_tolerance=DEFAULT_SHAPE_TOLERANCE,
) -> DesignSpace:
    """Build the design space of a chain of ``num_blocks`` from a look-up table; ValueError naming the
    parameter when the constraints cannot be met (too few stiff designs, inventory too small)."""
    if not isinstance(num_blocks, (int, np.integer)) or not 1 <= num_blocks <= MAX_BLOCKS:
        raise ValueError(f"num_blocks must be an integer 1..{MAX_BLOCKS}, got {num_blocks!r}")
    stiff = np.zeros(num_blocks, dtype=bool)
    for position in stiff_positions:
        if not 0 <= position < num_blocks:
            raise ValueError(f"stiff_positions: block {position} is outside 0..{num_blocks - 1}")
        stiff[position] = True
    if not min_stiff_rod_diameter > 0:
        raise ValueError(f"min_stiff_rod_diameter must be positive [m], got {min_stiff_rod_diameter!r}")

    ids = np.asarray(table.ids, dtype=np.int64)
    theta0 = np.asarray(table.theta0, dtype=float)
    length = np.asarray(table.rod_length, dtype=float)
    qualifies = np.asarray(table.rod_diameter, dtype=float) >= min_stiff_rod_diameter * (1 - 1e-9)
    stiffness = np.asarray(table.stiffness, dtype=float)
    if inventory is not None:
        unknown = sorted(set(inventory) - set(ids.tolist()))
        if unknown:
            raise ValueError(f"inventory names unknown design IDs {unknown}")
        if any(int(count) < 0 for count in inventory.values()):
            raise ValueError("inventory counts must be >= 0")
    in_stock = np.array([inventory.get(int(i), 0) if inventory is not None else 1 for i in ids])

    group = _shape_groups(length, theta0, shape_tolerance)
    shapes = range(group.max() + 1)
    members, member_stiff, shape_theta, shape_length = [], [], [], []
    for shape in shapes:
        index = np.flatnonzero(group == shape)
        index = index[np.lexsort((-stiffness[index], ~(in_stock[index] > 0)))]  # in stock, then stiffest
        members.append(tuple(int(i) for i in ids[index]))
        member_stiff.append(tuple(bool(q) for q in qualifies[index]))
        shape_theta.append(theta0[index[0]])
        shape_length.append(length[index[0]])
    member_stiff_any = np.array([any(s) for s in member_stiff])

    stock = stiff_stock = None
    if inventory is not None:
        counts = {int(k): int(v) for k, v in inventory.items()}
        stock = np.array([sum(counts.get(i, 0) for i in m) for m in members])
        stiff_stock = np.array(
            [sum(counts.get(i, 0) for i, q in zip(m, s) if q) for m, s in zip(members, member_stiff)]
        )
        if stock.sum() < num_blocks:
            raise ValueError(f"inventory holds {stock.sum()} blocks, fewer than num_blocks = {num_blocks}")
        if stiff_stock.sum() < stiff.sum():
            raise ValueError(
                f"inventory holds {stiff_stock.sum()} stiff blocks (rod diameter >= {min_stiff_rod_diameter} m),"
                f" fewer than the {stiff.sum()} stiff positions"
            )
    available = np.ones(len(members), dtype=bool) if stock is None else stock > 0
    stiff_available = member_stiff_any if stiff_stock is None else stiff_stock > 0
    if stiff.any() and not stiff_available.any():
        raise ValueError(f"no design has a rod diameter >= min_stiff_rod_diameter = {min_stiff_rod_diameter} m")
    choices = tuple(
        np.flatnonzero(stiff_available if stiff[position] else available) for position in range(num_blocks)
    )
    return DesignSpace(
        theta=np.array(shape_theta),
        length=np.array(shape_length),
        members=tuple(members),
        member_stiff=tuple(member_stiff),
        choices=choices,
        stiff_positions=stiff,
        rotations=SNAP_FITS if allow_rotation else 1,
        stock=stock,
        stiff_stock=stiff_stock,
        inventory=None if inventory is None else {int(k): int(v) for k, v in inventory.items()},
    )
