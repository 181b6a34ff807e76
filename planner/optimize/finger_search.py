"""Certified finger design: depth-first branch and bound over (base, block 1, ..., block N), compiled.

A finger is built from its base. Once blocks 1..k are placed, their centerline samples are fixed and so
is each contour point's distance ``a`` to them. Blocks k+1..N form a suffix whose shape in the frame of
the prefix's end does not depend on the prefix (piecewise constant curvature), so the set of points any
suffix can reach from there, and the set of tip periphery points it can end at, are computed once per
design space (``SuffixRegions``, distance fields on a grid, exact up to a recorded error). With ``b`` a
lower bound on a contour point's distance to that set, its final distance lies in [min(a, b), a], which
bounds its term |d - r| from below; the tip term is bounded by the distance to the tip set. The bound of
a complete finger is its objective.

The search visits children in the order of their bounds and drops every child whose bound reaches the
best collision-free finger found, so when it ends that finger is the optimum (``Status.CERTIFIED``).
Collision is the exact rule of ``planner.clearance`` (tube of radius r around the continuous centerline
against the object's pixel squares), checked for a block when the search enters it. Stopped early (time
budget, callback), the run returns the best finger so far and a proven lower bound: the smallest bound of
the children not yet visited.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit
from scipy import ndimage

from planner.clearance import RESOLUTION, block_min_distance
from planner.kinematics import CAP_LENGTH, DEFAULT_SAMPLES_PER_BLOCK, chain_shape
from planner.objectives import COLLISION_PENALTY, ShapeTarget
from planner.optimize.pso import design_costs
from planner.optimize.result import DesignOptimizeResult, RunControl, Status, Stop, make_result
from planner.optimize.space import DesignSpace

DEFAULT_OPTIONS = {
    "region_spacing": 2e-4,  # grid step of the suffix regions [m]
    "expansions_per_check": 4000,  # nodes expanded between time-budget / callback checks
    "ceiling_growth": 1.3,  # factor between the cost ceilings of successive rounds
}
SAMPLES_PER_BLOCK = DEFAULT_SAMPLES_PER_BLOCK  # the objective's centerline samples (planner.kinematics)


# ---------------------------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class BlockShapes:
    """Every distinct block shape in the frame of its start (x lateral toward the bend, z along)."""

    samples: np.ndarray  # (S, M, 2) the objective's centerline samples, start excluded
    ends: np.ndarray  # (S, 3) end x, z and turn (theta)
    reach: np.ndarray  # (S,) farthest sample from the start [m]
    theta: np.ndarray  # (S,)
    length: np.ndarray  # (S,)


def block_shapes(space: DesignSpace) -> BlockShapes:
    shape = chain_shape(space.theta[:, None], space.length[:, None], 0.0, samples_per_block=SAMPLES_PER_BLOCK)
    samples = shape.points[:, 1:, :][..., [0, 2]]
    ends = np.column_stack([shape.positions[:, 1, 0], shape.positions[:, 1, 2], space.theta])
    return BlockShapes(np.ascontiguousarray(samples), ends, np.linalg.norm(samples, axis=-1).max(axis=1),
                       np.asarray(space.theta, float), np.asarray(space.length, float))


@njit(cache=True)
def _mark(points, grid, x0, z0, spacing):
    """Set the grid node nearest to each point (points inside the grid by construction)."""
    for i in range(points.shape[0]):
        grid[int(np.round((points[i, 1] - z0) / spacing)), int(np.round((points[i, 0] - x0) / spacing))] = True


@njit(cache=True)
def _transform_marked(marked, x0, z0, spacing, end_x, end_z, turn, out_grid):
    """Mark, in ``out_grid``, the nodes nearest to the marked nodes of ``marked`` moved by a block (the
    block's end pose in its start frame: a point p of the next frame lies at end + R(turn) p)."""
    cos, sin = np.cos(turn), np.sin(turn)
    rows, cols = marked.shape
    for a in range(rows):
        for b in range(cols):
            if marked[a, b]:
                x = x0 + b * spacing
                z = z0 + a * spacing
                wx = end_x + x * cos + z * sin
                wz = end_z - x * sin + z * cos
                out_grid[int(np.round((wz - z0) / spacing)), int(np.round((wx - x0) / spacing))] = True


@dataclass(frozen=True)
class SuffixRegions:
    """Per number of placed blocks k (1..N-1): distance fields, in the frame of block k's end, of the points
    any suffix k+1..N can occupy (``body``) and of the tip periphery points it can end at (``tip``).
    ``error[k]`` is added to the grid error: the true distance is at least field - node offset - error."""

    body: np.ndarray  # (N, rows, cols) float64; index 0 unused
    tip: np.ndarray  # (N, rows, cols)
    x0: float
    z0: float
    spacing: float
    error: np.ndarray  # (N,)


@lru_cache(maxsize=8)
def _suffix_regions(key, spacing: float) -> SuffixRegions:
    samples, ends, radius, choices = key
    samples = np.array(samples).reshape(-1, SAMPLES_PER_BLOCK, 2)
    ends = np.array(ends).reshape(-1, 3)
    blocks = len(choices)
    # every suffix stays within the sum of its blocks' reaches (plus r for the tip periphery)
    reach = np.linalg.norm(samples, axis=-1).max(axis=1)
    extent = sum(reach[list(c)].max() for c in choices[1:]) + radius + 4 * spacing
    x0 = z0 = -extent
    size = int(np.ceil(2 * extent / spacing)) + 1
    body = np.zeros((blocks, size, size))
    tip = np.zeros((blocks, size, size))
    error = np.zeros(blocks)
    marked_body = marked_tip = None
    for k in range(blocks - 1, 0, -1):  # suffix k+1..N in 1-based blocks = choices[k:] in 0-based positions
        new_body = np.zeros((size, size), dtype=bool)
        new_tip = np.zeros((size, size), dtype=bool)
        for s in choices[k]:
            _mark(samples[s], new_body, x0, z0, spacing)
            if marked_body is None:
                turn = ends[s, 2]
                _mark(np.array([[ends[s, 0] + radius * np.cos(turn), ends[s, 1] - radius * np.sin(turn)]]), new_tip,
                      x0, z0, spacing)
            else:
                _transform_marked(marked_body, x0, z0, spacing, ends[s, 0], ends[s, 1], ends[s, 2], new_body)
                _transform_marked(marked_tip, x0, z0, spacing, ends[s, 0], ends[s, 1], ends[s, 2], new_tip)
        error[k] = (0.0 if marked_body is None else error[k + 1]) + spacing / np.sqrt(2)
        body[k] = ndimage.distance_transform_edt(~new_body) * spacing
        tip[k] = ndimage.distance_transform_edt(~new_tip) * spacing
        marked_body, marked_tip = new_body, new_tip
    return SuffixRegions(body, tip, x0, z0, spacing, error)


def suffix_regions(shapes: BlockShapes, space: DesignSpace, radius: float, spacing: float) -> SuffixRegions:
    """The regions of ``space``'s suffixes (cached per block geometry and per-position choices)."""
    key = (tuple(np.round(shapes.samples, 12).ravel()), tuple(np.round(shapes.ends, 12).ravel()), float(radius),
           tuple(tuple(int(s) for s in c) for c in space.choices))
    return _suffix_regions(key, float(spacing))


# ------------------------------------------------------------------------------------------ search
@njit(cache=True)
def _region_lower(field, x0, z0, spacing, x, z):
    """Lower bound on the distance from a point to the region whose distance field is ``field``."""
    b = int(np.round((x - x0) / spacing))
    a = int(np.round((z - z0) / spacing))
    rows, cols = field.shape
    if a < 0 or b < 0 or a >= rows or b >= cols:  # outside the grid: at least the distance to the grid box
        far = x0 + (cols - 1) * spacing
        top = z0 + (rows - 1) * spacing
        dx = max(x0 - x, x - far, 0.0)
        dz = max(z0 - z, z - top, 0.0)
        return np.hypot(dx, dz)
    return field[a, b] - np.hypot(x - (x0 + b * spacing), z - (z0 + a * spacing))


@njit(cache=True)
def _expand(problem, depth, pose, alpha, out_bound, out_shape, out_base, out_pose, out_alpha, start, base, path,
            counts):
    """Children of a node with ``depth`` blocks placed (pose, contour distances alpha) into the out arrays
    from index ``start``; returns the new end index. Bounds only: collision is checked on entry."""
    (contour, end_point, radius, choices, n_choices, samples, ends, reach, regions_body, regions_tip, grid,
     error, stock, stiff_stock, stiff_positions, limited) = problem[:16]
    blocks = choices.shape[0]
    points = contour.shape[0]
    px, pz, heading = pose[0], pose[1], pose[2]
    cos, sin = np.cos(heading), np.sin(heading)
    to_start = np.empty(points)
    for q in range(points):
        to_start[q] = np.hypot(contour[q, 0] - px, contour[q, 1] - pz)
    n = start
    for c in range(n_choices[depth]):
        s = choices[depth, c]
        if limited:
            used = counts[s]
            if used >= stock[s]:
                continue
            if stiff_positions[depth]:
                stiff_used = 0
                for k in range(depth):
                    if stiff_positions[k] and path[k + 1] == s:
                        stiff_used += 1
                if stiff_used >= stiff_stock[s]:
                    continue
        child = out_alpha[n]
        child[:] = alpha
        for q in range(points):
            if to_start[q] - reach[s] < child[q]:
                for m in range(samples.shape[1]):
                    sx = px + samples[s, m, 0] * cos + samples[s, m, 1] * sin
                    sz = pz - samples[s, m, 0] * sin + samples[s, m, 1] * cos
                    d = np.hypot(contour[q, 0] - sx, contour[q, 1] - sz)
                    if d < child[q]:
                        child[q] = d
        ex = px + ends[s, 0] * cos + ends[s, 1] * sin
        ez = pz - ends[s, 0] * sin + ends[s, 1] * cos
        eh = heading + ends[s, 2]
        tip_x = ex + radius * np.cos(eh)
        tip_z = ez - radius * np.sin(eh)
        bound = 0.0
        if depth + 1 == blocks:  # a complete finger: its objective
            for q in range(points):
                bound += abs(child[q] - radius)
            bound += np.hypot(tip_x - end_point[0], tip_z - end_point[1])
        else:
            level = depth + 1
            ec, es = np.cos(eh), np.sin(eh)
            for q in range(points):
                dx, dz = contour[q, 0] - ex, contour[q, 1] - ez
                lx, lz = dx * ec - dz * es, dx * es + dz * ec  # in the child's end frame
                later = _region_lower(regions_body[level], grid[0], grid[1], grid[2], lx, lz) - error[level]
                lowest = min(child[q], later)
                bound += max(lowest - radius, radius - child[q], 0.0)
            dx, dz = end_point[0] - ex, end_point[1] - ez
            lx, lz = dx * ec - dz * es, dx * es + dz * ec
            bound += max(_region_lower(regions_tip[level], grid[0], grid[1], grid[2], lx, lz) - error[level], 0.0)
        out_bound[n] = bound
        out_shape[n] = s
        out_base[n] = base
        out_pose[n, 0], out_pose[n, 1], out_pose[n, 2] = ex, ez, eh
        n += 1
    return n


@njit(cache=True)
def _sort_level(level, count, bound, order):
    order[level, :count] = np.argsort(bound[level, :count], kind="mergesort")


@njit(cache=True)
def _search(problem, state, max_expansions):
    """Run the depth-first search from ``state`` for at most ``max_expansions`` node expansions.

    Returns 1 when the search is complete (the best finger in ``state`` is optimal), 0 when interrupted.
    """
    contour, radius, choices = problem[0], problem[2], problem[3]
    field, frame, threshold, cap, theta, length, base_x = problem[16:23]
    (depth_box, pointer, count, order, bound, shape, base, pose, alpha, node_pose, node_alpha, path, counts, best,
     best_path, stats, limits) = state
    blocks = choices.shape[0]
    expansions = 0
    while True:
        depth = depth_box[0]
        if pointer[depth] >= count[depth]:
            if depth == 0:
                return 1
            depth_box[0] = depth - 1
            if depth - 1 >= 0 and path[depth] >= 0:  # leave the block placed at this depth
                counts[path[depth]] -= 1
                path[depth] = -1
            continue
        i = order[depth, pointer[depth]]
        pointer[depth] += 1
        if bound[depth, i] >= min(best[0], limits[0]):  # children are sorted: the rest are no better
            if bound[depth, i] < best[0]:  # cut by the round's ceiling, not by a finger: remember the bound
                limits[1] = min(limits[1], bound[depth, i])
            pointer[depth] = count[depth]
            continue
        s = shape[depth, i]
        parent_x, parent_z, parent_h = node_pose[depth, 0], node_pose[depth, 1], node_pose[depth, 2]
        if depth == 0:
            parent_x, parent_z, parent_h = base_x[base[depth, i]], 0.0, 0.0
        stats[0] += 1
        clearance = block_min_distance(field, frame, parent_x, parent_z, parent_h, theta[s], length[s], cap,
                                       threshold, False)
        if clearance < threshold - RESOLUTION:
            continue
        if depth + 1 == blocks:  # the best finger below this node (children sorted, the rest is no better)
            best[0] = bound[depth, i]
            for k in range(1, blocks):
                best_path[k] = path[k]
            best_path[0] = path[0]
            best_path[blocks] = s
            pointer[depth] = count[depth]
            continue
        if depth == 0:
            path[0] = base[depth, i]
        path[depth + 1] = s
        counts[s] += 1
        node_pose[depth + 1, :] = pose[depth, i]
        node_alpha[depth + 1, :] = alpha[depth, i]
        depth_box[0] = depth + 1
        end = _expand(problem, depth + 1, node_pose[depth + 1], node_alpha[depth + 1], bound[depth + 1],
                      shape[depth + 1], base[depth + 1], pose[depth + 1], alpha[depth + 1], 0, path[0], path, counts)
        count[depth + 1] = end
        pointer[depth + 1] = 0
        stats[1] += end
        _sort_level(depth + 1, end, bound, order)
        expansions += 1
        if expansions >= max_expansions:
            return 0


@njit(cache=True)
def _start(problem, state):
    """Root children: every base with every first block."""
    contour, base_x = problem[0], problem[22]
    (depth_box, pointer, count, order, bound, shape, base, pose, alpha, node_pose, node_alpha, path, counts, best,
     best_path, stats, limits) = state
    n = 0
    root_alpha = np.empty(contour.shape[0])
    for b in range(base_x.shape[0]):
        for q in range(contour.shape[0]):
            root_alpha[q] = np.hypot(contour[q, 0] - base_x[b], contour[q, 1])
        root_pose = np.array([base_x[b], 0.0, 0.0])
        n = _expand(problem, 0, root_pose, root_alpha, bound[0], shape[0], base[0], pose[0], alpha[0], n, b, path,
                    counts)
    count[0] = n
    pointer[0] = 0
    depth_box[0] = 0
    path[:] = -1
    counts[:] = 0
    stats[1] += n
    _sort_level(0, n, bound, order)
    limits[1] = np.inf


def _lower_bound(state) -> float:
    """Smallest bound among the children not yet visited or cut by the round's ceiling (and the best
    finger): a proven lower bound."""
    depth_box, pointer, count, order, bound = state[:5]
    best = state[13][0]
    lowest = min(best, state[16][1])
    for level in range(depth_box[0] + 1):
        if pointer[level] < count[level]:
            lowest = min(lowest, float(bound[level, order[level, pointer[level]]]))
    return lowest


def _fraction(state) -> float:
    pointer, count = state[1], state[2]
    if count[0] == 0:
        return 1.0
    inner = pointer[1] / count[1] if state[0][0] >= 1 and count[1] else 0.0
    return min((max(pointer[0] - 1, 0) + inner) / count[0], 1.0)


def solve_finger(target: ShapeTarget, space: DesignSpace, *, options: dict | None = None, time_budget=None,
                 callback=None) -> DesignOptimizeResult:
    """Minimise the finger objective of ``target`` (eq. 3, with a body) over the planar ``space``; certified
    unless the time budget or the callback stops it first (then ``lower_bound`` is proven)."""
    unknown = set(options or {}) - set(DEFAULT_OPTIONS)
    if unknown:
        raise ValueError(f"options: unknown keys {sorted(unknown)}; known: {sorted(DEFAULT_OPTIONS)}")
    settings = DEFAULT_OPTIONS | (options or {})
    if not (np.isfinite(settings["region_spacing"]) and settings["region_spacing"] > 0):
        raise ValueError("options['region_spacing'] must be a positive length [m]")
    if not (isinstance(settings["expansions_per_check"], (int, np.integer)) and settings["expansions_per_check"] >= 1):
        raise ValueError("options['expansions_per_check'] must be an integer >= 1")
    if target.body is None:
        raise ValueError("solve_finger needs a finger target (with a body); use solve_exact for paths")
    if space.rotations != 1:
        raise ValueError("finger designs are planar: the design space must not allow rotations")
    control = RunControl(time_budget, callback)
    body = target.body
    shapes = block_shapes(space)
    regions = suffix_regions(shapes, space, body.radius, settings["region_spacing"])
    blocks = space.num_blocks
    choices = np.full((blocks, max(len(c) for c in space.choices)), -1, dtype=np.int64)
    for k, c in enumerate(space.choices):
        choices[k, : len(c)] = c
    n_choices = np.array([len(c) for c in space.choices], dtype=np.int64)
    contour = np.ascontiguousarray(target.points[:, [0, 2]])
    base_x = np.ascontiguousarray(target.bases[:, 0])
    limited = space.stock is not None
    stock = space.stock if limited else np.zeros(len(space.theta), dtype=np.int64)
    stiff_stock = space.stiff_stock if limited else stock
    problem = (
        contour, np.asarray(target.end_point[[0, 2]], float), float(body.radius), choices, n_choices,
        shapes.samples, shapes.ends, shapes.reach, regions.body, regions.tip,
        np.array([regions.x0, regions.z0, regions.spacing]), regions.error, np.asarray(stock, np.int64),
        np.asarray(stiff_stock, np.int64), np.asarray(space.stiff_positions, bool), limited,
        body.distance.kernel_args, body.frame, float(body.threshold), float(body.cap_length), shapes.theta,
        shapes.length, base_x,
    )
    width = max(len(base_x) * n_choices[0], n_choices.max())
    points = len(contour)
    levels = blocks
    state = (
        np.zeros(1, np.int64), np.zeros(levels, np.int64), np.zeros(levels, np.int64),
        np.zeros((levels, width), np.int64), np.zeros((levels, width)), np.zeros((levels, width), np.int64),
        np.zeros((levels, width), np.int64), np.zeros((levels, width, 3)), np.zeros((levels, width, points)),
        np.zeros((levels, 3)), np.zeros((levels, points)), np.full(blocks + 1, -1, np.int64),
        np.zeros(len(space.theta), np.int64), np.array([np.inf]), np.full(blocks + 1, -1, np.int64),
        np.zeros(2, np.int64), np.array([np.inf, np.inf]),
    )
    _start(problem, state)
    best, limits = state[13], state[16]
    limits[0] = state[4][0, state[3][0, 0]] * settings["ceiling_growth"] if state[2][0] else np.inf
    status, nit, proven = Status.FINISHED, 0, -np.inf
    try:
        while True:
            nit += 1
            done = _search(problem, state, settings["expansions_per_check"])
            control.report(_fraction(state), best[0], int(state[15][1]))
            if done and best[0] < np.inf or done and limits[1] == np.inf:  # optimum found, or nothing left
                status = Status.CERTIFIED
                break
            if done:  # no finger below the ceiling: every finger costs at least the smallest bound cut
                proven = limits[1]
                limits[0] = max(limits[1], limits[0] * settings["ceiling_growth"])
                _start(problem, state)
    except Stop as stop:
        status = stop.status
    best, best_path = float(best[0]), state[14]
    lower_bound = best if status == Status.CERTIFIED else max(proven, _lower_bound(state))
    nfev = int(state[15][1])
    if not np.isfinite(best):  # nothing collision-free: report the least bad first-choice finger
        shapes_chosen = np.array([c[0] for c in space.choices])
        best = float(design_costs(target, space, shapes_chosen[None], np.zeros((1, blocks), np.int64),
                                  np.zeros(1, np.int64))[0])
        base_index = 0
        if status == Status.CERTIFIED:  # the search ended: every finger collides
            lower_bound = COLLISION_PENALTY
    else:
        shapes_chosen, base_index = best_path[1:].copy(), int(best_path[0])
    return make_result(space, shapes_chosen, np.zeros(blocks, np.int64), best, status, base=base_index, nit=nit,
                       nfev=nfev, lower_bound=lower_bound, control=control)
