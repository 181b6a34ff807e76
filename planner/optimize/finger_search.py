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
blocks in one vectorised pass per node; a complete finger is bounded by its objective.

The search visits children in the order of their bounds and drops every child whose bound reaches the
best collision-free finger found, so when it ends that finger is the optimum (``Status.CERTIFIED``). The
first finger comes from two beams over the same tree (16 prefixes per level, always run to the end, then
``beam_width`` while the budget allows) improved by local search; should they find none, rounds search
below a cost ceiling that grows by ``ceiling_growth`` until a finger is found under it (a round without one
proves the optimum is at least the smallest bound it cut).
Collision is the exact rule of ``planner.clearance``, checked for a block when the search enters it.
Stopped early (time budget, callback), the run returns the best finger so far and a proven lower bound:
the smallest bound of the children not yet visited.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from numba import njit
from scipy import ndimage

from planner.clearance import RESOLUTION, block_min_distance
from planner.kinematics import DEFAULT_SAMPLES_PER_BLOCK, chain_shape
from planner.objectives import COLLISION_PENALTY, ShapeTarget
from planner.optimize.local_search import polish
from planner.optimize.pso import design_costs
from planner.optimize.result import DesignOptimizeResult, RunControl, Status, Stop, make_result
from planner.optimize.space import DesignSpace

DEFAULT_OPTIONS = {
    "field_spacing": 5e-4,  # grid step of the lookahead fields [m] (half of it for the last block's)
    "region_spacing": 2e-4,  # grid step of the suffix regions they are built from [m]
    "expansions_per_check": 2000,  # nodes expanded between time-budget / callback checks
    "ceiling_growth": 1.3,  # factor between the cost ceilings of successive rounds
    "beam_width": 128,  # collision-free prefixes per level of the second beam (the first keeps 16)
    "polish": True,  # improve the beam's finger by block-by-block local search before the search starts
}
SAMPLES_PER_BLOCK = DEFAULT_SAMPLES_PER_BLOCK  # the objective's centerline samples (planner.kinematics)
FLOAT32_MARGIN = 1e-7  # [m] subtracted before storing bounds as float32, so rounding never raises them
FIRST_BEAM_WIDTH = 16  # the beam that always runs to the end, so that every run returns a finger
FIELDS_VERSION = 1  # bump when the way the fields are built changes (names the cache files)


# ---------------------------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class BlockShapes:
    """Every distinct block shape in the frame of its start (x lateral toward the bend, z along)."""

    samples: np.ndarray  # (S, M, 2) the objective's centerline samples, start excluded
    ends: np.ndarray  # (S, 3) end x, z and turn (theta)
    reach: np.ndarray  # (S,) farthest sample from the start [m]
    disc: np.ndarray  # (S, 3) centre x, z and radius of a disc holding the samples [m]
    theta: np.ndarray  # (S,)
    length: np.ndarray  # (S,)


def block_shapes(space: DesignSpace) -> BlockShapes:
    shape = chain_shape(space.theta[:, None], space.length[:, None], 0.0, samples_per_block=SAMPLES_PER_BLOCK)
    samples = shape.points[:, 1:, :][..., [0, 2]]
    ends = np.column_stack([shape.positions[:, 1, 0], shape.positions[:, 1, 2], space.theta])
    centre = 0.5 * (samples.min(axis=1) + samples.max(axis=1))
    disc = np.column_stack([centre, np.linalg.norm(samples - centre[:, None], axis=-1).max(axis=1)])
    return BlockShapes(np.ascontiguousarray(samples), ends, np.linalg.norm(samples, axis=-1).max(axis=1), disc,
                       np.asarray(space.theta, float), np.asarray(space.length, float))


@njit(cache=True)
def _mark(points, grid, x0, z0, spacing):
    """Set the grid node nearest to each point."""
    for i in range(points.shape[0]):
        grid[int(np.round((points[i, 1] - z0) / spacing)), int(np.round((points[i, 0] - x0) / spacing))] = True


