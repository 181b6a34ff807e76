"""Certified finger design: depth-first branch and bound over (base, block 1, ..., block N), compiled.

A finger is built from its base. Once blocks 1..k are placed, their centerline samples are fixed and so
is each contour point's distance ``a`` to them. In piecewise constant curvature, the next block and every
suffix after it have a shape in the frame of the prefix's end that does not depend on the prefix. So for
each block position and each shape the next block may take, ``LookaheadFields`` hold, once per design
space, lower bounds on the distance from any point of that frame to (the next block's samples and every
suffix that can follow it) and to (the tip periphery points any such suffix can end at), on a grid
whose error is accounted for. With ``b`` that bound for a contour point, the point's final distance is at
least min(a, b), so its term |d - r| is at least max(min(a, b) - r, 0); the tip term is bounded by the
tip field. Summed, this bounds every finger that continues the prefix with that next block, for all next
blocks in one vectorised pass per node; a complete finger is bounded by its objective. A third field, the
cover, is an upper bound on the distance to the continuous centerline of *every* such finger: a contour point
``g`` from the object and closer to the node than the collision threshold minus ``g`` proves that all of
them collide, and the next block is dropped (this prunes the fingers that would have to pass through the
object long before a block of theirs touches it).

The search visits children in the order of their bounds and drops every child whose bound reaches the
best collision-free finger found, so when it ends that finger is the optimum (``Status.CERTIFIED``). The
first finger comes from two beams over the same tree (16 prefixes per level, always run to the end, then
``beam_width`` while the budget allows) improved by local search; should they find none, rounds search
below a cost ceiling that grows by ``ceiling_growth`` until a finger is found under it (a round without one
proves the optimum is at least the smallest bound it cut).
With a first finger in hand, the first level's children are dealt out to ``workers`` threads that share
only the lowest cost found. Collision is the exact rule of ``planner.clearance``, checked for a block when
the search enters it.
Stopped early (time budget, callback), the run returns the best finger so far and a proven lower bound:
the smallest bound of the children not yet visited.
"""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

from planner.clearance import RESOLUTION, block_min_distance
from planner.objectives import COLLISION_PENALTY, ShapeTarget
from planner.optimize.lookahead import SAMPLES_PER_BLOCK, block_shapes, lookahead_fields
from planner.optimize.local_search import polish
from planner.optimize.pso import design_costs
from planner.optimize.result import DesignOptimizeResult, RunControl, Status, Stop, make_result
from planner.optimize.space import DesignSpace

DEFAULT_OPTIONS = {
    "field_spacing": 5e-4,  # grid step of the lookahead fields [m] (half of it for the last block's)
    "region_spacing": 2e-4,  # grid step of the suffix regions they are built from [m]
    "expansions_per_check": 2000,  # nodes expanded between time-budget / callback checks
    "ceiling_growth": 1.3,  # factor between the cost ceilings of successive rounds
    "beam_width": 32,  # collision-free prefixes per level of the second beam (the first keeps 16)
    "polish": True,  # improve the beam's finger by block-by-block local search before the search starts
    "workers": 2,  # threads that share the search once a first finger is in hand (the first level is split)
}
FIRST_BEAM_WIDTH = 16  # the beam that always runs to the end, so that every run returns a finger


# ------------------------------------------------------------------------------------------ search
@njit(cache=True, nogil=True)
def _place(pose, x, z):
    cos, sin = np.cos(pose[2]), np.sin(pose[2])
    return pose[0] + x * cos + z * sin, pose[1] - x * sin + z * cos


@njit(cache=True, nogil=True)
def _beyond_grid(discs, reach, radius, x, z, own, count, acc, last):
    """Add to acc[:count] the bound of one term whose point (x, z), in the frame of the next block's start,
    lies beyond the grid: from each next block's discs (``discs``: that position's rows of the fields'
    discs; ``last``: the last position, no blocks after). ``own``: the point's distance to the prefix;
    infinite for the tip term. Square roots rather than hypot, so that the loops vectorise."""
    if own <= radius:  # the term's bound is 0 whatever comes next
        return
    if own < np.inf and own <= np.sqrt(x * x + z * z) - reach:  # every later sample lies within reach of
        for k in range(count):  # the frame's origin: the prefix stays the nearest, whatever comes next
            acc[k] += own - radius
        return
    for k in range(count):
        if own == np.inf:  # the tip periphery point: exact after the last block
            value = np.sqrt((x - discs[k, 6]) ** 2 + (z - discs[k, 7]) ** 2) - discs[k, 8]
        else:
            nearest = np.sqrt((x - discs[k, 0]) ** 2 + (z - discs[k, 1]) ** 2) - discs[k, 2]
            if not last:  # the blocks after it lie within their reach of its end
                nearest = min(nearest, np.sqrt((x - discs[k, 3]) ** 2 + (z - discs[k, 4]) ** 2) - discs[k, 5])
            value = min(own, nearest) - radius
        if value > 0.0:
            acc[k] += value


