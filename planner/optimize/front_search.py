"""One finger for several objects, and the trade-off against block swaps: a certified branch and bound.

The finger is one block sequence; each object (its own contour, collision rule and candidate base
offsets, a ``ShapeTarget`` of ``planner.design.finger_problems``) grasps with it from its own best base. The
objective is the weighted sum of the objects' eq. (3) costs, and a finger must be collision-free for every
object. The search reuses the compiled kernels of ``planner.optimize.finger_search``: the lookahead fields
bound every object's cost below a prefix, per base; the minimum over an object's bases bounds that object,
and the weighted sum of the objects' bounds bounds the finger.

A *current* finger (the robot as built) turns the search into a Pareto search: a position whose shape
changes is one block swap, and ``best[s]`` is the lowest objective over fingers with at most ``s`` swaps.
``best`` does not increase with ``s``, so a prefix with ``u`` swaps so far can only improve some budget if
its bound is below ``best[u]``; one depth-first search certifies every budget from 0 to N at once. Shape
counts are limited by ``stock`` (and ``stiff_stock`` for stiff positions), checked as blocks are placed, so
the lookahead fields stay those of the unlimited space (prepared once, on disk): a restricted set of
continuations can only be farther away than the full one, so their bounds stay valid.

Stopped early (time budget, callback), every budget keeps its best finger and a proven lower bound: the
smallest bound of the prefixes not yet visited with at most that many swaps.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numba import njit

from planner.clearance import RESOLUTION, block_min_distance
from planner.optimize.finger_search import (DEFAULT_OPTIONS, _block_update, _leaf_bounds, _leaf_cost, _lookahead,
                                            _place, _too_close, search_problem)
from planner.optimize.result import MESSAGES, RunControl, Status, Stop
from planner.optimize.space import DesignSpace

CHECK_EVERY = 64  # node expansions between time-budget / callback checks


@njit(cache=True, nogil=True)
def _node_bounds(problem, depth, poses, alphas, alive, leaf, scratch, out):
    """out[k] = lower bound on this object's cost of every finger continuing the node with next choice k:
    the smallest over the object's live bases (infinite when every base is dead or proven colliding)."""
    count = problem[4][depth]
    out[:count] = np.inf
    for b in range(poses.shape[0]):
        if not alive[b]:
            continue
        if leaf:
            _leaf_bounds(problem, depth, poses[b], alphas[b], scratch)
        else:
            _lookahead(problem, depth, poses[b], alphas[b], scratch)
        for k in range(count):
            out[k] = min(out[k], scratch[k])


@njit(cache=True, nogil=True)
def _collides(problem, pose, s):
    field, frame, threshold, cap, theta, length = (problem[16], problem[17], problem[18], problem[19], problem[20],
                                                   problem[21])
    distance = block_min_distance(field, frame, pose[0], pose[1], pose[2], theta[s], length[s], cap, threshold, False)
    return distance < threshold - RESOLUTION


@njit(cache=True, nogil=True)
def _child(problem, poses, alphas, alive, s, out_poses, out_alphas, out_alive):
    """Place shape s after the node at every live base of this object; returns whether a base stays live
    (collision-free so far, exactly)."""
    ends = problem[6]
    any_alive = False
    for b in range(poses.shape[0]):
        out_alive[b] = False
        if not alive[b]:
            continue
        _block_update(problem, poses[b], alphas[b], s, out_alphas[b])
        if _too_close(problem, out_alphas[b]) or _collides(problem, poses[b], s):
            continue
        x, z = _place(poses[b], ends[s, 0], ends[s, 1])
        out_poses[b, 0], out_poses[b, 1], out_poses[b, 2] = x, z, poses[b, 2] + ends[s, 2]
        out_alive[b] = True
        any_alive = True
    return any_alive


@njit(cache=True, nogil=True)
def _leaf_exact(problem, poses, alphas, alive, s):
    """(cost, base): this object's objective of the complete finger ending with shape s, at its best
    collision-free base; (inf, -1) when it collides at every base."""
    best, best_base = np.inf, -1
    for b in range(poses.shape[0]):
        if not alive[b]:
            continue
        cost = _leaf_cost(problem, poses[b], alphas[b], s, best)
        if cost < 0.0 or cost >= best or _collides(problem, poses[b], s):
            continue
        best, best_base = cost, b
    return best, best_base