@njit(cache=True)
def _mark_moved(marked, x0, z0, spacing, end_x, end_z, turn, out_grid):
    """Mark in ``out_grid`` the nodes nearest to the marked nodes of ``marked`` moved by a block (a point p
    of the block's end frame lies at end + p_x (cos turn, -sin turn) + p_z (sin turn, cos turn))."""
    cos, sin = np.cos(turn), np.sin(turn)
    for a in range(marked.shape[0]):
        for b in range(marked.shape[1]):
            if marked[a, b]:
                x, z = x0 + b * spacing, z0 + a * spacing
                out_grid[int(np.round((end_z - x * sin + z * cos - z0) / spacing)),
                         int(np.round((end_x + x * cos + z * sin - x0) / spacing))] = True


@njit(cache=True)
def _grid_lower(field, x0, z0, spacing, x, z):
    """Lower bound on a 1-Lipschitz distance at (x, z) from its values at grid nodes; outside the grid, the
    distance to the grid box (the region lies inside it)."""
    b = int(np.round((x - x0) / spacing))
    a = int(np.round((z - z0) / spacing))
    rows, cols = field.shape
    if a < 0 or b < 0 or a >= rows or b >= cols:
        dx = max(x0 - x, x - (x0 + (cols - 1) * spacing), 0.0)
        dz = max(z0 - z, z - (z0 + (rows - 1) * spacing), 0.0)
        return np.hypot(dx, dz)
    return field[a, b] - np.hypot(x - (x0 + b * spacing), z - (z0 + a * spacing))


@njit(cache=True)
def _fill_level(out_body, out_tip, x0, z0, spacing, choices, samples, ends, radius, region, region_tip, rx0, rz0,
                region_spacing, region_error, last):
    """Lookahead fields of one block position at every node: for each allowed next shape c, a lower bound
    on the distance to (c's samples and the suffix region after c) and to the tip periphery set after c."""
    rows, cols, count = out_body.shape
    for a in range(rows):
        z = z0 + a * spacing
        for b in range(cols):
            x = x0 + b * spacing
            for k in range(count):
                c = choices[k]
                nearest = np.inf
                for m in range(samples.shape[1]):
                    nearest = min(nearest, np.hypot(x - samples[c, m, 0], z - samples[c, m, 1]))
                cos, sin = np.cos(ends[c, 2]), np.sin(ends[c, 2])
                dx, dz = x - ends[c, 0], z - ends[c, 1]
                if last:  # no block after c: its own samples and its own tip periphery point
                    tip = np.hypot(dx - radius * cos, dz + radius * sin)
                else:
                    px, pz = dx * cos - dz * sin, dx * sin + dz * cos  # in the frame of c's end
                    later = _grid_lower(region, rx0, rz0, region_spacing, px, pz) - region_error
                    nearest = min(nearest, later)
                    tip = _grid_lower(region_tip, rx0, rz0, region_spacing, px, pz) - region_error
                out_body[a, b, k] = nearest - FLOAT32_MARGIN
                out_tip[a, b, k] = max(tip, 0.0) - FLOAT32_MARGIN


@dataclass(frozen=True)
class LookaheadFields:
    """Per block position d: float32 fields (rows, cols, choices) in the frame of block d's start, packed
    flat; ``layout[d]`` = (offset, rows, cols, x0, z0, reach, spacing): every sample from block d on lies
    within ``reach`` of block d's start (tip periphery points within reach + r), the grid covers r beyond
    that. The last block's grid is twice as fine (it decides which complete fingers are evaluated)."""

    body: np.ndarray
    tip: np.ndarray
    discs: np.ndarray  # (N, C, 9): per next shape, a disc (x, z, radius) holding its samples, its end (x, z),
    # the reach of the blocks after it, and a point (x, z) and radius holding the tip periphery set
    layout: np.ndarray  # (N, 7) float64: offset, rows, cols, x0, z0, reach of the samples that follow, spacing


