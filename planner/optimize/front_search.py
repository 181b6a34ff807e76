"""One finger for several objects, and the trade-off against block swaps: a certified branch and bound.

The finger is one block sequence; each object (its own contour, collision rule and candidate base
offsets, a ``ShapeTarget`` of ``planner.design.finger_problems``) grasps with it from its own best base. The
objective is the weighted sum of the objects' eq. (3) costs, and a finger must be collision-free for every
object. The search reuses the compiled kernels of ``planner.optimize.finger_search``: the lookahead fields
bound every object's cost below a prefix, per base; the minimum over an object's bases bounds that object,
and the weighted sum of the objects' bounds bounds the finger. One tree holds every base of every object: a
node is expanded once for all of them, and a child keeps only the bases of an object whose own bound, with
every other object at its best base, is still below the limit (so a prefix is not searched again per
combination of bases, and the exact costs of a complete finger are taken only at the bases that can win).

A *current* finger (the robot as built) turns the search into a Pareto search: a position that does not
keep its block is one block swap (see ``Run`` for which blocks may stay), and ``best[s]`` is the lowest
objective over fingers with at most ``s`` swaps. ``best`` does not increase with ``s``, so a prefix with
``u`` swaps so far can only improve a budget ``v >= u``, below ``best[v]`` (and not where a proven bound
already reaches that); one depth-first search certifies every budget from 0 to N at once. It runs compiled
(``_search_front``) and returns to Python for each finger below its limit and for progress checks. Shape
counts are limited by ``stock`` (and ``stiff_stock`` for stiff positions), checked as blocks are placed, so
the lookahead fields stay those of the unlimited space (prepared once, on disk): a restricted set of
continuations can only be farther away than the full one, so their bounds stay valid.

Stopped early (time budget, callback), every budget keeps its best finger and a proven lower bound: the
smallest bound of the prefixes not yet visited with at most that many swaps.
"""
from __future__ import annotations

import itertools
import threading
from concurrent.futures import ThreadPoolExecutor
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
def _node_bounds(problem, depth, poses, alphas, alive, leaf, scratch, out, per_base):
    """out[k] = lower bound on this object's cost of every finger continuing the node with next choice k:
    the smallest over the object's live bases (infinite when every base is dead or proven colliding);
    per_base[k, b] the bound at base b alone (infinite where it is dead)."""
    count = problem[4][depth]
    out[:count] = np.inf
    for b in range(poses.shape[0]):
        if not alive[b]:
            per_base[:count, b] = np.inf
            continue
        if leaf:
            _leaf_bounds(problem, depth, poses[b], alphas[b], scratch)
        else:
            _lookahead(problem, depth, poses[b], alphas[b], scratch)
        for k in range(count):
            per_base[k, b] = scratch[k]
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
def _leaf_exact(problem, poses, alphas, alive, s, cutoff):
    """(cost, base): this object's objective of the complete finger ending with shape s, at its best
    collision-free base; (inf, -1) when it collides at every base or costs ``cutoff`` or more at each."""
    best, best_base = cutoff, -1
    for b in range(poses.shape[0]):
        if not alive[b]:
            continue
        cost = _leaf_cost(problem, poses[b], alphas[b], s, best)
        if cost < 0.0 or cost >= best or _collides(problem, poses[b], s):
            continue
        best, best_base = cost, b
    return (best, best_base) if best_base >= 0 else (np.inf, -1)