@njit(cache=True, nogil=True)
def _lookahead(problem, depth, pose, alpha, acc):
    """acc[k] = lower bound on every collision-free finger continuing this node with next shape
    choices[depth, k]; infinite when a contour point proves that every such finger collides (the cover
    field: all of them pass closer to that point than the collision threshold minus its distance to the
    object). A contour point nearer to the prefix than to anything that can follow, and too far from the
    object for any cover to prove a collision, adds the same to all (``node_minima`` of the fields)."""
    contour, end_point, radius, n_choices = problem[0], problem[1], problem[2], problem[4]
    body, tip, layout, discs, threshold, gap, cover = (problem[8], problem[9], problem[10], problem[11], problem[18],
                                                       problem[23], problem[24])
    nearest_any, cover_least = problem[26][problem[25][depth]:], problem[27][problem[25][depth]:]
    count = n_choices[depth]
    spacing = layout[depth, 6]
    offset, rows, cols, x0, z0 = (int(layout[depth, 0]), int(layout[depth, 1]), int(layout[depth, 2]),
                                  layout[depth, 3], layout[depth, 4])
    cos, sin = np.cos(pose[2]), np.sin(pose[2])
    acc[:count] = 0.0
    common = 0.0  # the terms that are the same for every next shape
    for q in range(contour.shape[0] + 1):
        if q < contour.shape[0]:
            dx, dz = contour[q, 0] - pose[0], contour[q, 1] - pose[1]
            own = alpha[q]
        else:  # the tip term's target
            dx, dz = end_point[0] - pose[0], end_point[1] - pose[1]
            own = np.inf
        x, z = dx * cos - dz * sin, dx * sin + dz * cos
        b = int(np.round((x - x0) / spacing))
        a = int(np.round((z - z0) / spacing))
        if a < 0 or b < 0 or a >= rows or b >= cols:
            _beyond_grid(discs[depth], layout[depth, 5], radius, x, z, own, count, acc, False)
            continue
        node_offset = np.hypot(x - (x0 + b * spacing), z - (z0 + a * spacing))
        start = offset + (a * cols + b) * count
        if q < contour.shape[0]:
            doom = threshold - 2.0 * RESOLUTION - gap[q] - node_offset  # a cover below this proves a collision
            node = a * cols + b
            if own <= nearest_any[node] - node_offset and cover_least[node] >= doom:
                common += max(own - radius, 0.0)
                continue
            for k in range(count):
                if cover[start + k] < doom:
                    acc[k] = np.inf
                value = min(own, body[start + k] - node_offset) - radius
                if value > 0.0:
                    acc[k] += value
        else:
            for k in range(count):
                value = tip[start + k] - node_offset
                if value > 0.0:
                    acc[k] += value
    for k in range(count):
        acc[k] += common