def _lookahead_fields(key, field_spacing: float, region_spacing: float) -> LookaheadFields:
    samples, ends, radius, choices = key
    samples = np.array(samples).reshape(-1, SAMPLES_PER_BLOCK, 2)
    ends = np.array(ends).reshape(-1, 3)
    blocks = len(choices)
    reach = np.linalg.norm(samples, axis=-1).max(axis=1)
    ahead = [sum(reach[list(c)].max() for c in choices[d:]) + radius for d in range(blocks + 1)]
    # suffix regions after each position, re-marked on one grid (each re-marking adds half a diagonal)
    extent = ahead[1] + 4 * region_spacing
    size = int(np.ceil(2 * extent / region_spacing)) + 1
    regions, tips, errors = [None] * (blocks + 1), [None] * (blocks + 1), np.zeros(blocks + 1)
    marked_body = marked_tip = None
    for d in range(blocks - 1, 0, -1):  # region of the suffix d..N-1, in the frame of block d's start
        body = np.zeros((size, size), dtype=bool)
        tip = np.zeros((size, size), dtype=bool)
        for c in choices[d]:
            _mark(samples[c], body, -extent, -extent, region_spacing)
            if marked_body is None:
                turn = ends[c, 2]
                periphery = np.array([[ends[c, 0] + radius * np.cos(turn), ends[c, 1] - radius * np.sin(turn)]])
                _mark(periphery, tip, -extent, -extent, region_spacing)
            else:
                _mark_moved(marked_body, -extent, -extent, region_spacing, *ends[c], body)
                _mark_moved(marked_tip, -extent, -extent, region_spacing, *ends[c], tip)
        errors[d] = errors[d + 1] + region_spacing / np.sqrt(2)
        regions[d] = ndimage.distance_transform_edt(~body) * region_spacing
        tips[d] = ndimage.distance_transform_edt(~tip) * region_spacing
        marked_body, marked_tip = body, tip
    layout, body_parts, tip_parts, offset = np.zeros((blocks, 7)), [], [], 0
    centre = 0.5 * (samples.min(axis=1) + samples.max(axis=1))
    disc_radius = np.linalg.norm(samples - centre[:, None], axis=-1).max(axis=1)
    discs = np.zeros((blocks, max(len(c) for c in choices), 9))
    for d in range(blocks):
        last = d == blocks - 1
        after = 0.0 if last else ahead[d + 1] - radius
        for k, c in enumerate(choices[d]):
            x, z, turn = ends[c]
            tip = (x + radius * np.cos(turn), z - radius * np.sin(turn)) if last else (x, z)
            discs[d, k] = (*centre[c], disc_radius[c], x, z, after, *tip, 0.0 if last else after + radius)
    for d in range(blocks):
        spacing = field_spacing / 2 if d == blocks - 1 else field_spacing
        half = ahead[d] + 2 * spacing
        cells = int(np.ceil(2 * half / spacing)) + 1
        out_body = np.empty((cells, cells, len(choices[d])), dtype=np.float32)
        out_tip = np.empty_like(out_body)
        last = d == blocks - 1
        region = regions[d + 1] if not last else np.zeros((1, 1))
        region_tip = tips[d + 1] if not last else np.zeros((1, 1))
        _fill_level(out_body, out_tip, -half, -half, spacing, np.array(choices[d], dtype=np.int64), samples,
                    ends, radius, region, region_tip, -extent, -extent, region_spacing, errors[d + 1], last)
        layout[d] = (offset, cells, cells, -half, -half, ahead[d] - radius, spacing)
        offset += out_body.size
        body_parts.append(out_body.ravel())
        tip_parts.append(out_tip.ravel())
    return LookaheadFields(np.concatenate(body_parts), np.concatenate(tip_parts), discs, layout)


def lookahead_fields(shapes: BlockShapes, space: DesignSpace, radius: float, field_spacing: float,
                     region_spacing: float) -> LookaheadFields:
    """The lookahead fields of ``space``: they depend only on the block geometry, the radius and the
    per-position choices, so they are kept in memory and in ``cache_directory()`` (building them takes
    seconds; loading them, a fraction of one)."""
    key = (tuple(np.round(shapes.samples, 12).ravel()), tuple(np.round(shapes.ends, 12).ravel()), float(radius),
           tuple(tuple(int(s) for s in c) for c in space.choices))
    return _cached_fields(key, float(field_spacing), float(region_spacing))


def cache_directory() -> Path:
    """Where lookahead fields are kept: $SOFTBLOCK_CACHE, else ~/.cache/softblock."""
    return Path(os.environ.get("SOFTBLOCK_CACHE") or Path.home() / ".cache" / "softblock")