@njit(cache=True, nogil=True)
def _admissible(total, shape, current, keeps_stiff, stiff_position, releasable, swaps, limit, counts, stock,
                stiff_counts, stiff_stock, blocked):
    """The children of a node worth visiting, lowest bound first: (bound, shape, choice index, swaps after,
    whether it takes a stiff block). A child is kept when its bound is below ``limit[swaps after]`` and its shape is
    still in stock (a stiff block too, where one is needed); a releasable position also offers its own
    shape with another block of it (one swap more, any block). A child below its limit that the stock stops
    lowers ``blocked[0, shape]`` (``blocked[1, shape]`` for the stiff stock) to the blocks of its shape
    already placed."""
    count = len(shape)
    bounds, shapes, index = np.empty(count + 1), np.empty(count + 1, np.int64), np.empty(count + 1, np.int64)
    afters, stiff = np.empty(count + 1, np.int64), np.empty(count + 1, np.bool_)
    m = 0
    for k in range(count):
        s = shape[k]
        kept = s == current
        after = swaps if kept else swaps + 1
        needs_stiff = stiff_position or (kept and keeps_stiff)
        wanted = total[k] < limit[after]
        other_block = kept and releasable and total[k] < limit[swaps + 1]
        if not (wanted or other_block):
            continue
        if counts[s] >= stock[s]:
            blocked[0, s] = min(blocked[0, s], counts[s])
            continue
        if wanted:
            if not needs_stiff or stiff_counts[s] < stiff_stock[s]:
                bounds[m], shapes[m], index[m], afters[m], stiff[m] = total[k], s, k, after, needs_stiff
                m += 1
            else:
                blocked[1, s] = min(blocked[1, s], stiff_counts[s])
        if other_block:
            bounds[m], shapes[m], index[m], afters[m], stiff[m] = total[k], s, k, swaps + 1, False
            m += 1
    order = np.argsort(bounds[:m], kind="mergesort")
    return bounds[order], shapes[order], index[order], afters[order], stiff[order]


CHECKPOINT, LEAF, DONE = 0, 1, 2  # why the compiled search returned


@njit(cache=True, nogil=True)
def _expand(problems, weights, sizes, level, blocks, poses, alphas, alive, choices, n_choices, current, keeps_stiff,
            stiff_positions, releasable, swaps, limit, counts, stock, stiff_counts, stiff_stock, scratch, per_object,
            total, base_bounds, state_bounds, state_shapes, state_index, state_afters, state_stiff, count, blocked,
            placements):
    """The admissible children of the node at ``level`` (its object states at index ``level``), lowest bound
    first, into the level's rows of the child lists; each object's bound per base and next choice into the
    level's rows of ``base_bounds``."""
    leaf = level + 1 == blocks
    n = n_choices[level]
    total[:n] = 0.0
    for i in range(len(problems)):
        b, q = sizes[i, 0], sizes[i, 1]
        _node_bounds(problems[i], level, poses[i, level, :b], alphas[i, level, :b, :q], alive[i, level, :b], leaf,
                     scratch, per_object, base_bounds[level, i, :n, :b])
        for k in range(n):
            total[k] += weights[i] * per_object[k]
    placements[0] += n * len(problems)
    bounds, shapes, index, afters, stiff = _admissible(total[:n], choices[level, :n], current[level],
                                                       keeps_stiff[level], stiff_positions[level], releasable[level],
                                                       swaps, limit, counts, stock, stiff_counts, stiff_stock,
                                                       blocked)
    m = len(bounds)
    state_bounds[level, :m], state_shapes[level, :m], state_index[level, :m] = bounds, shapes, index
    state_afters[level, :m], state_stiff[level, :m] = afters, stiff
    count[level] = m


@njit(cache=True, nogil=True)
def _useful_bases(weights, sizes, per_base, alive, limit, mask):
    """mask[i, b]: base b of object i stays live below a child whose bounds per object and base are
    ``per_base[i, :, b]``: the child's bound with object i at base b and every other object at its best base
    is below ``limit`` (summed in the order of ``_expand``, so the best base of each object passes exactly
    when the child's own bound does). A base that fails proves that no finger below the child with object i
    at that base beats the limit, which only falls."""
    n_objects = len(weights)
    least = np.empty(n_objects)
    for i in range(n_objects):
        least[i] = np.inf
        for b in range(sizes[i, 0]):
            least[i] = min(least[i], per_base[i, b])
    for i in range(n_objects):
        for b in range(sizes[i, 0]):
            mask[i, b] = False
            if not alive[i, b]:
                continue
            total = 0.0
            for j in range(n_objects):
                total += weights[j] * (per_base[i, b] if j == i else least[j])
            mask[i, b] = total < limit
    return least


