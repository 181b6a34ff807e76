"""A chain along a 3D path (a trunk), rebuilt from the chain as built: the exact trade-off between block swaps
and the path objective (eq. 1).

A position keeps its block when its shape and snap-fit rotation stay; otherwise it is one swap (a new block,
or the same one re-seated at another rotation). ``best[s]`` is the lowest objective with at most ``s``
swaps; it does not increase with ``s``, so a prefix with ``u`` swaps so far can only improve a budget when
its bound is below ``best[u]``. The prefixes and their bounds are those of the path search
(``planner.optimize.exact.PrefixSearch``: the bound is exact for complete chains, and blocks beyond the
stock are never placed), taken depth first in batches: each batch's children, lowest bound first, are
split into batches again, so complete chains (and pruning) come early. First chains to prune with: the
chain as built and the given starts, each with every subset of its positions as built.

Complete: every budget certified. Stopped (time budget, callback): every budget keeps its best chain and a
proven bound, the smallest bound of the prefixes still waiting with at most that many swaps.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from planner.objectives import ShapeTarget
from planner.optimize.exact import DEFAULT_OPTIONS, PrefixSearch
from planner.optimize.pso import design_costs
from planner.optimize.result import RunControl, Status, Stop
from planner.optimize.space import DesignSpace

BATCH = 256  # prefixes expanded together


@dataclass
class PathFrontResult:
    """Per swap budget s = 0..N: ``fun[s]`` [m] (inf: no chain within the stock), ``lower_bound[s]``,
    ``optimal[s]``, the chain's ``shapes[s]`` / ``rotations[s]`` (-1: none) and ``swaps[s]``; ``status``."""

    fun: np.ndarray
    lower_bound: np.ndarray
    optimal: np.ndarray
    shapes: np.ndarray
    rotations: np.ndarray
    swaps: np.ndarray
    status: Status
    nfev: int
    solve_time: float


def _swaps(shapes, rotations, current, current_rotations) -> np.ndarray:
    k = shapes.shape[-1]
    return np.sum((shapes != current[:k]) | (rotations != current_rotations[:k]), axis=-1)


def solve_path_front(target: ShapeTarget, space: DesignSpace, current, current_rotations, *, starts=(),
                     time_budget=None, callback=None) -> PathFrontResult:
    """Every swap budget's best chain of ``space`` (its stock: the shelf and the chain's own blocks) from the
    chain as built (``current`` shape indices, -1: a block outside the space, and ``current_rotations``)."""
    if target.body is not None:
        raise ValueError("solve_path_front designs paths; fingers go to planner.optimize.front_search")
    control = RunControl(time_budget, callback)
    blocks = space.num_blocks
    current = np.asarray(current, np.int64)
    current_rotations = np.asarray(current_rotations, np.int64)
    if current.shape != (blocks,) or current_rotations.shape != (blocks,):
        raise ValueError(f"current and current_rotations must be {blocks} values each")
    search = PrefixSearch(target, space, DEFAULT_OPTIONS["samples_per_block"], DEFAULT_OPTIONS["chunk_elements"])
    best = np.full(blocks + 1, np.inf)
    chosen = np.full((blocks + 1, 2, blocks), -1, np.int64)
    nfev = 0

    def record(shapes, rotations, costs) -> None:
        swaps = _swaps(shapes, rotations, current, current_rotations)
        for u in np.unique(swaps):
            at = np.flatnonzero(swaps == u)
            j = at[np.argmin(costs[at])]
            for s in range(int(u), blocks + 1):
                if costs[j] < best[s]:
                    best[s], chosen[s, 0], chosen[s, 1] = costs[j], shapes[j], rotations[j]

    seeds = []
    for start_shapes, start_rotations in [(current, current_rotations)] + list(starts):
        for keep in itertools.product((False, True), repeat=blocks):
            keep = np.array(keep) & (current >= 0)
            seeds.append((np.where(keep, current, start_shapes), np.where(keep, current_rotations, start_rotations)))
    seeds = [(s, r) for s, r in seeds if np.all(s >= 0) and not space.excess(s[None])[0]]
    if seeds:
        shapes, rotations = np.array([s for s, _ in seeds]), np.array([r for _, r in seeds])
        record(shapes, rotations, design_costs(target, space, shapes, rotations, np.zeros(len(seeds), np.int64)))

    root = search.root()
    stack = [(0, root, np.zeros(len(root), np.int64))]  # (level, prefixes, their swaps)
    status = Status.CERTIFIED
    try:
        while stack:
            control.report(0.0, best[-1], nfev)
            level, prefixes, swaps = stack[-1]
            alive = np.flatnonzero(prefixes.bound < best[swaps])  # the best may have improved meanwhile
            if not len(alive):
                stack.pop()
                continue
            children = search.expand(prefixes.take(alive), level, ranked=False)
            nfev += len(children)
            stack.pop()
            after = _swaps(children.shapes, children.rotations, current, current_rotations)
            alive = children.bound < best[after]
            children, after = children.take(np.flatnonzero(alive)), after[alive]
            if level == blocks - 1:  # complete chains: the bound is their objective
                if len(children):
                    record(children.shapes, children.rotations, children.bound)
                continue
            order = np.argsort(children.bound, kind="mergesort")
            for start in range(((len(order) - 1) // BATCH) * BATCH, -1, -BATCH):  # the lowest bounds on top
                part = order[start:start + BATCH]
                if len(part):
                    stack.append((level + 1, children.take(part), after[part]))
    except Stop as stop:
        status = stop.status
    lower = best.copy()
    for _, prefixes, swaps in stack:  # still waiting: nothing below them is proven away
        for u in np.unique(swaps):
            lower[u:] = np.minimum(lower[u:], prefixes.bound[swaps == u].min())
    optimal = np.full(blocks + 1, status == Status.CERTIFIED) | (best <= lower + 1e-12)
    used = _swaps(chosen[:, 0], chosen[:, 1], current, current_rotations)
    return PathFrontResult(fun=best, lower_bound=np.where(optimal, best, lower), optimal=optimal,
                           shapes=chosen[:, 0], rotations=chosen[:, 1], swaps=np.where(np.isfinite(best), used, -1),
                           status=status, nfev=nfev, solve_time=control.elapsed)