@njit(cache=True, nogil=True)
def _leaf_bounds(problem, depth, pose, alpha, acc):
    """acc[k] = lower bound on the objective of the complete finger with last block choices[depth, k];
    infinite when the cover proves that it collides (as in ``_lookahead``): most children that pass through
    the object are dropped here, not by their exact evaluation. Contour points already within r of the
    prefix add nothing, and a point nearer to the prefix than to any last block adds the same to all
    (``node_minima`` of the fields; its cover is not consulted, which can only cost an exact evaluation).
    Points outer, blocks inner: the inner loop runs over contiguous field values."""
    contour, end_point, radius, n_choices = problem[0], problem[1], problem[2], problem[4]
    body, tip, layout, discs = problem[8], problem[9], problem[10], problem[11]
    threshold, gap, cover, nearest_any = problem[18], problem[23], problem[24], problem[26][problem[25][depth]:]
    count = n_choices[depth]
    spacing = layout[depth, 6]
    offset, rows, cols, x0, z0 = (int(layout[depth, 0]), int(layout[depth, 1]), int(layout[depth, 2]),
                                  layout[depth, 3], layout[depth, 4])
    cos, sin = np.cos(pose[2]), np.sin(pose[2])
    dx, dz = end_point[0] - pose[0], end_point[1] - pose[1]
    x, z = dx * cos - dz * sin, dx * sin + dz * cos
    b, a = int(np.round((x - x0) / spacing)), int(np.round((z - z0) / spacing))
    acc[:count] = 0.0
    if a < 0 or b < 0 or a >= rows or b >= cols:
        _beyond_grid(discs[depth], layout[depth, 5], radius, x, z, np.inf, count, acc, True)
    else:
        node_offset = np.hypot(x - (x0 + b * spacing), z - (z0 + a * spacing))
        start = offset + (a * cols + b) * count
        for k in range(count):
            acc[k] = max(tip[start + k] - node_offset, 0.0)
    common = 0.0  # the terms that are the same for every last block
    for q in range(contour.shape[0]):
        own = alpha[q]
        if own <= radius:
            continue
        dx, dz = contour[q, 0] - pose[0], contour[q, 1] - pose[1]
        x, z = dx * cos - dz * sin, dx * sin + dz * cos
        b, a = int(np.round((x - x0) / spacing)), int(np.round((z - z0) / spacing))
        if a < 0 or b < 0 or a >= rows or b >= cols:
            _beyond_grid(discs[depth], layout[depth, 5], radius, x, z, own, count, acc, True)
            continue
        node_offset = np.hypot(x - (x0 + b * spacing), z - (z0 + a * spacing))
        if own <= nearest_any[a * cols + b] - node_offset:  # no last block comes nearer than the prefix
            common += own - radius
            continue
        start = offset + (a * cols + b) * count
        shift = node_offset + radius
        most = own - radius
        doom = threshold - 2.0 * RESOLUTION - gap[q] - node_offset  # a cover below this proves a collision
        for k in range(count):
            value = max(min(most, body[start + k] - shift), 0.0)
            acc[k] += np.inf if cover[start + k] < doom else value
    for k in range(count):
        acc[k] += common


@njit(cache=True, nogil=True)
def _placed_samples(problem, pose, s):
    """Block s's samples and the centre of the disc that holds them, placed at ``pose``."""
    samples, disc = problem[5], problem[7]
    cos, sin = np.cos(pose[2]), np.sin(pose[2])
    world = np.empty((samples.shape[1], 2))
    for m in range(samples.shape[1]):
        world[m, 0] = pose[0] + samples[s, m, 0] * cos + samples[s, m, 1] * sin
        world[m, 1] = pose[1] - samples[s, m, 0] * sin + samples[s, m, 1] * cos
    return world, pose[0] + disc[s, 0] * cos + disc[s, 1] * sin, pose[1] - disc[s, 0] * sin + disc[s, 1] * cos


@njit(cache=True, nogil=True)
def _nearer(qx, qz, world, distance):
    """min(distance, distance from (qx, qz) to the nearest of the points ``world``); squares inside."""
    nearest = distance * distance
    for m in range(world.shape[0]):
        ex, ez = qx - world[m, 0], qz - world[m, 1]
        nearest = min(nearest, ex * ex + ez * ez)
    return np.sqrt(nearest)


@njit(cache=True, nogil=True)
def _leaf_cost(problem, pose, alpha, s, cutoff):
    """Objective of the complete finger ending with block s at ``pose`` (alpha: the prefix's contour
    distances); -1 when a sample is provably closer to the object than the collision threshold (as
    ``_too_close``). One pass that stops as soon as either is decided: a partial sum that reaches
    ``cutoff`` is returned as it is (still a lower bound: every term is >= 0)."""
    contour, end_point, radius, ends, disc = problem[0], problem[1], problem[2], problem[6], problem[7]
    gap, threshold = problem[23], problem[18]
    ex, ez = _place(pose, ends[s, 0], ends[s, 1])
    eh = pose[2] + ends[s, 2]
    total = np.hypot(ex + radius * np.cos(eh) - end_point[0], ez - radius * np.sin(eh) - end_point[1])
    world, centre_x, centre_z = _placed_samples(problem, pose, s)
    for q in range(contour.shape[0]):
        qx, qz = contour[q, 0], contour[q, 1]
        distance = alpha[q]
        reach = distance + disc[s, 2]
        dx, dz = qx - centre_x, qz - centre_z
        if dx * dx + dz * dz < reach * reach:
            distance = _nearer(qx, qz, world, distance)
            if distance + gap[q] < threshold - RESOLUTION:
                return -1.0
        total += abs(distance - radius)
        if total >= cutoff:
            return total
    return total