@lru_cache(maxsize=4)
def _cached_fields(key, field_spacing: float, region_spacing: float) -> LookaheadFields:
    digest = hashlib.sha256(repr((FIELDS_VERSION, key, field_spacing, region_spacing)).encode()).hexdigest()[:24]
    path = cache_directory() / f"lookahead-{digest}.npz"
    try:
        with np.load(path) as stored:
            return LookaheadFields(*(stored[name] for name in LookaheadFields.__dataclass_fields__))
    except (OSError, KeyError, ValueError):
        pass  # not built yet (or unreadable): build and store
    fields = _lookahead_fields(key, field_spacing, region_spacing)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(temporary, **{name: getattr(fields, name) for name in LookaheadFields.__dataclass_fields__})
        temporary.replace(path)  # atomic: concurrent processes never read a half-written file
    except OSError:
        pass  # a read-only home still works, only slower
    return fields


# ------------------------------------------------------------------------------------------ search
@njit(cache=True)
def _place(pose, x, z):
    cos, sin = np.cos(pose[2]), np.sin(pose[2])
    return pose[0] + x * cos + z * sin, pose[1] - x * sin + z * cos


@njit(cache=True)
def _lookahead(problem, depth, pose, alpha, acc):
    """acc[k] = lower bound on every finger continuing this node with next shape choices[depth, k]."""
    contour, end_point, radius, choices, n_choices = problem[0], problem[1], problem[2], problem[3], problem[4]
    body, tip, layout, discs = problem[8], problem[9], problem[10], problem[11]
    count = n_choices[depth]
    spacing = layout[depth, 6]
    offset, rows, cols, x0, z0 = (int(layout[depth, 0]), int(layout[depth, 1]), int(layout[depth, 2]),
                                  layout[depth, 3], layout[depth, 4])
    cos, sin = np.cos(pose[2]), np.sin(pose[2])
    acc[:count] = 0.0
    common = 0.0
    for q in range(contour.shape[0] + 1):
        if q < contour.shape[0]:
            dx, dz = contour[q, 0] - pose[0], contour[q, 1] - pose[1]
            own = alpha[q]
        else:  # the tip term's target
            dx, dz = end_point[0] - pose[0], end_point[1] - pose[1]
            own = np.inf
        if own <= radius:  # the term's bound is 0 whatever comes next
            continue
        x, z = dx * cos - dz * sin, dx * sin + dz * cos
        b = int(np.round((x - x0) / spacing))
        a = int(np.round((z - z0) / spacing))
        if a < 0 or b < 0 or a >= rows or b >= cols:  # beyond the grid: bounds from each next block's discs
            for k in range(count):
                nearest = min(np.hypot(x - discs[depth, k, 0], z - discs[depth, k, 1]) - discs[depth, k, 2],
                              np.hypot(x - discs[depth, k, 3], z - discs[depth, k, 4]) - discs[depth, k, 5])
                if q < contour.shape[0]:
                    value = min(own, nearest) - radius
                else:  # the tip periphery point: exact after the last block
                    value = np.hypot(x - discs[depth, k, 6], z - discs[depth, k, 7]) - discs[depth, k, 8]
                if value > 0.0:
                    acc[k] += value
            continue
        node_offset = np.hypot(x - (x0 + b * spacing), z - (z0 + a * spacing))
        start = offset + (a * cols + b) * count
        if q < contour.shape[0]:
            for k in range(count):
                value = min(own, body[start + k] - node_offset) - radius
                if value > 0.0:
                    acc[k] += value
        else:
            for k in range(count):
                value = tip[start + k] - node_offset
                if value > 0.0:
                    acc[k] += value
    acc[:count] += common


@njit(cache=True)
def _block_update(problem, pose, alpha, s, out):
    """out = contour distances after adding block s at pose (alpha: before). Points farther from the
    block's sample disc than their current distance are skipped; squared distances inside."""
    contour, samples, disc = problem[0], problem[5], problem[7]
    cos, sin = np.cos(pose[2]), np.sin(pose[2])
    count = samples.shape[1]
    world = np.empty((count, 2))
    for m in range(count):
        world[m, 0] = pose[0] + samples[s, m, 0] * cos + samples[s, m, 1] * sin
        world[m, 1] = pose[1] - samples[s, m, 0] * sin + samples[s, m, 1] * cos
    centre_x = pose[0] + disc[s, 0] * cos + disc[s, 1] * sin
    centre_z = pose[1] - disc[s, 0] * sin + disc[s, 1] * cos
    radius = disc[s, 2]
    out[:] = alpha
    for q in range(contour.shape[0]):
        qx, qz = contour[q, 0], contour[q, 1]
        reach = out[q] + radius
        dx, dz = qx - centre_x, qz - centre_z
        if dx * dx + dz * dz >= reach * reach:
            continue
        nearest = out[q] * out[q]
        for m in range(count):
            ex, ez = qx - world[m, 0], qz - world[m, 1]
            squared = ex * ex + ez * ez
            if squared < nearest:
                nearest = squared
        out[q] = np.sqrt(nearest)