@dataclass
class FrontResult:
    """Outcome of ``solve_finger_front`` (scipy style), per swap budget s = 0..N (index s).

    ``fun[s]``: lowest weighted objective [m] found with at most s swaps (inf: none found);
    ``lower_bound[s]``: proven lower bound on it (= ``fun[s]`` when ``optimal[s]``); ``shapes[s]`` the
    finger's shape indices (-1 when none); ``bases[s]`` each object's base index; ``object_costs[s]`` each
    object's eq. (3) cost [m]; ``swaps[s]``: the swaps that finger actually needs.
    """

    fun: np.ndarray
    lower_bound: np.ndarray
    optimal: np.ndarray
    shapes: np.ndarray
    bases: np.ndarray
    object_costs: np.ndarray
    swaps: np.ndarray
    success: bool
    status: Status
    message: str
    nit: int
    nfev: int
    solve_time: float


def _object_states(problems):
    """Root state per object: every base live, at its base pose, with its contour distances."""
    states = []
    for problem in problems:
        contour, base_x = problem[0], problem[22]
        poses = np.zeros((len(base_x), 3))
        poses[:, 0] = base_x
        alphas = np.hypot(contour[None, :, 0] - base_x[:, None], contour[None, :, 1])
        states.append((poses, alphas, np.ones(len(base_x), bool)))
    return states


def _mixtures(current, starts):
    """The current finger, each start, and each start with any subset of its positions kept as they are
    now (a first finger for every swap budget)."""
    yield current
    for start in starts or ():
        start = np.asarray(start, np.int64)
        for keep in itertools.product((False, True), repeat=len(start)):
            yield np.where(np.array(keep) & (current >= 0), current, start)


def _evaluate(problems, roots, shapes):
    """Each object's cost (inf: colliding at every base) and best base for one complete finger."""
    costs, bases = np.full(len(problems), np.inf), np.full(len(problems), -1, np.int64)
    if np.any(shapes < 0):
        return costs, bases
    for i, (problem, state) in enumerate(zip(problems, roots)):
        for s in shapes[:-1]:
            out = (np.empty_like(state[0]), np.empty_like(state[1]), np.empty_like(state[2]))
            if not _child(problem, *state, s, *out):
                break
            state = out
        else:
            costs[i], bases[i] = _leaf_exact(problem, *state, shapes[-1])
    return costs, bases


def _within(shapes, space, stock, stiff_stock) -> bool:
    counts = np.bincount(shapes, minlength=len(stock))
    stiff = np.bincount(shapes[space.stiff_positions], minlength=len(stock))
    return bool(np.all(counts <= stock) and np.all(stiff <= stiff_stock))


def _base_combinations(problems, weights, roots, scratch, blocks):
    """Every combination of one base per object (rows of base indices) and its bound: the weighted sum of
    each object's bound at that base (the smallest over its first blocks)."""
    per_object = []
    for problem, (poses, alphas, alive) in zip(problems, roots):
        bounds = np.empty(len(alive))
        out = np.empty(problem[4][0])
        for b in range(len(alive)):
            _node_bounds(problem, 0, poses, alphas, np.arange(len(alive)) == b, blocks == 1, scratch, out)
            bounds[b] = out.min()
        per_object.append(bounds)
    grids = np.meshgrid(*[np.arange(len(b)) for b in per_object], indexing="ij")
    combos = np.stack([g.reshape(-1) for g in grids], axis=1)
    total = sum(w * b[combos[:, i]] for i, (w, b) in enumerate(zip(weights, per_object)))
    return combos, total