@njit(cache=True, nogil=True)
def _search_front(problems, weights, sizes, blocks, choices, n_choices, current, keeps_stiff, stiff_positions,
                  releasable, limit, stock, stiff_stock, share, root_bound, root_poses, root_alphas, state,
                  check_every):
    """Resumable depth-first search (see ``FingerFrontSearch.run``): returns LEAF with a complete finger
    below its limit in the state's leaf rows, CHECKPOINT every ``check_every`` nodes, DONE at the end.
    ``share`` (offset, stride): this search takes the root's children at those ranks of the bound order."""
    (top, started, next_child, count, bounds, shapes, index, afters, stiff, node_swaps, path, swapped, stiff_used,
     counts, stiff_counts, poses, alphas, alive, leaf_costs, leaf_bases, scratch, per_object, total, base_bounds,
     mask, blocked, stats) = state
    while True:
        level = top[0]
        if level < 0:  # the root: every base of every object live
            if started[0] or root_bound >= limit[0]:
                started[0] = 1
                return DONE
            started[0] = 1
            for i in range(len(problems)):
                b, q = sizes[i, 0], sizes[i, 1]
                poses[i, 0, :b] = root_poses[i, :b]
                alphas[i, 0, :b, :q] = root_alphas[i, :b, :q]
                alive[i, 0, :b] = True
            node_swaps[0] = 0
            next_child[0] = 0
            _expand(problems, weights, sizes, 0, blocks, poses, alphas, alive, choices, n_choices, current,
                    keeps_stiff, stiff_positions, releasable, 0, limit, counts, stock, stiff_counts, stiff_stock,
                    scratch, per_object, total, base_bounds, bounds, shapes, index, afters, stiff, count, blocked,
                    stats[1:])
            m = 0
            for k in range(share[0], count[0], share[1]):
                bounds[0, m], shapes[0, m], index[0, m] = bounds[0, k], shapes[0, k], index[0, k]
                afters[0, m], stiff[0, m] = afters[0, k], stiff[0, k]
                m += 1
            count[0] = m
            top[0] = 0
            continue
        if next_child[level] >= count[level]:  # every child done: back to the parent
            top[0] = level - 1
            if level >= 1:
                s = path[level - 1]
                counts[s] -= 1
                if stiff_used[level - 1]:
                    stiff_counts[s] -= 1
            continue
        k = next_child[level]
        next_child[level] += 1
        s, after = shapes[level, k], afters[level, k]
        if bounds[level, k] >= limit[after]:
            continue
        least = _useful_bases(weights, sizes, base_bounds[level, :, index[level, k]], alive[:, level], limit[after],
                              mask)
        if level + 1 == blocks:  # a complete finger: each object at its best collision-free base
            partial, rest = 0.0, 0.0
            for i in range(len(problems)):
                rest += weights[i] * least[i]
            for i in range(len(problems)):
                b, q = sizes[i, 0], sizes[i, 1]
                rest -= weights[i] * least[i]
                # object i matters only below what the limit leaves it (loosened a little against rounding)
                cutoff = (limit[after] - partial - rest) / weights[i] * (1.0 + 1e-9) + 1e-12
                cost, base = _leaf_exact(problems[i], poses[i, level, :b], alphas[i, level, :b, :q], mask[i, :b], s,
                                         cutoff)
                leaf_costs[i], leaf_bases[i] = cost, base
                partial += weights[i] * cost
                if partial >= limit[after]:
                    break
            else:
                path[level], swapped[level] = s, after > node_swaps[level]
                return LEAF
            continue
        clear = True
        for i in range(len(problems)):
            b, q = sizes[i, 0], sizes[i, 1]
            if not _child(problems[i], poses[i, level, :b], alphas[i, level, :b, :q], mask[i, :b], s,
                          poses[i, level + 1, :b], alphas[i, level + 1, :b, :q], alive[i, level + 1, :b]):
                clear = False
                break
        if not clear:
            continue
        path[level], swapped[level], stiff_used[level] = s, after > node_swaps[level], stiff[level, k]
        counts[s] += 1
        if stiff[level, k]:
            stiff_counts[s] += 1
        node_swaps[level + 1] = after
        next_child[level + 1] = 0
        _expand(problems, weights, sizes, level + 1, blocks, poses, alphas, alive, choices, n_choices, current,
                keeps_stiff, stiff_positions, releasable, after, limit, counts, stock, stiff_counts, stiff_stock,
                scratch, per_object, total, base_bounds, bounds, shapes, index, afters, stiff, count, blocked,
                stats[1:])
        top[0] = level + 1
        stats[0] += 1
        if stats[0] % check_every == 0:
            return CHECKPOINT


@dataclass(frozen=True)
class Candidate:
    """One complete finger: its shapes, which positions change their block (``swapped``), each object's
    cost and base index, the weighted ``cost`` [m] and the swaps it needs. ``as_built``: the finger exactly
    as built, rotations included (not a point of the planar design space)."""

    shapes: np.ndarray
    swapped: np.ndarray
    costs: np.ndarray
    bases: np.ndarray
    cost: float
    as_built: bool = False

    @property
    def swaps(self) -> int:
        return int(self.swapped.sum())


