"""Lookahead fields of the finger search: what any continuation of a partial finger can reach and what it
must cover, in the frame of the partial finger's end.

In piecewise constant curvature a block and every suffix of blocks after it have a shape in the frame of
their start that does not depend on what came before. So per block position d and per shape c the block
there may take, float32 grids in the frame of block d's start hold, once per design space:

- ``body``: a lower bound on the distance from the grid node to the centerline samples of c and of every
  suffix that can follow c (the objective's samples);
- ``tip``: a lower bound on the distance to the tip periphery points such a finger can end at;
- ``cover``: an upper bound on the distance from the node to the continuous centerline of *every* finger
  continuing with c: each of them passes within that distance of the node. A point of the object closer to
  the node than ``r - cover`` proves that all of them collide.

Suffix regions are built backwards on a finer grid: the body and tip regions of the suffix from d are
marked point sets (the samples of every shape at d, and the region from d + 1 moved to the end of each
shape), turned into distances by an exact Euclidean distance transform; the cover of the suffix from d is
max over shapes c of min(distance to c, cover from d + 1 seen from c's end). Every resampling between grids
is accounted for: lower bounds subtract, upper bounds add the distance to the grid node used (the fields
are 1-Lipschitz), and float32 storage rounds toward the safe side.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np
from numba import njit
from scipy import ndimage

from planner import clearance
from planner.clearance import block_point
from planner.kinematics import DEFAULT_SAMPLES_PER_BLOCK, chain_shape
from planner.optimize import field_cache
from planner.optimize.space import DesignSpace

SAMPLES_PER_BLOCK = DEFAULT_SAMPLES_PER_BLOCK  # the objective's centerline samples (planner.kinematics)
DENSE_PER_BLOCK = 96  # centerline points per block for the cover (continuous centerline within 0.1 mm)
FLOAT32_MARGIN = 1e-7  # [m] moved toward the safe side before storing bounds as float32
COVER_MARGIN = 1e-3  # [m] covers are kept up to r + this; larger ones can never prove a collision
KEPT_IN_MEMORY = 4  # field sets of recent design spaces kept loaded
_LOADED: OrderedDict[str, LookaheadFields] = OrderedDict()
_LOCKS: dict[str, threading.Lock] = {}  # one per field set: threads needing it load it once, others go on
_LOCKS_LOCK = threading.Lock()


@dataclass(frozen=True)
class BlockShapes:
    """Every distinct block shape in the frame of its start (x lateral toward the bend, z along)."""

    samples: np.ndarray  # (S, M, 2) the objective's centerline samples, start excluded
    dense: np.ndarray  # (S, DENSE_PER_BLOCK, 2) points of the continuous centerline, start and end included
    ends: np.ndarray  # (S, 3) end x, z and turn (theta)
    reach: np.ndarray  # (S,) farthest sample from the start [m]
    disc: np.ndarray  # (S, 3) centre x, z and radius of a disc holding the samples [m]
    theta: np.ndarray  # (S,)
    length: np.ndarray  # (S,)
    cap_length: float


def block_shapes(space: DesignSpace, cap_length: float) -> BlockShapes:
    """The shapes' samples, ends and discs (kept in memory: every search of the same table needs them)."""
    theta, length = np.asarray(space.theta, float), np.asarray(space.length, float)
    return _block_shapes(tuple(theta.tolist()), tuple(length.tolist()), float(cap_length))


@lru_cache(maxsize=KEPT_IN_MEMORY)
def _block_shapes(theta: tuple, length: tuple, cap_length: float) -> BlockShapes:
    theta, length = np.array(theta), np.array(length)
    shape = chain_shape(theta[:, None], length[:, None], 0.0, samples_per_block=SAMPLES_PER_BLOCK,
                        cap_length=cap_length)
    samples = shape.points[:, 1:, :][..., [0, 2]]
    ends = np.column_stack([shape.positions[:, 1, 0], shape.positions[:, 1, 2], theta])
    centre = 0.5 * (samples.min(axis=1) + samples.max(axis=1))
    disc = np.column_stack([centre, np.linalg.norm(samples - centre[:, None], axis=-1).max(axis=1)])
    dense = np.empty((len(theta), DENSE_PER_BLOCK, 2))
    for s, (bend, rod) in enumerate(zip(theta, length)):
        total = 2 * cap_length + rod
        dense[s] = [block_point(bend, rod, cap_length, total * i / (DENSE_PER_BLOCK - 1))
                    for i in range(DENSE_PER_BLOCK)]
    return BlockShapes(np.ascontiguousarray(samples), dense, ends, np.linalg.norm(samples, axis=-1).max(axis=1),
                       disc, theta, length, float(cap_length))