def _check_inputs(targets, weights, space, current, stock, stiff_stock):
    if not targets:
        raise ValueError("targets: at least one object is needed")
    if any(target.body is None for target in targets):
        raise ValueError("targets must be finger targets (with a body); see planner.design.finger_problems")
    weights = np.asarray(weights, dtype=float).reshape(-1)
    if len(weights) != len(targets) or not np.all(np.isfinite(weights) & (weights > 0)):
        raise ValueError(f"weights must be {len(targets)} finite numbers > 0, got {weights.tolist()}")
    if space.rotations != 1 or space.stock is not None:
        raise ValueError("space must be a planar space without inventory (limits go in stock / stiff_stock)")
    blocks, shapes = space.num_blocks, len(space.theta)
    current = np.full(blocks, -1, np.int64) if current is None else np.asarray(current, dtype=np.int64)
    if current.shape != (blocks,) or np.any((current < -1) | (current >= shapes)):
        raise ValueError(f"current must be {blocks} shape indices (or -1 for an empty position)")
    if stock is None:
        stock = np.full(shapes, blocks, np.int64)
    stock = np.asarray(stock, dtype=np.int64)
    stiff_stock = stock if stiff_stock is None else np.asarray(stiff_stock, dtype=np.int64)
    if stock.shape != (shapes,) or stiff_stock.shape != (shapes,) or np.any(stock < 0) or np.any(stiff_stock < 0):
        raise ValueError(f"stock and stiff_stock must be {shapes} counts >= 0 (one per shape)")
    return weights, current, stock, stiff_stock