@njit(cache=True, nogil=True)
def _block_update(problem, pose, alpha, s, out):
    """out = contour distances after adding block s at pose (alpha: before). Points farther from the
    block's sample disc than their current distance are skipped."""
    contour, disc = problem[0], problem[7]
    world, centre_x, centre_z = _placed_samples(problem, pose, s)
    out[:] = alpha
    for q in range(contour.shape[0]):
        qx, qz = contour[q, 0], contour[q, 1]
        reach = out[q] + disc[s, 2]
        dx, dz = qx - centre_x, qz - centre_z
        if dx * dx + dz * dz < reach * reach:
            out[q] = _nearer(qx, qz, world, out[q])


@njit(cache=True, nogil=True)
def _too_close(problem, alpha):
    """True when a centerline sample is provably closer to the object than the collision threshold: within
    ``threshold - gap`` of a contour point that lies ``gap`` from the object (a quick, exact reject)."""
    gap, threshold = problem[23], problem[18]
    for q in range(alpha.shape[0]):
        if alpha[q] + gap[q] < threshold - RESOLUTION:
            return True
    return False


@njit(cache=True, nogil=True)
def _expand(problem, depth, pose, alpha, best, limits, out_bound, out_shape, out_base, out_pose, start, base, path,
            counts, acc):
    """Children of a node with ``depth`` blocks placed whose bound is below min(best, ceiling limits[0]),
    from index ``start`` of the out arrays; returns the new end index. Complete fingers get their objective.
    The smallest bound cut by the ceiling alone goes to limits[1]."""
    choices, n_choices, ends = problem[3], problem[4], problem[6]
    stock, stiff_stock, stiff_positions, limited = problem[12], problem[13], problem[14], problem[15]
    blocks = choices.shape[0]
    cutoff = min(best, limits[0])
    if depth + 1 == blocks:
        _leaf_bounds(problem, depth, pose, alpha, acc)
    else:
        _lookahead(problem, depth, pose, alpha, acc)
    n = start
    for k in range(n_choices[depth]):
        if acc[k] >= cutoff:
            if acc[k] < best:
                limits[1] = min(limits[1], acc[k])
            continue
        s = choices[depth, k]
        if limited:
            if counts[s] >= stock[s]:
                continue
            if stiff_positions[depth]:
                stiff_used = 0
                for j in range(depth):
                    if stiff_positions[j] and path[j + 1] == s:
                        stiff_used += 1
                if stiff_used >= stiff_stock[s]:
                    continue
        ex, ez = _place(pose, ends[s, 0], ends[s, 1])
        eh = pose[2] + ends[s, 2]
        bound = acc[k]
        if depth + 1 == blocks:  # a complete finger: its objective
            bound = _leaf_cost(problem, pose, alpha, s, cutoff)
            if bound < 0.0:  # too close to the object
                continue
            if bound >= cutoff:
                if bound < best:
                    limits[1] = min(limits[1], bound)
                continue
        out_bound[n] = bound
        out_shape[n] = s
        out_base[n] = base
        out_pose[n, 0], out_pose[n, 1], out_pose[n, 2] = ex, ez, eh
        n += 1
    return n


