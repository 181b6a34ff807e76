"""Branch and bound over block prefixes with a widening beam and local search ("exact" method for paths).

A chain is built from its base. Once blocks 1..k are placed, their centerline samples are fixed, and so is
each target point's distance ``a`` to them. The remaining blocks start at the prefix end, reach at most
``R`` from it (sum of the longest remaining block chords) and, while their total bend stays below 90
degrees, stay ahead of the end (planar chains bending toward +x also stay on its +x side). With ``b`` the
distance of a target point to that region, its final centerline distance lies in [min(a, b), a], which
bounds its error term from below; the tip term is bounded the same way. The bound is exact for complete
chains. (Fingers, which must also keep clear of an object, have their own certified search:
``planner.optimize.finger_search``.)

The search runs level by level (block 1, 2, ...) and drops every prefix whose bound reaches the best
complete design found. Rounds keep the ``width`` best prefixes per level and also the ``width // bases``
best of each candidate base position (so one base cannot crowd out the others: fingers whose best base
ranks low early were missed otherwise), starting narrow and widening by ``growth`` up to ``max_width``.
Which prefixes are best is a heuristic order (``PrefixSearch._rank``);
the best complete designs of each round are improved by block-by-block local search
(``planner.optimize.local_search``). Certificate: a round that dropped no prefix whose bound was below
its best design proves that design optimal (``optimal=True``); otherwise the smallest dropped bound is a
proven lower bound (``lower_bound``). Small spaces certify (``max_width=None`` widens until they do); for
long 3D paths the bound is weak (path points still ahead of a prefix bound to about zero), so those runs
end uncertified with a proven but loose lower bound.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.assembly import ROTATION_STEP
from planner.kinematics import CAP_LENGTH, DEFAULT_SAMPLES_PER_BLOCK, chain_shape
from planner.objectives import ShapeTarget
from planner.optimize.local_search import polish
from planner.optimize.result import DesignOptimizeResult, RunControl, Status, Stop, make_result
from planner.optimize.space import DesignSpace

DEFAULT_OPTIONS = {
    "initial_width": 16,  # best prefixes kept per level in the first round (plus the best per base)
    "growth": 8,  # width factor between rounds
    "max_width": 256,  # the last round's width; None: widen until certified (unlimited at the end)
    "unlimited_after": 1024,  # with max_width None: after this width the next round is unlimited
    "samples_per_block": DEFAULT_SAMPLES_PER_BLOCK,
    "chunk_elements": 1_500_000,  # work array size per vectorised step
    "polish_starts": 8,  # best complete designs (and best per base) of each round improved by local search
}


@dataclass(frozen=True)
class BlockLibrary:
    """Each (shape, rotation) block in the frame of its start; samples exclude the start point."""

    samples: np.ndarray  # (S, J, M, 3)
    end_rotation: np.ndarray  # (S, J, 3, 3)
    end_position: np.ndarray  # (S, J, 3)
    reach: float  # farthest sample from a block start [m]
    remaining_length: np.ndarray  # (N,) after block k: sum of the longest chords of blocks k+1.. [m]
    remaining_turn: np.ndarray  # (N, 2) after block k: least and most total bend of blocks k+1.. [rad]


def block_library(space: DesignSpace, samples_per_block: int) -> BlockLibrary:
    phi = np.arange(space.rotations) * ROTATION_STEP
    shape = chain_shape(
        space.theta[:, None, None], space.length[:, None, None], phi[None, :, None], samples_per_block=samples_per_block
    )
    samples = shape.points[:, :, 1:, :]
    chord = np.linalg.norm(shape.positions[:, 0, 1, :], axis=-1)
    longest = np.array([chord[c].max() for c in space.choices])
    least_bend = np.array([np.minimum(space.theta[c], 0).min() for c in space.choices])
    most_bend = np.array([np.maximum(space.theta[c], 0).max() for c in space.choices])
    after = lambda values: np.concatenate([np.cumsum(values[::-1])[::-1][1:], [0.0]])  # noqa: E731
    return BlockLibrary(
        samples=samples,
        end_rotation=shape.rotations[:, :, 1],
        end_position=shape.positions[:, :, 1],
        reach=float(np.linalg.norm(samples, axis=-1).max()),
        remaining_length=after(longest),
        remaining_turn=np.stack([after(least_bend), after(most_bend)], axis=-1),
    )


@dataclass
class _Prefixes:
    """Partial chains of one level (n of them)."""

    base: np.ndarray  # (n,) index into the target's candidate bases
    shapes: np.ndarray  # (n, k)
    rotations: np.ndarray  # (n, k)
    frame_rotation: np.ndarray  # (n, 3, 3) end frame
    frame_position: np.ndarray  # (n, 3)
    nearest: np.ndarray  # (n, P) distance of each target point to the prefix samples
    counts: np.ndarray | None  # (n, S) blocks used per shape (inventory only)
    stiff_counts: np.ndarray | None
    bound: np.ndarray  # (n,)
    rank: np.ndarray  # (n,) beam order (see PrefixSearch.expand)
    travelled: np.ndarray  # (n,) centerline length so far [m]

    def __len__(self) -> int:
        return len(self.bound)

    def take(self, index) -> _Prefixes:
        pick = lambda a: None if a is None else a[index]  # noqa: E731
        return _Prefixes(*(pick(getattr(self, f)) for f in self.__dataclass_fields__))

    @staticmethod
    def concat(parts: list[_Prefixes]) -> _Prefixes:
        join = lambda arrays: None if arrays[0] is None else np.concatenate(arrays)  # noqa: E731
        return _Prefixes(*(join([getattr(p, f) for p in parts]) for f in _Prefixes.__dataclass_fields__))


class PrefixSearch:
    """One design problem: target, design space and precomputed block geometry."""

    def __init__(self, target: ShapeTarget, space: DesignSpace, samples_per_block: int = DEFAULT_SAMPLES_PER_BLOCK,
                 chunk_elements: int = DEFAULT_OPTIONS["chunk_elements"], polish_starts: int = 0):
        self.target = target
        self.samples_per_block = samples_per_block
        self.chunk_elements = chunk_elements
        self.polish_starts = polish_starts
        self.space = space
        self.library = block_library(space, samples_per_block)
        self.targets_sq = np.einsum("pk,pk->p", target.points, target.points)
        steps = np.linalg.norm(np.diff(target.points, axis=0), axis=1)
        self.target_arc = np.linalg.norm(target.points[0]) + np.concatenate([[0.0], np.cumsum(steps)])
        self.block_arc = space.length + 2 * CAP_LENGTH

    def root(self) -> _Prefixes:
        """One empty chain per candidate base position."""
        bases = self.target.bases
        count = len(bases)
        inventory = self.space.stock is not None
        counts = np.zeros((count, len(self.space.theta)), dtype=np.int16) if inventory else None
        return _Prefixes(
            base=np.arange(count),
            shapes=np.zeros((count, 0), dtype=np.int64),
            rotations=np.zeros((count, 0), dtype=np.int64),
            frame_rotation=np.repeat(np.eye(3)[None], count, axis=0),
            frame_position=bases.copy(),
            nearest=np.linalg.norm(self.target.points[None] - bases[:, None], axis=-1),
            counts=counts,
            stiff_counts=None if counts is None else counts.copy(),
            bound=np.zeros(count),
            rank=np.zeros(count),
            travelled=np.zeros(count),
        )

    def options(self, level: int) -> tuple[np.ndarray, np.ndarray]:
        """(shape, rotation) pairs allowed at block ``level``."""
        shapes = np.repeat(self.space.choices[level], self.space.rotations)
        rotations = np.tile(np.arange(self.space.rotations), len(self.space.choices[level]))
        return shapes, rotations

    def expand(self, parents: _Prefixes, level: int, ranked: bool = True) -> _Prefixes:
        """All allowed children of ``parents`` with their bounds (inventory-breaking children omitted);
        ``ranked`` False skips the beam order (unlimited rounds keep every child anyway)."""
        target, library = self.target, self.library
        shapes, rotations = self.options(level)
        n, q = len(parents), len(shapes)
        local = library.samples[shapes, rotations]  # (Q, M, 3)
        rotation, position = parents.frame_rotation, parents.frame_position
        world = (local.reshape(-1, 3) @ rotation.transpose(0, 2, 1)).reshape(n, q, -1, 3) + position[:, None, None, :]

        nearest = np.repeat(parents.nearest[:, None, :], q, axis=1)
        to_end = np.linalg.norm(target.points[None] - position[:, None, :], axis=-1)
        active = np.flatnonzero(np.any(to_end - library.reach < parents.nearest, axis=0))
        if active.size:
            squared = world @ (-2.0 * target.points[active].T)  # |w|^2 - 2 w.p + |p|^2, in place
            squared += np.einsum("nqmk,nqmk->nqm", world, world)[..., None]
            new = np.sqrt(np.maximum(squared.min(axis=-2) + self.targets_sq[active], 0.0))
            nearest[..., active] = np.minimum(nearest[..., active], new)

        end_rotation = rotation[:, None] @ library.end_rotation[shapes, rotations][None]
        end_position = position[:, None] + library.end_position[shapes, rotations] @ rotation.transpose(0, 2, 1)
        bound = self._bound(nearest, end_rotation, end_position, level)
        travelled = parents.travelled[:, None] + self.block_arc[shapes]
        rank = self._rank(bound, nearest, travelled, end_rotation, end_position, level) if ranked else bound

        keep = np.ones((n, q), dtype=bool)
        counts = stiff_counts = None
        if parents.counts is not None:
            stiff = self.space.stiff_positions[level]
            keep &= parents.counts[:, shapes] < self.space.stock[shapes]
            if stiff:
                keep &= parents.stiff_counts[:, shapes] < self.space.stiff_stock[shapes]
            one_hot = (shapes[:, None] == np.arange(len(self.space.theta))).astype(np.int16)
            counts = parents.counts[:, None, :] + one_hot
            stiff_counts = parents.stiff_counts[:, None, :] + (one_hot if stiff else 0 * one_hot)
        flat = keep.reshape(-1)
        reshape = lambda a, *tail: a.reshape(n * q, *tail)[flat]  # noqa: E731
        return _Prefixes(
            base=np.repeat(parents.base, q)[flat],
            shapes=np.concatenate([np.repeat(parents.shapes, q, axis=0), np.tile(shapes, n)[:, None]], axis=1)[flat],
            rotations=np.concatenate(
                [np.repeat(parents.rotations, q, axis=0), np.tile(rotations, n)[:, None]], axis=1
            )[flat],
            frame_rotation=reshape(end_rotation, 3, 3),
            frame_position=reshape(end_position, 3),
            nearest=reshape(nearest, nearest.shape[-1]),
            counts=None if counts is None else reshape(counts, counts.shape[-1]),
            stiff_counts=None if stiff_counts is None else reshape(stiff_counts, stiff_counts.shape[-1]),
            bound=reshape(bound),
            rank=reshape(rank),
            travelled=reshape(travelled),
        )

    def _rank(self, bound, nearest, travelled, rotation, position, level: int) -> np.ndarray:
        """Beam order of children (a heuristic; pruning uses the bound alone): the error of the target
        points up to the same length along the path, plus the distance from the prefix end to the path
        point at that length (where the tip should be by now).
        """
        target = self.target
        covered = self.target_arc <= travelled[..., None]
        passed = np.where(covered, np.abs(nearest - target.offset), 0.0).sum(axis=-1)
        due = np.stack([np.interp(travelled, self.target_arc, target.points[:, k]) for k in range(3)], axis=-1)
        return passed + np.linalg.norm(position - due, axis=-1)

    def _region_distance(self, points, rotation, position, level: int) -> np.ndarray:
        """Lower bound on the distance from points (P, 3) to the blocks after ``level`` -> (..., P).

        Those blocks lie within ``remaining_length`` of the prefix end. While their total bend stays below
        90 degrees their tangents keep a non-negative component along the end tangent, so they lie ahead
        of the end; planar chains that only bend toward +x also stay on its +x side. (Dot products as
        matrix products with the points: no (..., P, 3) temporaries.)
        """
        along = lambda axis: axis @ points.T - np.einsum("...k,...k->...", axis, position)[..., None]  # noqa: E731
        squared = (np.einsum("pk,pk->p", points, points) - 2.0 * position @ points.T
                   + np.einsum("...k,...k->...", position, position)[..., None])
        bound = np.maximum(np.sqrt(np.maximum(squared, 0.0)) - self.library.remaining_length[level], 0.0)
        least, most = self.library.remaining_turn[level]
        if max(abs(least), abs(most)) <= np.pi / 2:
            behind = np.maximum(-along(rotation[..., :, 2]), 0.0)
            if self.space.rotations == 1 and least >= 0:
                behind = np.hypot(behind, np.maximum(-along(rotation[..., :, 0]), 0.0))
            bound = np.maximum(bound, behind)
        return bound

    def _bound(self, nearest, rotation, position, level: int) -> np.ndarray:
        target = self.target
        tip = position + target.tip_offset * rotation[..., :, 0]
        if level == self.space.num_blocks - 1:  # complete chains: the objective itself
            gaps = np.abs(nearest - target.offset).sum(axis=-1)
            end_error = np.linalg.norm(tip - target.end_point, axis=-1)
        else:
            later = self._region_distance(target.points, rotation, position, level)
            lowest = np.minimum(nearest, later)
            gaps = np.maximum(np.maximum(lowest - target.offset, target.offset - nearest), 0.0).sum(axis=-1)
            end_region = self._region_distance(target.end_point[None], rotation, position, level)[..., 0]
            end_error = np.maximum(end_region - target.tip_offset, 0.0)
        return target.start_error + end_error + gaps


@dataclass
class _Best:
    cost: float = np.inf
    shapes: np.ndarray | None = None
    rotations: np.ndarray | None = None
    base: int = 0


def _take_best(search: PrefixSearch, leaves: _Prefixes, best: _Best, control: RunControl, stats: dict) -> None:
    """Update ``best`` with the best complete designs of a round after local search from the top few."""
    starts = min(search.polish_starts, len(leaves))
    candidates = [(float(leaves.bound[i]), leaves.shapes[i], leaves.rotations[i], int(leaves.base[i]))
                  for i in [int(np.argmin(leaves.bound))]]
    if starts:  # the best few, and the best for each base position, for diversity
        order = np.argsort(leaves.bound)
        first_per_base = order[np.unique(leaves.base[order], return_index=True)[1]]
        top = np.union1d(order[:starts], first_per_base)
        shapes, rotations, bases, costs, nfev = polish(
            search.target, search.space, leaves.shapes[top], leaves.rotations[top], leaves.base[top], control,
            search.samples_per_block,
        )
        stats["nfev"] += nfev
        candidates += [(float(c), s, r, int(b)) for c, s, r, b in zip(costs, shapes, rotations, bases)]
    cost, shapes, rotations, base = min(candidates, key=lambda c: c[0])
    if cost < best.cost:
        best.cost, best.shapes, best.rotations, best.base = cost, shapes, rotations, base


def _beam(prefixes: _Prefixes, width: int, bases: int) -> np.ndarray:
    """Mask of the prefixes a round keeps: the ``width`` best-ranked ones, and also the best
    ``width // bases`` of each base position, so that no base is crowded out by the others."""
    keep = np.zeros(len(prefixes), dtype=bool)
    keep[np.argpartition(prefixes.rank, min(width, len(prefixes) - 1))[:width]] = True
    order = np.lexsort((prefixes.rank, prefixes.base))
    grouped = prefixes.base[order]
    first = np.searchsorted(grouped, grouped)  # start of each prefix's base group in ``order``
    keep[order[np.arange(len(order)) - first < max(width // bases, 1)]] = True
    return keep


def _run_round(search: PrefixSearch, width: int | None, best: _Best, control: RunControl, stats: dict,
               round_fraction) -> float:
    """One level-by-level pass; updates ``best``; returns the smallest bound it dropped for width."""
    dropped = np.inf
    level_prefixes = search.root()
    bases = len(search.target.bases)
    blocks = search.space.num_blocks
    q_max = max(len(search.options(k)[0]) for k in range(blocks))
    per_child = q_max * search.library.samples.shape[-2] * len(search.target.points)
    chunk = max(1, search.chunk_elements // per_child)
    for level in range(blocks):
        kept: list[_Prefixes] = []
        held = 0
        for start in range(0, len(level_prefixes), chunk):
            control.check_time()
            children = search.expand(level_prefixes.take(slice(start, start + chunk)), level, width is not None)
            stats["nfev"] += len(children)
            children = children.take(children.bound < best.cost)
            if not len(children):
                continue
            kept.append(children)
            held += len(children)
            if width is not None and held > 4 * width:
                merged = _Prefixes.concat(kept)
                keep = _beam(merged, width, bases)
                dropped = min(dropped, merged.bound[~keep].min(initial=np.inf))
                kept = [merged.take(keep)]
                held = len(kept[0])
        if not kept:
            return dropped
        level_prefixes = _Prefixes.concat(kept)
        if width is not None and len(level_prefixes) > width:
            keep = _beam(level_prefixes, width, bases)
            dropped = min(dropped, level_prefixes.bound[~keep].min(initial=np.inf))
            level_prefixes = level_prefixes.take(keep)
        if level == blocks - 1:
            _take_best(search, level_prefixes, best, control, stats)
        control.report(round_fraction(level + 1, blocks), best.cost, stats["nfev"])
    return dropped


def _width_schedule(settings: dict) -> list[int | None]:
    """Beam widths of the rounds: initial_width, times growth, ..., up to max_width (None = unlimited)."""
    widths, width, limit = [], settings["initial_width"], settings["max_width"]
    while True:
        if limit is not None and width >= limit:
            return widths + [limit]
        if limit is None and width > settings["unlimited_after"]:
            return widths + [None]
        widths.append(width)
        width *= settings["growth"]


def solve_exact(target: ShapeTarget, space: DesignSpace, *, options: dict | None = None, time_budget=None,
                callback=None) -> DesignOptimizeResult:
    """Minimise the objective of ``target`` (a path: fingers go to ``solve_finger``) over ``space`` by prefix
    branch and bound (see module doc)."""
    if target.body is not None:
        raise ValueError("solve_exact designs paths; a finger target (with a body) needs solve_finger")
    unknown = set(options or {}) - set(DEFAULT_OPTIONS)
    if unknown:
        raise ValueError(f"options: unknown keys {sorted(unknown)}; known: {sorted(DEFAULT_OPTIONS)}")
    settings = DEFAULT_OPTIONS | (options or {})
    if not (isinstance(settings["initial_width"], int) and settings["initial_width"] >= 1):
        raise ValueError("options['initial_width'] must be an integer >= 1")
    if not settings["growth"] > 1:
        raise ValueError("options['growth'] must be > 1")
    control = RunControl(time_budget, callback)
    search = PrefixSearch(target, space, settings["samples_per_block"], settings["chunk_elements"],
                          settings["polish_starts"])
    best, stats = _Best(), {"nfev": 0}
    lower_bound, status, rounds = -np.inf, Status.FINISHED, 0
    widths = _width_schedule(settings)
    try:
        for rounds, width in enumerate(widths, start=1):
            dropped = _run_round(
                search, width, best, control, stats,
                lambda level, blocks, done=rounds - 1: (done + level / blocks) / len(widths),
            )
            lower_bound = min(best.cost, dropped)
            if dropped >= best.cost:
                status = Status.CERTIFIED
                break
    except Stop as stop:
        status = stop.status
    if best.shapes is None:  # stopped before the first complete design: take the first choice everywhere
        best.shapes = np.array([c[0] for c in space.choices])
        best.rotations = np.zeros(space.num_blocks, dtype=np.int64)
        best.cost = np.inf
    return make_result(space, best.shapes, best.rotations, best.cost, status, base=best.base, nit=rounds,
                       nfev=stats["nfev"], lower_bound=lower_bound, control=control)