@dataclass
class Run:
    """One depth-first search of a ``FingerFrontSearch``.

    ``current``: the shape each position keeps without a swap (-1: none); ``keeps_stiff``: keeping the
    position's block uses one of its shape's stiff blocks (a forced-stiff position, or a stiff block at a free
    one); ``releasable``: the position may instead take another block of its shape, for one swap (a stiff
    block at a free position whose shape also has free designs: it may be wanted at a stiff position).
    ``stock`` / ``stiff_stock``: blocks per shape. A child is dropped when its bound reaches
    ``limit[swaps after it]`` (read at every step: the caller may lower it); ``on_leaf(Candidate)`` receives
    every complete finger below its limit. ``frames`` hold the children not yet visited (see ``frontier``).
    """

    current: np.ndarray
    keeps_stiff: np.ndarray
    releasable: np.ndarray
    stock: np.ndarray
    stiff_stock: np.ndarray
    limit: np.ndarray
    on_leaf: object
    frames: object = None  # what the search has not visited yet; None: not started

    def frontier(self) -> list[tuple[float, int]]:
        """(bound, swaps) of every child not yet visited: a stopped search proves nothing below them."""
        return [] if self.frames is None else self.frames.frontier()

    def stock_needed(self) -> tuple[np.ndarray, np.ndarray]:
        """Per shape, the fewest blocks of it already placed when the stock (``[0]``) or the stiff stock
        (``[1]``) stopped a child below its limit (the finger's length where it never did). Another stock
        with at most that many of every shape stops every such child too, so a search under it, with limits
        no higher, finds nothing this one missed (see ``gripper_search``)."""
        return self.frames.stock_needed()