def solve_finger_front(targets, weights, space: DesignSpace, *, current=None, stock=None, stiff_stock=None,
                       time_budget=None, callback=None, options=None, starts=(), floor: float = 0.0) -> FrontResult:
    """Minimise sum_i weights[i] * cost_i over the fingers of ``space`` (planar, unlimited: its lookahead
    fields are the prepared ones), for every swap budget 0..N from ``current`` (N shape indices; -1 or None:
    every position counts as a swap). ``stock`` / ``stiff_stock`` (one count per shape) limit how often a
    shape may be used (stiff positions draw on ``stiff_stock``). ``callback(Progress)`` may raise
    StopIteration; ``time_budget`` [s]. ``starts``: complete fingers (shape indices) to prune with from the
    start, e.g. each object's own optimum; each is also tried with every subset of its positions as now.
    ``floor``: a proven lower bound on every finger [m] (e.g. the weighted sum of the objects' own certified
    optima), reported where the search's own bound is lower. Certified unless stopped (then every budget
    carries a proven bound)."""
    weights, current, stock, stiff_stock = _check_inputs(targets, weights, space, current, stock, stiff_stock)
    settings = DEFAULT_OPTIONS | (options or {})
    control = RunControl(time_budget, callback)
    problems = [search_problem(target, space, settings) for target in targets]
    blocks, n_objects = space.num_blocks, len(targets)
    choices = [np.asarray(c, np.int64) for c in space.choices]
    best = np.full(blocks + 1, np.inf)
    best_shapes = np.full((blocks + 1, blocks), -1, np.int64)
    best_bases = np.full((blocks + 1, n_objects), -1, np.int64)
    best_costs = np.full((blocks + 1, n_objects), np.inf)
    counts, stiff_counts = np.zeros(len(space.theta), np.int64), np.zeros(len(space.theta), np.int64)
    scratch = np.zeros(max(len(c) for c in choices))
    stats = {"nodes": 0, "placements": 0}

    def record(path, costs, bases):
        total = float(weights @ costs)
        swaps = int(np.sum(np.asarray(path) != current))
        for s in range(swaps, blocks + 1):
            if total < best[s]:
                best[s], best_shapes[s], best_bases[s], best_costs[s] = total, path, bases, costs

    def children(depth, states, swaps):
        """(bound, shape, swaps after) of the node's admissible children, lowest bound first."""
        leaf = depth + 1 == blocks
        total = np.zeros(len(choices[depth]))
        per_object = np.empty(len(choices[depth]))
        for problem, weight, (poses, alphas, alive) in zip(problems, weights, states):
            _node_bounds(problem, depth, poses, alphas, alive, leaf, scratch, per_object)
            total += weight * per_object
        stats["placements"] += len(choices[depth]) * n_objects
        shape = choices[depth]
        after = swaps + (shape != current[depth])
        usable = (total < best[np.minimum(after, blocks)]) & (counts[shape] < stock[shape])
        if space.stiff_positions[depth]:
            usable &= stiff_counts[shape] < stiff_stock[shape]
        picked = np.flatnonzero(usable)
        picked = picked[np.argsort(total[picked], kind="mergesort")]
        return [(float(total[k]), int(shape[k]), int(after[k])) for k in picked]

    def place(s, depth, sign):
        counts[s] += sign
        if space.stiff_positions[depth]:
            stiff_counts[s] += sign

    roots = _object_states(problems)
    for seed in _mixtures(current, starts):  # first fingers to prune with, for every budget
        costs, bases = _evaluate(problems, roots, seed)
        if np.all(seed >= 0) and np.all(np.isfinite(costs)) and _within(seed, space, stock, stiff_stock):
            record(seed.copy(), costs, bases)
    combos, combo_bounds = _base_combinations(problems, weights, roots, scratch, blocks)
    # frames[0]: the objects' base combinations; frames[1 + d]: the children of a node with d blocks placed.
    # Each frame: next entry, entries (bound, choice, swaps after), the node's object states.
    frames = [[0, [(float(combo_bounds[j]), j, 0) for j in np.argsort(combo_bounds, kind="mergesort")], roots]]
    path = np.full(blocks, -1, np.int64)
    status, nit = Status.CERTIFIED, 0
    try:
        control.report(0.0, best[blocks], 0)
        while frames:
            depth = len(frames) - 2  # blocks placed at the node whose children this frame holds
            frame = frames[-1]
            if frame[0] >= len(frame[1]):
                frames.pop()
                if depth >= 1:
                    place(path[depth - 1], depth - 1, -1)
                    path[depth - 1] = -1
                continue
            bound, s, after = frame[1][frame[0]]
            frame[0] += 1
            if bound >= best[after]:
                continue
            if depth < 0:  # a base per object
                states = [(poses, alphas, np.arange(len(alive)) == combos[s, i])
                          for i, (poses, alphas, alive) in enumerate(roots)]
                frames.append([0, children(0, states, 0), states])
                continue
            if depth + 1 == blocks:
                costs, bases, partial = np.empty(n_objects), np.empty(n_objects, np.int64), 0.0
                for i, (problem, (poses, alphas, alive)) in enumerate(zip(problems, frame[2])):
                    costs[i], bases[i] = _leaf_exact(problem, poses, alphas, alive, s)
                    partial += weights[i] * costs[i] if costs[i] < np.inf else np.inf  # inf: it collides
                    if partial >= best[after]:
                        break
                else:
                    path[depth] = s
                    record(path.copy(), costs, bases)
                    path[depth] = -1
                continue
            states = []
            for problem, (poses, alphas, alive) in zip(problems, frame[2]):
                out = (np.empty_like(poses), np.empty_like(alphas), np.empty_like(alive))
                if not _child(problem, poses, alphas, alive, s, *out):
                    break
                states.append(out)
            else:
                path[depth] = s
                place(s, depth, +1)
                frames.append([0, children(depth + 1, states, after), states])
                stats["nodes"] += 1
                if stats["nodes"] % CHECK_EVERY == 0:
                    nit += 1
                    control.report(frames[0][0] / len(frames[0][1]), best[blocks], stats["placements"])
    except Stop as stop:
        status = stop.status
    lower = best.copy()
    for frame in frames:  # prefixes not yet visited
        for bound, _, after in frame[1][frame[0]:]:
            lower[after:] = np.minimum(lower[after:], bound)
    swaps = np.array([int(np.sum(best_shapes[s] != current)) if best_shapes[s, 0] >= 0 else -1
                      for s in range(blocks + 1)])
    lower = np.maximum(lower, floor)
    optimal = np.full(blocks + 1, status == Status.CERTIFIED) | (best <= lower + 1e-12)
    found = np.isfinite(best)
    if status == Status.CERTIFIED and not found[-1]:
        status = Status.INFEASIBLE
    message = MESSAGES[status] if status != Status.CERTIFIED else "every swap budget certified"
    message += f" (best {best[-1]:.6g} m with up to {blocks} swaps)" if found[-1] else ""
    return FrontResult(
        fun=best, lower_bound=np.where(optimal, best, lower), optimal=optimal, shapes=best_shapes, bases=best_bases,
        object_costs=best_costs, swaps=swaps, success=bool(found[-1]), status=status, message=message, nit=nit,
        nfev=stats["placements"], solve_time=control.elapsed)