@dataclass(frozen=True)
class LookaheadFields:
    """Per block position d: float32 fields (rows, cols, choices) in the frame of block d's start, packed
    flat; ``layout[d]`` = (offset, rows, cols, x0, z0, reach, spacing): every sample from block d on lies
    within ``reach`` of block d's start (tip periphery points within reach + r), the grid covers r beyond
    that. The last block's grid is twice as fine (it decides which complete fingers are evaluated)."""

    body: np.ndarray
    tip: np.ndarray
    cover: np.ndarray
    discs: np.ndarray  # (N, C, 9): per next shape, a disc (x, z, radius) holding its samples, its end (x, z),
    # the reach of the blocks after it, and a point (x, z) and radius holding the tip periphery set
    layout: np.ndarray  # (N, 7) float64: offset, rows, cols, x0, z0, reach of the samples that follow, spacing

    @cached_property
    def node_minima(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per grid node of every position (flat, position d's nodes from ``first[d]``), the smallest body
        bound and the smallest cover over the position's next shapes: a contour point nearer to the prefix
        than the first keeps the prefix as its nearest whatever follows, and a point whose collision
        threshold (less its gap to the object) stays at or below the second proves no collision. Returns
        (first, nearest, cover)."""
        first, nearest, cover = [], [], []
        ends = [int(v) for v in self.layout[1:, 0]] + [self.body.size]
        for (offset, rows, cols), end in zip(self.layout[:, :3].astype(int), ends):
            first.append(sum(len(n) for n in nearest))
            nearest.append(self.body[offset:end].reshape(rows * cols, -1).min(axis=1))
            cover.append(self.cover[offset:end].reshape(rows * cols, -1).min(axis=1))
        return np.array(first, np.int64), np.concatenate(nearest), np.concatenate(cover)


def lookahead_fields(shapes: BlockShapes, space: DesignSpace, radius: float, field_spacing: float,
                     region_spacing: float) -> LookaheadFields:
    """The lookahead fields of ``space``. They depend only on the block geometry, the radius and the
    per-position choices (never on the object), so they are kept in memory and on disk
    (``planner.optimize.field_cache``): building them takes seconds, loading them a fraction of one."""
    choices = tuple(np.asarray(c, dtype=np.int64) for c in space.choices)
    digest = field_cache.key_digest(
        (shapes.samples, shapes.dense, shapes.ends, shapes.theta, shapes.length, shapes.cap_length, float(radius),
         choices, float(field_spacing), float(region_spacing)),
        modules=(__name__, clearance.__name__))
    with _LOCKS_LOCK:
        lock = _LOCKS.setdefault(digest, threading.Lock())
    with lock:
        fields = _LOADED.get(digest)
        if fields is None:
            arrays = field_cache.load_or_build(
                "lookahead", digest, lambda: _build(shapes, choices, float(radius), field_spacing, region_spacing))
            fields = LookaheadFields(**arrays)
            fields.node_minima  # derived here, once, rather than in the first search that needs them
            with _LOCKS_LOCK:
                _LOADED[digest] = fields
                while len(_LOADED) > KEPT_IN_MEMORY:
                    _LOADED.popitem(last=False)
        return fields


# ------------------------------------------------------------------------------------------- kernels
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
def _grid_upper(field, x0, spacing, x, z, cap):
    """Upper bound on a 1-Lipschitz cover at (x, z) from its values at the nodes of a square grid (both
    axes from x0); ``cap`` (no information) outside the grid."""
    b = int(np.round((x - x0) / spacing))
    a = int(np.round((z - x0) / spacing))
    size = field.shape[0]
    if a < 0 or b < 0 or a >= size or b >= size:
        return cap
    return min(field[a, b] + np.hypot(x - (x0 + b * spacing), z - (x0 + a * spacing)), cap)


@njit(cache=True)
def _block_windows(dense, spacing, cap, out):
    """out[s, a, b] = min(cap, distance from node (x, z) = ((b - w) spacing, (a - w) spacing) to the
    nearest dense centerline point of shape s), w = half the window; an upper bound on the distance to the
    continuous centerline."""
    w = (out.shape[1] - 1) // 2
    reach = int(np.ceil(cap / spacing))
    out[:] = cap
    for s in range(dense.shape[0]):
        for m in range(dense.shape[1]):
            px, pz = dense[s, m, 0], dense[s, m, 1]
            cb, ca = int(np.round(px / spacing)) + w, int(np.round(pz / spacing)) + w
            for a in range(max(ca - reach, 0), min(ca + reach + 1, out.shape[1])):
                for b in range(max(cb - reach, 0), min(cb + reach + 1, out.shape[2])):
                    value = np.hypot((b - w) * spacing - px, (a - w) * spacing - pz)
                    if value < out[s, a, b]:
                        out[s, a, b] = value


@njit(cache=True)
def _cover_region(windows, spacing, ends, choices, later, has_later, cap, out):
    """Cover of the suffixes from one block position on a square grid centred on that block's start (same
    spacing as the windows): out = max over shapes c of min(distance to c, cover after c seen from c's
    end), each an upper bound; at most ``cap``."""
    half = (out.shape[0] - 1) // 2
    w = (windows.shape[1] - 1) // 2
    later_x0 = -((later.shape[0] - 1) // 2) * spacing
    for a in range(out.shape[0]):
        for b in range(out.shape[1]):
            x, z = (b - half) * spacing, (a - half) * spacing
            worst = 0.0
            for k in range(choices.shape[0]):
                c = choices[k]
                wa, wb = a - half + w, b - half + w
                value = windows[c, wa, wb] if 0 <= wa < windows.shape[1] and 0 <= wb < windows.shape[2] else cap
                if has_later and value > worst:
                    cos, sin = np.cos(ends[c, 2]), np.sin(ends[c, 2])
                    dx, dz = x - ends[c, 0], z - ends[c, 1]
                    value = min(value, _grid_upper(later, later_x0, spacing, dx * cos - dz * sin, dx * sin + dz * cos,
                                                   cap))
                worst = max(worst, value)
                if worst >= cap:
                    break
            out[a, b] = worst


@njit(cache=True)
def _fill_level(out_body, out_tip, out_cover, x0, z0, spacing, choices, samples, ends, radius, region, region_tip,
                rx0, rz0, region_spacing, region_error, windows, later_cover, cap, last):
    """Lookahead fields of one block position at every node: for each allowed next shape c, a lower bound
    on the distance to (c's samples and the suffix region after c) and to the tip periphery set after c, and
    an upper bound on the distance to every continuation's centerline (the cover)."""
    rows, cols, count = out_body.shape
    w = (windows.shape[1] - 1) // 2
    later_x0 = -((later_cover.shape[0] - 1) // 2) * region_spacing
    for a in range(rows):
        z = z0 + a * spacing
        for b in range(cols):
            x = x0 + b * spacing
            for k in range(count):
                c = choices[k]
                nearest = np.inf
                for m in range(samples.shape[1]):
                    nearest = min(nearest, np.hypot(x - samples[c, m, 0], z - samples[c, m, 1]))
                cover = _grid_upper(windows[c], -w * region_spacing, region_spacing, x, z, cap)
                cos, sin = np.cos(ends[c, 2]), np.sin(ends[c, 2])
                dx, dz = x - ends[c, 0], z - ends[c, 1]
                if last:  # no block after c: its own samples and its own tip periphery point
                    tip = np.hypot(dx - radius * cos, dz + radius * sin)
                else:
                    px, pz = dx * cos - dz * sin, dx * sin + dz * cos  # in the frame of c's end
                    later = _grid_lower(region, rx0, rz0, region_spacing, px, pz) - region_error
                    nearest = min(nearest, later)
                    tip = _grid_lower(region_tip, rx0, rz0, region_spacing, px, pz) - region_error
                    cover = min(cover, _grid_upper(later_cover, later_x0, region_spacing, px, pz, cap))
                out_body[a, b, k] = nearest - FLOAT32_MARGIN
                out_tip[a, b, k] = max(tip, 0.0) - FLOAT32_MARGIN
                out_cover[a, b, k] = cover + FLOAT32_MARGIN


# ------------------------------------------------------------------------------------------- builder
def _build(shapes: BlockShapes, choices, radius: float, field_spacing: float, region_spacing: float) -> dict:
    samples, ends, dense = shapes.samples, shapes.ends, shapes.dense
    blocks = len(choices)
    reach = np.linalg.norm(samples, axis=-1).max(axis=1)
    ahead = [sum(reach[c].max() for c in choices[d:]) + radius for d in range(blocks + 1)]
    cap = radius + COVER_MARGIN
    h = region_spacing
    # suffix regions after each position, all on one square grid centred on the suffix's start
    dense_reach = np.linalg.norm(dense, axis=-1).max(axis=1)
    extent = np.ceil((max(ahead[1], sum(dense_reach[c].max() for c in choices[1:]) + cap) + 4 * h) / h) * h
    size = int(round(2 * extent / h)) + 1
    windows = np.empty((len(samples), *(2 * [2 * int(np.ceil((dense_reach.max() + cap) / h)) + 3])))
    _block_windows(dense, h, cap, windows)
    none = np.zeros((1, 1))
    regions, tips, covers = [none] * (blocks + 1), [none] * (blocks + 1), [none] * (blocks + 1)
    errors = np.zeros(blocks + 1)
    marked_body = marked_tip = None
    for d in range(blocks - 1, 0, -1):  # the suffix d..N-1, in the frame of block d's start
        body = np.zeros((size, size), dtype=bool)
        tip = np.zeros((size, size), dtype=bool)
        for c in choices[d]:
            _mark(samples[c], body, -extent, -extent, h)
            if marked_body is None:
                turn = ends[c, 2]
                periphery = np.array([[ends[c, 0] + radius * np.cos(turn), ends[c, 1] - radius * np.sin(turn)]])
                _mark(periphery, tip, -extent, -extent, h)
            else:
                _mark_moved(marked_body, -extent, -extent, h, *ends[c], body)
                _mark_moved(marked_tip, -extent, -extent, h, *ends[c], tip)
        errors[d] = errors[d + 1] + h / np.sqrt(2)  # each re-marking moves a point by up to half a diagonal
        regions[d] = ndimage.distance_transform_edt(~body) * h
        tips[d] = ndimage.distance_transform_edt(~tip) * h
        covers[d] = np.empty((size, size))
        _cover_region(windows, h, ends, choices[d], covers[d + 1], d < blocks - 1, cap, covers[d])
        marked_body, marked_tip = body, tip
    layout, parts, offset = np.zeros((blocks, 7)), {"body": [], "tip": [], "cover": []}, 0
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
        spacing = field_spacing / 2 if last else field_spacing
        half = ahead[d] + 2 * spacing
        cells = int(np.ceil(2 * half / spacing)) + 1
        out = {name: np.empty((cells, cells, len(choices[d])), dtype=np.float32) for name in parts}
        _fill_level(out["body"], out["tip"], out["cover"], -half, -half, spacing, choices[d], samples, ends, radius,
                    regions[d + 1], tips[d + 1], -extent, -extent, h, errors[d + 1], windows, covers[d + 1], cap, last)
        layout[d] = (offset, cells, cells, -half, -half, ahead[d] - radius, spacing)
        offset += cells * cells * len(choices[d])
        for name in parts:
            parts[name].append(out[name].ravel())
    return {name: np.concatenate(values) for name, values in parts.items()} | {"discs": discs, "layout": layout}