class FingerFrontSearch:
    """The compiled problems of one finger (its objects, weights and planar unlimited space), ready for
    depth-first searches under any stock, current finger and limits (``run``)."""

    def __init__(self, targets, weights, space: DesignSpace, options=None):
        if not targets:
            raise ValueError("targets: at least one object is needed")
        if any(target.body is None for target in targets):
            raise ValueError("targets must be finger targets (with a body); see planner.design.finger_problems")
        weights = np.asarray(weights, dtype=float).reshape(-1)
        if len(weights) != len(targets) or not np.all(np.isfinite(weights) & (weights > 0)):
            raise ValueError(f"weights must be {len(targets)} finite numbers > 0, got {weights.tolist()}")
        if space.rotations != 1 or space.stock is not None:
            raise ValueError("space must be a planar space without inventory (limits go in stock / stiff_stock)")
        settings = DEFAULT_OPTIONS | (options or {})
        self.space, self.weights = space, weights
        self.problems = [search_problem(target, space, settings) for target in targets]
        self.choices = [np.asarray(c, np.int64) for c in space.choices]
        self.scratch = np.zeros(max(len(c) for c in self.choices))
        self.roots = _object_states(self.problems)
        self.root_bound = _root_bound(self.problems, weights, self.roots, self.scratch, space.num_blocks)
        self.placements = 0
        # the compiled search's view: one tuple of problems, per-position choices, per-object states padded
        self.problems_tuple = tuple(self.problems)
        self.n_choices = np.array([len(c) for c in self.choices], np.int64)
        self.choices = np.full((len(self.choices), self.n_choices.max()), -1, np.int64)
        for k, c in enumerate(space.choices):
            self.choices[k, :len(c)] = c
        self.sizes = np.array([[len(poses), alphas.shape[1]] for poses, alphas, _ in self.roots], np.int64)
        b, q = self.sizes.max(axis=0)
        self.root_poses, self.root_alphas = np.zeros((len(targets), b, 3)), np.zeros((len(targets), b, q))
        for i, (poses, alphas, _) in enumerate(self.roots):
            self.root_poses[i, :len(poses)], self.root_alphas[i, :len(poses), :alphas.shape[1]] = poses, alphas

    def evaluate(self, shapes) -> tuple[np.ndarray, np.ndarray]:
        """Each object's cost (inf: colliding at every base) and best base for one complete finger."""
        return _evaluate(self.problems, self.roots, np.asarray(shapes, np.int64))

    def _new_state(self) -> tuple:
        """The compiled search's working arrays (see ``_search_front`` for the order)."""
        blocks, n_objects, width = self.space.num_blocks, len(self.problems), self.choices.shape[1] + 1
        b, q = self.sizes.max(axis=0)
        size = len(self.space.theta)
        return (np.array([-1]), np.zeros(1, np.int64), np.zeros(blocks, np.int64), np.zeros(blocks, np.int64),
                np.zeros((blocks, width)), np.zeros((blocks, width), np.int64), np.zeros((blocks, width), np.int64),
                np.zeros((blocks, width), np.int64), np.zeros((blocks, width), np.bool_), np.zeros(blocks, np.int64),
                np.full(blocks, -1, np.int64), np.zeros(blocks, np.bool_), np.zeros(blocks, np.bool_),
                np.zeros(size, np.int64), np.zeros(size, np.int64), np.zeros((n_objects, blocks, b, 3)),
                np.zeros((n_objects, blocks, b, q)), np.zeros((n_objects, blocks, b), np.bool_), np.zeros(n_objects),
                np.zeros(n_objects, np.int64), np.zeros(width), np.zeros(width), np.zeros(width),
                np.full((blocks, n_objects, width, b), np.inf), np.zeros((n_objects, b), np.bool_),
                np.full((2, size), blocks, np.int64), np.zeros(2, np.int64))

    def run(self, run: Run, control: RunControl, fraction=lambda done: done, workers: int = 1) -> int:
        """Search every finger whose bound stays below ``run.limit`` (read at every step: ``run.on_leaf``
        may lower it); returns the nodes expanded. ``control`` may raise Stop (``run.frontier()`` then holds
        what is left). ``fraction`` maps the share of the root's children done to the progress reported.
        ``workers`` > 1: the root's children are dealt out in turn to that many threads (the compiled search
        releases the GIL), which share the limit; ``on_leaf`` and reports are then made one at a time."""
        workers = max(1, workers)
        shares = [np.array([w, workers], np.int64) for w in range(workers)]
        states = [self._new_state() for _ in shares]
        run.frames = _Pending(states, self.root_bound)
        placed = self.placements
        control.report(fraction(0.0), float(run.limit[-1]), placed)
        common = (self.problems_tuple, self.weights, self.sizes, self.space.num_blocks, self.choices, self.n_choices,
                  np.asarray(run.current, np.int64), np.asarray(run.keeps_stiff, np.bool_),
                  np.asarray(self.space.stiff_positions, np.bool_), np.asarray(run.releasable, np.bool_), run.limit,
                  np.asarray(run.stock, np.int64), np.asarray(run.stiff_stock, np.int64))
        lock, stopped = threading.Lock(), []

        def search(share, state) -> None:
            arguments = common + (share, self.root_bound, self.root_poses, self.root_alphas, state, CHECK_EVERY)
            path, swapped, leaf_costs, leaf_bases = state[10], state[11], state[18], state[19]
            while not stopped:
                code = _search_front(*arguments)
                with lock:
                    self.placements = placed + sum(int(st[-1][1]) for st in states)
                    try:
                        if code == LEAF:
                            run.on_leaf(Candidate(path.copy(), swapped.copy(), leaf_costs.copy(), leaf_bases.copy(),
                                                  float(self.weights @ leaf_costs)))
                        elif code == CHECKPOINT:
                            control.report(fraction(_done(states)), float(run.limit[-1]), self.placements)
                        else:
                            return
                    except Stop as stop:
                        stopped.append(stop)
                        return

        if workers == 1:
            search(shares[0], states[0])
        else:
            with ThreadPoolExecutor(max_workers=workers) as pool:
                for future in [pool.submit(search, share, state) for share, state in zip(shares, states)]:
                    future.result()
        if stopped:
            raise stopped[0]
        return sum(int(state[-1][0]) for state in states)


def _done(states) -> float:
    """The share of the root's children the searches have finished."""
    shares = []
    for state in states:
        top, started, next_child, count = state[:4]
        if not started[0]:
            shares.append(0.0)
        elif top[0] < 0:
            shares.append(1.0)
        else:
            shares.append(max(int(next_child[0]) - 1, 0) / count[0] if count[0] else 1.0)
    return min(float(np.mean(shares)), 1.0)