@njit(cache=True, nogil=True)
def _search(problem, state, max_expansions):
    """Run the depth-first search from ``state`` for at most ``max_expansions`` node expansions.

    Returns 1 when the round is complete, 0 when interrupted.
    """
    choices = problem[3]
    field, frame, threshold, cap, theta, length, base_x = problem[16:23]
    (depth_box, pointer, count, order, bound, shape, base, pose, node_pose, node_alpha, path, counts, best,
     best_path, stats, limits, acc, incumbent) = state
    blocks = choices.shape[0]
    expansions = 0
    while True:
        depth = depth_box[0]
        if pointer[depth] >= count[depth]:
            if depth == 0:
                return 1
            counts[path[depth]] -= 1  # leave the block placed at this depth
            path[depth] = -1
            depth_box[0] = depth - 1
            continue
        i = order[depth, pointer[depth]]
        pointer[depth] += 1
        if bound[depth, i] >= min(best[0], incumbent[0], limits[0]):  # sorted: the rest are no better
            if bound[depth, i] < min(best[0], incumbent[0]):  # cut by the round's ceiling: remember the bound
                limits[1] = min(limits[1], bound[depth, i])
            pointer[depth] = count[depth]
            continue
        s = shape[depth, i]
        if depth == 0:
            node_pose[0, 0], node_pose[0, 1], node_pose[0, 2] = base_x[base[0, i]], 0.0, 0.0
            for q in range(node_alpha.shape[1]):
                node_alpha[0, q] = np.hypot(problem[0][q, 0] - base_x[base[0, i]], problem[0][q, 1])
        leaf = depth + 1 == blocks
        if not leaf:  # (a complete finger passed this test when it was generated)
            _block_update(problem, node_pose[depth], node_alpha[depth], s, node_alpha[depth + 1])
            if _too_close(problem, node_alpha[depth + 1]):
                continue
        stats[0] += 1
        clearance = block_min_distance(field, frame, node_pose[depth, 0], node_pose[depth, 1], node_pose[depth, 2],
                                       theta[s], length[s], cap, threshold, False)
        if clearance < threshold - RESOLUTION:
            continue
        if leaf:  # the best finger below this node (children sorted, the rest is no better)
            best[0] = bound[depth, i]
            incumbent[0] = min(incumbent[0], best[0])  # a race between workers leaves some finger's cost
            best_path[:] = path
            if depth == 0:
                best_path[0] = base[0, i]
            best_path[blocks] = s
            pointer[depth] = count[depth]
            continue
        if depth == 0:
            path[0] = base[0, i]
        path[depth + 1] = s
        counts[s] += 1
        node_pose[depth + 1, :] = pose[depth, i]
        depth_box[0] = depth + 1
        end = _expand(problem, depth + 1, node_pose[depth + 1], node_alpha[depth + 1], min(best[0], incumbent[0]),
                      limits, bound[depth + 1], shape[depth + 1], base[depth + 1], pose[depth + 1], 0, path[0], path,
                      counts, acc)
        count[depth + 1] = end
        pointer[depth + 1] = 0
        stats[1] += problem[4][depth + 1]
        order[depth + 1, :end] = np.argsort(bound[depth + 1, :end], kind="mergesort")
        expansions += 1
        if expansions >= max_expansions:
            return 0


@njit(cache=True, nogil=True)
def _start(problem, state):
    """Root children: every base with every first block, below the ceiling."""
    contour, base_x = problem[0], problem[22]
    (depth_box, pointer, count, order, bound, shape, base, pose, node_pose, node_alpha, path, counts, best,
     best_path, stats, limits, acc, incumbent) = state
    path[:] = -1
    counts[:] = 0
    limits[1] = np.inf
    n = 0
    root_alpha = np.empty(contour.shape[0])
    root_pose = np.zeros(3)
    for b in range(base_x.shape[0]):
        for q in range(contour.shape[0]):
            root_alpha[q] = np.hypot(contour[q, 0] - base_x[b], contour[q, 1])
        root_pose[0] = base_x[b]
        n = _expand(problem, 0, root_pose, root_alpha, best[0], limits, bound[0], shape[0], base[0], pose[0], n, b, path,
                    counts, acc)
        stats[1] += problem[4][0]
    count[0] = n
    pointer[0] = 0
    depth_box[0] = 0
    order[0, :n] = np.argsort(bound[0, :n], kind="mergesort")


def _lower_bound(states) -> float:
    """Smallest bound among the children not yet visited or cut by the round's ceiling (and the best
    finger), over the workers' states: a proven lower bound for this round."""
    lowest = np.inf
    for state in states:
        depth_box, pointer, count, order, bound = state[:5]
        lowest = min(lowest, state[12][0], state[15][1])
        for level in range(depth_box[0] + 1):
            if pointer[level] < count[level]:
                lowest = min(lowest, float(bound[level, order[level, pointer[level]]]))
    return lowest


def _fraction(states) -> float:
    done = []
    for state in states:
        pointer, count = state[1], state[2]
        inner = pointer[1] / count[1] if state[0][0] >= 1 and count[1] else 0.0
        done.append(min((max(pointer[0] - 1, 0) + inner) / count[0], 1.0) if count[0] else 1.0)
    return float(np.mean(done))