@njit(cache=True)
def _too_close(problem, alpha):
    """True when a centerline sample is provably closer to the object than the collision threshold: within
    ``threshold - gap`` of a contour point that lies ``gap`` from the object (a quick, exact reject)."""
    gap, threshold = problem[23], problem[18]
    for q in range(alpha.shape[0]):
        if alpha[q] + gap[q] < threshold - RESOLUTION:
            return True
    return False


@njit(cache=True)
def _expand(problem, depth, pose, alpha, best, limits, out_bound, out_shape, out_base, out_pose, start, base, path,
            counts, acc, scratch):
    """Children of a node with ``depth`` blocks placed whose bound is below min(best, ceiling limits[0]),
    from index ``start`` of the out arrays; returns the new end index. Complete fingers get their objective.
    The smallest bound cut by the ceiling alone goes to limits[1]."""
    contour, end_point, radius, choices, n_choices, samples, ends = problem[:7]
    stock, stiff_stock, stiff_positions, limited = problem[12], problem[13], problem[14], problem[15]
    blocks = choices.shape[0]
    cutoff = min(best, limits[0])
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
            _block_update(problem, pose, alpha, s, scratch)
            if _too_close(problem, scratch):
                continue
            bound = np.hypot(ex + radius * np.cos(eh) - end_point[0], ez - radius * np.sin(eh) - end_point[1])
            for q in range(contour.shape[0]):
                bound += abs(scratch[q] - radius)
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


@njit(cache=True)
def _search(problem, state, max_expansions):
    """Run the depth-first search from ``state`` for at most ``max_expansions`` node expansions.

    Returns 1 when the round is complete, 0 when interrupted.
    """
    choices = problem[3]
    field, frame, threshold, cap, theta, length, base_x = problem[16:23]
    (depth_box, pointer, count, order, bound, shape, base, pose, node_pose, node_alpha, path, counts, best,
     best_path, stats, limits, acc, scratch) = state
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
        if bound[depth, i] >= min(best[0], limits[0]):  # children are sorted: the rest are no better
            if bound[depth, i] < best[0]:  # cut by the round's ceiling, not by a finger: remember the bound
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
        end = _expand(problem, depth + 1, node_pose[depth + 1], node_alpha[depth + 1], best[0], limits,
                      bound[depth + 1], shape[depth + 1], base[depth + 1], pose[depth + 1], 0, path[0], path, counts,
                      acc, scratch)
        count[depth + 1] = end
        pointer[depth + 1] = 0
        stats[1] += problem[4][depth + 1]
        order[depth + 1, :end] = np.argsort(bound[depth + 1, :end], kind="mergesort")
        expansions += 1
        if expansions >= max_expansions:
            return 0


@njit(cache=True)
def _start(problem, state):
    """Root children: every base with every first block, below the ceiling."""
    contour, base_x = problem[0], problem[22]
    (depth_box, pointer, count, order, bound, shape, base, pose, node_pose, node_alpha, path, counts, best,
     best_path, stats, limits, acc, scratch) = state
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
                    counts, acc, scratch)
        stats[1] += problem[4][0]
    count[0] = n
    pointer[0] = 0
    depth_box[0] = 0
    order[0, :n] = np.argsort(bound[0, :n], kind="mergesort")