class _Pending:
    """The children the compiled searches (their states) have not visited yet, and where the stock stopped
    them."""

    def __init__(self, states, root_bound):
        self.states, self.root_bound = states, root_bound

    def stock_needed(self) -> tuple[np.ndarray, np.ndarray]:
        least = np.min([state[-2] for state in self.states], axis=0)
        return least[0], least[1]

    def frontier(self) -> list[tuple[float, int]]:
        out = []
        for state in self.states:
            top, started, next_child, count, bounds, _, _, afters = state[:8]
            if not started[0]:
                out.append((float(self.root_bound), 0))
            for level in range(int(top[0]) + 1):
                out += [(float(bounds[level, k]), int(afters[level, k]))
                        for k in range(next_child[level], count[level])]
        return out


class Front:
    """The best candidate per swap budget 0..N so far (``best``, ``chosen``), and the limit a search
    prunes with. A finger with v swaps matters only below min(best[v], ``ceiling[v]``) (a caller's need), and
    not at all where ``floor[v]`` (a proven bound on every finger with at most v swaps) reaches that: a
    prefix with u swaps is searched below the largest such cap over v >= u."""

    def __init__(self, blocks: int, ceiling=None, floor=None):
        self.best = np.full(blocks + 1, np.inf)
        self.chosen: list[Candidate | None] = [None] * (blocks + 1)
        self.ceiling = np.full(blocks + 1, np.inf) if ceiling is None else np.asarray(ceiling, float).copy()
        self.floor = np.full(blocks + 1, -np.inf) if floor is None else np.asarray(floor, float)
        self.limit = np.empty(blocks + 1)
        self.tighten()

    def tighten(self, ceiling=None) -> None:
        """Lower the ceiling (when given) and recompute the limit in place (searches hold it)."""
        if ceiling is not None:
            np.minimum(self.ceiling, ceiling, out=self.ceiling)
        cap = np.minimum(self.best, self.ceiling)
        self.limit[:] = np.maximum.accumulate(np.where(self.floor < cap, cap, -np.inf)[::-1])[::-1]

    def record(self, candidate: Candidate) -> None:
        improved = False
        for s in range(candidate.swaps, len(self.best)):
            if candidate.cost < self.best[s]:
                self.best[s], self.chosen[s] = candidate.cost, candidate
                improved = True
        if improved:
            self.tighten()


def within(shapes, stiff_used, stock, stiff_stock) -> bool:
    """Whether a finger's blocks (shapes, which of them use a stiff block) fit the stock."""
    counts = np.bincount(shapes, minlength=len(stock))
    stiff = np.bincount(shapes[stiff_used], minlength=len(stock))
    return bool(np.all(counts <= stock) and np.all(stiff <= stiff_stock))


@dataclass
class FrontResult:
    """Outcome of ``solve_finger_front`` (scipy style), per swap budget s = 0..N (index s).

    ``fun[s]``: lowest weighted objective [m] found with at most s swaps (inf: none found);
    ``lower_bound[s]``: proven lower bound on it (= ``fun[s]`` when ``optimal[s]``); ``shapes[s]`` the
    finger's shape indices (-1 when none); ``swapped[s]`` the positions that change their block;
    ``bases[s]`` each object's base index; ``object_costs[s]`` each object's eq. (3) cost [m];
    ``swaps[s]``: the swaps that finger actually needs; ``candidates[s]`` the same as a ``Candidate``.
    """

    fun: np.ndarray
    lower_bound: np.ndarray
    optimal: np.ndarray
    shapes: np.ndarray
    swapped: np.ndarray
    bases: np.ndarray
    object_costs: np.ndarray
    swaps: np.ndarray
    candidates: list
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
            costs[i], bases[i] = _leaf_exact(problem, *state, shapes[-1], np.inf)
    return costs, bases


def _root_bound(problems, weights, roots, scratch, blocks) -> float:
    """The weighted sum of each object's bound over every first block at any of its bases: every finger
    costs at least this."""
    total = 0.0
    for weight, problem, (poses, alphas, alive) in zip(weights, problems, roots):
        out, per_base = np.empty(problem[4][0]), np.empty((problem[4][0], len(alive)))
        _node_bounds(problem, 0, poses, alphas, alive, blocks == 1, scratch, out, per_base)
        total += weight * out.min()
    return float(total)


def _check_limits(space, current, stock, stiff_stock):
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
    return current, stock, stiff_stock