def _split(state, workers: int) -> list[tuple]:
    """The root's children dealt out in turn to ``workers`` copies of a started state (so each gets a share
    of every bound range); the copies share the incumbent, nothing else."""
    workers = min(workers, int(state[2][0]))
    if workers < 2:
        return [state]
    shares = []
    for w in range(workers):
        share = tuple(a if a is state[17] else a.copy() for a in state)
        mine = state[3][0, w:state[2][0]:workers]
        share[3][0, : len(mine)] = mine
        share[2][0] = len(mine)
        if w:
            share[14][:] = 0  # the root's counts stay with the first share
        shares.append(share)
    return shares


def _search_shares(problem, shares, chunk: int, control: RunControl) -> tuple[Status | None, int]:
    """Run the search of every share in its own thread (the compiled search releases the GIL) until all are
    complete or the control stops them; returns the stop status (None: complete) and the checks made."""
    lock, stopped, checks = threading.Lock(), [], [0]

    def check() -> bool:  # between chunks: one report for all shares; True when the run must end
        with lock:
            checks[0] += 1
            if not stopped:
                try:
                    control.report(_fraction(shares), min(s[12][0] for s in shares), sum(int(s[14][1]) for s in shares))
                except Stop as stop:
                    stopped.append(stop.status)
            return bool(stopped)

    def run(share) -> None:
        while not _search(problem, share, chunk):
            if check():
                return

    with ThreadPoolExecutor(max_workers=len(shares)) as pool:
        for future in [pool.submit(run, share) for share in shares]:
            future.result()
    if not stopped:
        check()  # the last report; a stop now still ends the run as stopped
    return (stopped[0] if stopped else None), checks[0]


def _collides(problem, pose, s) -> bool:
    field, frame, threshold, cap, theta, length = problem[16:22]
    distance = block_min_distance(field, frame, pose[0], pose[1], pose[2], theta[s], length[s], cap, threshold, False)
    return distance < threshold - RESOLUTION


def _moved(problem, pose, s) -> np.ndarray:
    x, z = _place(pose, problem[6][s, 0], problem[6][s, 1])
    return np.array([x, z, pose[2] + problem[6][s, 2]])


def _beam(problem, space: DesignSpace, width: int, control: RunControl, timed: bool):
    """A good collision-free finger to start from (cost, [base, shapes...]) or None: a beam over the same
    tree that keeps, per level, the ``width`` collision-free children with the lowest bounds, those whose
    straightest completion also stays clear first. The callback hears from it once per level; ``timed``
    False: it runs to the end whatever the time budget."""
    contour, choices, n_choices, base_x = problem[0], problem[3], problem[4], problem[22]
    blocks = space.num_blocks
    straightest = [int(c[np.argmin(np.abs(space.theta[c]))]) for c in space.choices]
    size = max(len(base_x) * n_choices[0], n_choices.max())
    out_bound, out_shape, out_base = np.zeros(size), np.zeros(size, np.int64), np.zeros(size, np.int64)
    out_pose, acc = np.zeros((size, 3)), np.zeros(n_choices.max())
    limits = np.array([np.inf, np.inf])
    beam = [(np.array([x, 0.0, 0.0]), np.hypot(contour[:, 0] - x, contour[:, 1]), [b]) for b, x in enumerate(base_x)]
    for depth in range(blocks):
        control.report(0.0, np.inf, 0, timed=timed)
        candidates = []
        for pose, alpha, path in beam:
            path_array = np.array(path + [-1] * (blocks + 1 - len(path)), dtype=np.int64)
            counts = np.bincount(path_array[1:][path_array[1:] >= 0], minlength=len(space.theta)).astype(np.int64)
            n = _expand(problem, depth, pose, alpha, np.inf, limits, out_bound, out_shape, out_base, out_pose, 0,
                        path[0], path_array, counts, acc)
            candidates += [(out_bound[j], int(out_shape[j]), pose, alpha, path) for j in range(n)]
        candidates.sort(key=lambda c: c[0])
        kept, clear = [], 0
        for bound, s, pose, alpha, path in candidates:
            child_alpha = np.empty(len(contour))
            _block_update(problem, pose, alpha, s, child_alpha)
            if _too_close(problem, child_alpha) or _collides(problem, pose, s):
                continue
            tail_pose, doomed = _moved(problem, pose, s), False
            for t in straightest[depth + 1:]:
                if _collides(problem, tail_pose, t):
                    doomed = True
                    break
                tail_pose = _moved(problem, tail_pose, t)
            kept.append((doomed, bound, _moved(problem, pose, s), child_alpha, path + [s]))
            clear += not doomed
            if clear >= width:
                break
        if not kept:
            return None
        kept.sort(key=lambda k: (k[0], k[1]))
        beam = [(pose, alpha, path) for _, _, pose, alpha, path in kept[:width]]
        if depth == blocks - 1:
            return kept[0][1], kept[0][4]
    return None


