"""Reconfiguration toward a 3D path: a chain of the robot (a trunk) rebuilt from the shelf and its own blocks
to follow a path (eq. 1), with the fewest block swaps.

A position keeps its block when its shape and snap-fit rotation stay; otherwise it is one swap: a block
from the shelf or from another position of the chain, or the same block re-seated at another rotation.
``plan_path_reconfiguration`` returns, per swap budget 0..N, the best chain and a proven bound
(``planner.optimize.path_front``); the path design's own search (``solve_exact``) gives the first chains
to prune with. The result is a ``ReconfigurationResult`` (no fingers), and ``swap_steps`` turns a point
into operator steps, rotations included.
"""
from __future__ import annotations

import time
from collections import Counter

import numpy as np

from planner.assembly import Assembly, Chain, PlacedBlock
from planner.design import PATH_EXACT_OPTIONS
from planner.objectives import path_target
from planner.optimize import design_space, solve_exact
from planner.optimize.path_front import solve_path_front
from planner.optimize.result import Status
from planner.reconfigure import ParetoPoint, ReconfigurationResult, cancel_now, check_shelf, share_progress
from planner.table import load_table

MAX_PATH_POINTS = 10_000


def _check_path(path) -> np.ndarray:
    path = np.asarray(path, dtype=float)
    if path.ndim != 2 or path.shape[1] != 3 or not 2 <= len(path) <= MAX_PATH_POINTS:
        raise ValueError(f"path must be an (n, 3) array of 2..{MAX_PATH_POINTS} points [m], got shape {path.shape}")
    if not np.all(np.isfinite(path)):
        raise ValueError("path contains NaN or infinite coordinates")
    return path


def plan_path_reconfiguration(assembly: Assembly, chain: str, shelf: dict[int, int], path, *, table=None,
                              time_budget: float | None = None, callback=None) -> ReconfigurationResult:
    """The Pareto set between the path objective of chain ``chain`` of ``assembly`` (``path``: (n, 3) points
    in the chain's base frame [m], base first) and the number of block swaps, drawing on ``shelf``.
    ``time_budget`` [s]; ``callback(Progress)`` may raise StopIteration (every point keeps its bound)."""
    table = load_table() if table is None else table
    shelf = check_shelf(shelf, table)
    try:
        built = assembly.chain(chain)
    except KeyError as missing:
        raise ValueError(str(missing.args[0])) from None
    target = path_target(_check_path(path))
    if time_budget is not None and not (np.isfinite(time_budget) and time_budget > 0):
        raise ValueError(f"time_budget must be a positive number of seconds or None, got {time_budget!r}")
    started = time.perf_counter()
    pool = Counter(shelf) + Counter(b.design_id for b in built.blocks)
    space = design_space(table, len(built.blocks), inventory=dict(pool), allow_rotation=True)
    shape_of = {d: s for s, members in enumerate(space.members) for d in members}
    current = np.array([shape_of[b.design_id] for b in built.blocks], np.int64)
    rotations = np.array([b.rotation_steps for b in built.blocks], np.int64)
    half = None if time_budget is None else time_budget / 2
    first = solve_exact(target, space, options=PATH_EXACT_OPTIONS, time_budget=half,
                        callback=share_progress(callback, 0.0, 2))
    canceled = first.status == Status.CANCELED
    starts = [(first.shapes, np.array(first.rotation_steps))] if np.isfinite(first.fun) else []
    remaining = None if time_budget is None else max(time_budget - (time.perf_counter() - started), 1e-3)
    front = solve_path_front(target, space, current, rotations, starts=starts, time_budget=remaining,
                             callback=cancel_now if canceled else share_progress(callback, 1.0, 2))
    points = []
    for budget in range(len(front.fun)):
        if not np.isfinite(front.fun[budget]):
            points.append(ParetoPoint(budget, -1, np.inf, float(front.lower_bound[budget]),
                                      bool(front.optimal[budget]), (), None))
            continue
        blocks = _blocks(built, space, shelf, front.shapes[budget], front.rotations[budget])
        points.append(ParetoPoint(budget, int(front.swaps[budget]), float(front.fun[budget]),
                                  float(front.lower_bound[budget]), bool(front.optimal[budget]), (),
                                  assembly.with_chains(Chain(built.name, built.hv_channel, blocks, built.base_position,
                                                             built.base_orientation))))
    status = Status.CANCELED if canceled else front.status
    if status == Status.CERTIFIED and not np.isfinite(front.fun[-1]):
        status = Status.INFEASIBLE
    success = bool(np.isfinite(front.fun[-1]))
    certified = sum(p.optimal for p in points)
    message = (f"{certified} of {len(points)} swap budgets certified; best {front.fun[-1]:.6g} m with "
               f"{points[-1].swaps} swaps" if success else "no chain within the shelf and the chain's blocks")
    if status in (Status.CANCELED, Status.TIME_BUDGET):
        message += f" ({status.name.lower().replace('_', ' ')}: uncertified points carry their bound)"
    return ReconfigurationResult(success=success, status=status, message=message, points=tuple(points), fronts={},
                                 solve_time=time.perf_counter() - started)


def _blocks(built: Chain, space, shelf, shapes, rotations) -> tuple[PlacedBlock, ...]:
    """The chain's blocks for one point: a kept position keeps its block; a swapped one takes a design of its
    shape from the shelf and the blocks taken out."""
    shape_of = {d: s for s, members in enumerate(space.members) for d in members}
    kept = [shape_of[b.design_id] == s and b.rotation_steps == r for b, s, r in zip(built.blocks, shapes, rotations)]
    available = Counter(shelf) + Counter(b.design_id for b, k in zip(built.blocks, kept) if not k)
    out = []
    for block, keep, shape, rotation in zip(built.blocks, kept, shapes, rotations):
        if keep:
            out.append(block)
            continue
        design_id = next(d for d in space.members[shape] if available[d] > 0)  # the stock was counted
        available[design_id] -= 1
        out.append(PlacedBlock(design_id, int(rotation)))
    return tuple(out)