def solve_finger_front(targets, weights, space: DesignSpace, *, current=None, stock=None, stiff_stock=None,
                       time_budget=None, callback=None, options=None, starts=(), floor: float = 0.0,
                       search: FingerFrontSearch | None = None, keeps_stiff=None, releasable=None,
                       extra=(), workers: int = 2) -> FrontResult:
    """Minimise sum_i weights[i] * cost_i over the fingers of ``space`` (planar, unlimited: its lookahead
    fields are the prepared ones), for every swap budget 0..N from ``current`` (N shape indices; -1 or None:
    every position counts as a swap). ``stock`` / ``stiff_stock`` (one count per shape) limit how often a
    shape may be used (stiff positions draw on ``stiff_stock``). ``callback(Progress)`` may raise
    StopIteration; ``time_budget`` [s]. ``starts``: complete fingers (shape indices) to prune with from the
    start, e.g. each object's own optimum; each is also tried with every subset of its positions as now.
    ``floor``: a proven lower bound on every finger [m] (e.g. the weighted sum of the objects' own certified
    optima), reported where the search's own bound is lower. ``search``: the prepared ``FingerFrontSearch``
    of the same targets (built here when None); ``keeps_stiff`` / ``releasable``: see ``Run`` (default: a
    kept block at a forced-stiff position is stiff, nothing releasable); ``extra``: ``Candidate`` fingers
    outside the design space to consider too (a finger as built with its rotations); ``workers``: threads
    that share the search. Certified unless stopped (then every budget carries a proven bound)."""
    search = FingerFrontSearch(targets, weights, space, options) if search is None else search
    current, stock, stiff_stock = _check_limits(space, current, stock, stiff_stock)
    blocks = space.num_blocks
    keeps_stiff = space.stiff_positions.copy() if keeps_stiff is None else np.asarray(keeps_stiff, bool)
    releasable = np.zeros(blocks, bool) if releasable is None else np.asarray(releasable, bool)
    control = RunControl(time_budget, callback)
    front = Front(blocks)
    for seed in _mixtures(current, starts):  # first fingers to prune with, for every budget
        if np.any(seed < 0):
            continue
        swapped = seed != current
        if within(seed, space.stiff_positions | (~swapped & keeps_stiff), stock, stiff_stock):
            costs, bases = search.evaluate(seed)
            if np.all(np.isfinite(costs)):
                front.record(Candidate(seed.copy(), swapped, costs, bases, float(search.weights @ costs)))
    for candidate in extra:
        front.record(candidate)
    run = Run(current, keeps_stiff, releasable, stock, stiff_stock, front.limit, front.record)
    status, placed, nodes = Status.CERTIFIED, search.placements, 0
    try:
        nodes = search.run(run, control, workers=workers)
    except Stop as stop:
        status = stop.status
    lower = front.best.copy()
    for bound, after in run.frontier():  # prefixes not yet visited
        lower[after:] = np.minimum(lower[after:], bound)
    lower = np.maximum(lower, floor)
    return front_result(front, lower, status, nodes=nodes, nfev=search.placements - placed, elapsed=control.elapsed,
                        objects=len(targets))


def front_result(front: Front, lower, status: Status, *, nodes: int, nfev: int, elapsed: float,
                 objects: int) -> FrontResult:
    """The result of a finished or stopped front: ``lower`` the proven bound per budget."""
    best, blocks = front.best, len(front.best) - 1
    optimal = np.full(blocks + 1, status == Status.CERTIFIED) | (best <= lower + 1e-12)
    found = np.isfinite(best)
    if status == Status.CERTIFIED and not found[-1]:
        status = Status.INFEASIBLE
    message = MESSAGES[status] if status != Status.CERTIFIED else "every swap budget certified"
    message += f" (best {best[-1]:.6g} m with up to {blocks} swaps)" if found[-1] else ""
    chosen = front.chosen
    none = np.full(blocks, -1, np.int64)
    return FrontResult(
        fun=best, lower_bound=np.where(optimal, best, lower), optimal=optimal,
        shapes=np.array([none if c is None else c.shapes for c in chosen]),
        swapped=np.array([np.zeros(blocks, bool) if c is None else c.swapped for c in chosen]),
        bases=np.array([np.full(objects, -1) if c is None else c.bases for c in chosen], np.int64),
        object_costs=np.array([np.full(objects, np.inf) if c is None else c.costs for c in chosen]),
        swaps=np.array([-1 if c is None else c.swaps for c in chosen]), candidates=list(chosen),
        success=bool(found[-1]), status=status, message=message, nit=nodes, nfev=nfev, solve_time=elapsed)