def _check_options(options) -> dict:
    unknown = set(options or {}) - set(DEFAULT_OPTIONS)
    if unknown:
        raise ValueError(f"options: unknown keys {sorted(unknown)}; known: {sorted(DEFAULT_OPTIONS)}")
    settings = DEFAULT_OPTIONS | (options or {})
    for key in ("field_spacing", "region_spacing"):
        if not (np.isfinite(settings[key]) and 0 < settings[key] <= 5e-3):
            raise ValueError(f"options[{key!r}] must be a length in (0, 0.005] m, got {settings[key]!r}")
    if not (isinstance(settings["expansions_per_check"], (int, np.integer)) and settings["expansions_per_check"] >= 1):
        raise ValueError("options['expansions_per_check'] must be an integer >= 1")
    if not (np.isfinite(settings["ceiling_growth"]) and settings["ceiling_growth"] > 1):
        raise ValueError("options['ceiling_growth'] must be > 1")
    for key in ("beam_width", "workers"):
        if not (isinstance(settings[key], (int, np.integer)) and settings[key] >= 1):
            raise ValueError(f"options[{key!r}] must be an integer >= 1, got {settings[key]!r}")
    return settings


def search_problem(target: ShapeTarget, space: DesignSpace, settings: dict | None = None) -> tuple:
    """Everything the compiled search reads, as one tuple (see the kernels for the order)."""
    settings = settings or DEFAULT_OPTIONS
    body = target.body
    shapes = block_shapes(space, body.cap_length)
    fields = lookahead_fields(shapes, space, body.radius, settings["field_spacing"], settings["region_spacing"])
    choices = np.full((space.num_blocks, max(len(c) for c in space.choices)), -1, dtype=np.int64)
    for k, c in enumerate(space.choices):
        choices[k, : len(c)] = c
    n_choices = np.array([len(c) for c in space.choices], dtype=np.int64)
    contour = np.ascontiguousarray(target.points[:, [0, 2]])
    limited = space.stock is not None
    stock = np.asarray(space.stock if limited else np.zeros(len(space.theta)), np.int64)
    stiff_stock = np.asarray(space.stiff_stock if limited else stock, np.int64)
    return (
        contour, np.asarray(target.end_point[[0, 2]], float), float(body.radius), choices, n_choices,
        shapes.samples, shapes.ends, shapes.disc, fields.body, fields.tip, fields.layout, fields.discs,
        stock, stiff_stock, np.asarray(space.stiff_positions, bool), limited,
        body.distance.kernel_args, body.frame, float(body.threshold), float(body.cap_length), shapes.theta,
        shapes.length, np.ascontiguousarray(target.bases[:, 0]), body.distance.exact(body.to_object(contour)),
        fields.cover, *fields.node_minima,
    )


def new_state(problem, space: DesignSpace) -> tuple:
    """The compiled search's working arrays for ``problem`` (from ``search_problem``) over ``space``."""
    blocks, contour, n_choices, base_x = space.num_blocks, problem[0], problem[4], problem[22]
    width = max(len(base_x) * n_choices[0], n_choices.max())
    # depth, then per depth: next child, child count, child order, child bounds, shapes, bases, end poses;
    # the current node's pose and contour distances per depth; the path (base, shapes), shapes used; best
    # cost and path; counters (collision checks, block placements evaluated); ceiling and smallest bound it
    # cut; scratch for the lookahead sums; the lowest cost any worker has found (shared by split workers)
    return (
        np.zeros(1, np.int64), np.zeros(blocks, np.int64), np.zeros(blocks, np.int64),
        np.zeros((blocks, width), np.int64), np.zeros((blocks, width)), np.zeros((blocks, width), np.int64),
        np.zeros((blocks, width), np.int64), np.zeros((blocks, width, 3)), np.zeros((blocks, 3)),
        np.zeros((blocks, len(contour))), np.full(blocks + 1, -1, np.int64), np.zeros(len(space.theta), np.int64),
        np.array([np.inf]), np.full(blocks + 1, -1, np.int64), np.zeros(2, np.int64), np.array([np.inf, np.inf]),
        np.zeros(n_choices.max()), np.array([np.inf]),
    )