def _lower_bound(state) -> float:
    """Smallest bound among the children not yet visited or cut by the round's ceiling (and the best
    finger): a proven lower bound for this round."""
    depth_box, pointer, count, order, bound = state[:5]
    lowest = min(state[12][0], state[15][1])
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
    out_pose, acc, scratch = np.zeros((size, 3)), np.zeros(n_choices.max()), np.zeros(len(contour))
    limits = np.array([np.inf, np.inf])
    beam = [(np.array([x, 0.0, 0.0]), np.hypot(contour[:, 0] - x, contour[:, 1]), [b]) for b, x in enumerate(base_x)]
    for depth in range(blocks):
        control.report(0.0, np.inf, 0, timed=timed)
        candidates = []
        for pose, alpha, path in beam:
            path_array = np.array(path + [-1] * (blocks + 1 - len(path)), dtype=np.int64)
            counts = np.bincount(path_array[1:][path_array[1:] >= 0], minlength=len(space.theta)).astype(np.int64)
            n = _expand(problem, depth, pose, alpha, np.inf, limits, out_bound, out_shape, out_base, out_pose, 0,
                        path[0], path_array, counts, acc, scratch)
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
    if not (isinstance(settings["beam_width"], (int, np.integer)) and settings["beam_width"] >= 1):
        raise ValueError("options['beam_width'] must be an integer >= 1")
    return settings


def search_problem(target: ShapeTarget, space: DesignSpace, settings: dict | None = None) -> tuple:
    """Everything the compiled search reads, as one tuple (see the kernels for the order)."""
    settings = settings or DEFAULT_OPTIONS
    body = target.body
    shapes = block_shapes(space)
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
    blocks, contour, n_choices, base_x = space.num_blocks, problem[0], problem[4], problem[22]
    width = max(len(base_x) * n_choices[0], n_choices.max())
    # depth, then per depth: next child, child count, child order, child bounds, shapes, bases, end poses;
    # the current node's pose and contour distances per depth; the path (base, shapes), shapes used; best
    # cost and path; counters (collision checks, block placements evaluated); ceiling and smallest bound it
    # cut; scratch for the lookahead sums and contour distances
    state = (
        np.zeros(1, np.int64), np.zeros(blocks, np.int64), np.zeros(blocks, np.int64),
        np.zeros((blocks, width), np.int64), np.zeros((blocks, width)), np.zeros((blocks, width), np.int64),
        np.zeros((blocks, width), np.int64), np.zeros((blocks, width, 3)), np.zeros((blocks, 3)),
        np.zeros((blocks, len(contour))), np.full(blocks + 1, -1, np.int64), np.zeros(len(space.theta), np.int64),
        np.array([np.inf]), np.full(blocks + 1, -1, np.int64), np.zeros(2, np.int64), np.array([np.inf, np.inf]),
        np.zeros(n_choices.max()), np.zeros(len(contour)),
    )
    best, limits, stats = state[12], state[15], state[14]
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
        _start(problem, state)  # with a finger in hand the ceiling stays off; without, it starts low and grows
        searching = True
        if found is None:
            limits[0] = state[4][0, state[3][0, 0]] * settings["ceiling_growth"] if state[2][0] else np.inf
        while True:
            nit += 1
            done = _search(problem, state, settings["expansions_per_check"])
            control.report(_fraction(state), best[0], int(stats[1]))
            if done and (best[0] < np.inf or limits[1] == np.inf):  # optimum found, or nothing left
                status = Status.CERTIFIED
                break
            if done:  # no finger below the ceiling: every finger costs at least the smallest bound cut
                proven = limits[1]
                limits[0] = max(limits[1], limits[0]) * settings["ceiling_growth"]
                _start(problem, state)
    except Stop as stop:
        status = stop.status
    cost, best_path = float(best[0]), state[13]
    lower_bound = cost if status == Status.CERTIFIED else max(proven, _lower_bound(state) if searching else 0.0)
    if not np.isfinite(cost):  # nothing collision-free: report the least bad first-choice finger
        chosen, base_index = np.array([c[0] for c in space.choices]), 0
        cost = float(design_costs(target, space, chosen[None], np.zeros((1, blocks), np.int64),
                                  np.zeros(1, np.int64))[0])
        if status == Status.CERTIFIED:  # the search ended: every finger collides
            lower_bound = COLLISION_PENALTY
    else:
        chosen, base_index = best_path[1:].copy(), int(best_path[0])
    return make_result(space, chosen, np.zeros(blocks, np.int64), cost, status, base=base_index, nit=nit,
                       nfev=int(stats[1]), lower_bound=min(lower_bound, cost), control=control)