def solve_finger(target: ShapeTarget, space: DesignSpace, *, options: dict | None = None, time_budget=None,
                 callback=None) -> DesignOptimizeResult:
    """Minimise the finger objective of ``target`` (eq. 3, with a body) over the planar ``space``; certified
    unless the time budget or the callback stops it first (then ``lower_bound`` is proven)."""
    settings = _check_options(options)
    if target.body is None:
        raise ValueError("solve_finger needs a finger target (with a body); use solve_exact for paths")
    if space.rotations != 1:
        raise ValueError("finger designs are planar: the design space must not allow rotations")
    control = RunControl(time_budget, callback)
    problem = search_problem(target, space, settings)
    blocks = space.num_blocks
    state = new_state(problem, space)
    best, limits, stats, incumbent = state[12], state[15], state[14], state[17]
    shares = [state]
    status, nit, proven, searching = Status.FINISHED, 0, 0.0, False  # every objective is >= 0
    try:
        found = None
        for width, timed in ((FIRST_BEAM_WIDTH, False), (settings["beam_width"], True)):  # narrow: a finger
            beam = _beam(problem, space, width, control, timed)  # at once; wide: a better one if time allows
            if beam is not None and beam[0] < best[0]:
                found = beam
                best[0], state[13][:] = beam[0], beam[1]
        if found is not None:
            if settings["polish"]:
                shapes_, _, bases_, costs_, _ = polish(target, space, np.array([found[1][1:]]),
                                                      np.zeros((1, blocks), np.int64), np.array([found[1][0]]),
                                                      control, SAMPLES_PER_BLOCK)
                if costs_[0] < best[0]:
                    best[0], state[13][:] = costs_[0], [bases_[0], *shapes_[0]]
        incumbent[0] = best[0]
        _start(problem, state)  # with a finger in hand the ceiling stays off; without, it starts low and grows
        searching = True
        if found is not None and settings["workers"] > 1:
            shares = _split(state, settings["workers"])
            stop, nit = _search_shares(problem, shares, settings["expansions_per_check"], control)
            if stop is not None:
                raise Stop(stop)
            status = Status.CERTIFIED
        if found is None:
            limits[0] = state[4][0, state[3][0, 0]] * settings["ceiling_growth"] if state[2][0] else np.inf
        while status != Status.CERTIFIED:
            nit += 1
            done = _search(problem, state, settings["expansions_per_check"])
            control.report(_fraction(shares), best[0], int(stats[1]))
            if done and (best[0] < np.inf or limits[1] == np.inf):  # optimum found, or nothing left
                status = Status.CERTIFIED
                break
            if done:  # no finger below the ceiling: every finger costs at least the smallest bound cut
                proven = limits[1]
                limits[0] = max(limits[1], limits[0]) * settings["ceiling_growth"]
                _start(problem, state)
    except Stop as stop:
        status = stop.status
    winner = min(shares, key=lambda share: share[12][0])
    cost, best_path = float(winner[12][0]), winner[13]
    lower_bound = cost if status == Status.CERTIFIED else max(proven, _lower_bound(shares) if searching else 0.0)
    if not np.isfinite(cost):  # nothing collision-free: report the least bad first-choice finger
        chosen, base_index = np.array([c[0] for c in space.choices]), 0
        cost = float(design_costs(target, space, chosen[None], np.zeros((1, blocks), np.int64),
                                  np.zeros(1, np.int64))[0])
        if status == Status.CERTIFIED:  # the search ended: every finger collides
            lower_bound = COLLISION_PENALTY
    else:
        chosen, base_index = best_path[1:].copy(), int(best_path[0])
    return make_result(space, chosen, np.zeros(blocks, np.int64), cost, status, base=base_index, nit=nit,
                       nfev=sum(int(share[14][1]) for share in shares), lower_bound=min(lower_bound, cost),
                       control=control)
