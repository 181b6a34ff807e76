"""High-level design API: fingers that conform to an object image, chains that follow a 3D path.

Finger placement (the convention behind eq. 3): the object is grasped vertically, so each finger hangs
straight down from the object's top edge (z = 0 of the ``planner.contours`` object frame) and bends toward
the object. Its base centerline point sits one block radius outside the object's bounding box (x = -w/2 - r
for the left finger, +w/2 + r for the right; a straight finger then just touches the widest point) plus an
outward offset that the optimizer chooses from ``base_offsets`` (default 0-12 mm in 1 mm steps) together
with the blocks: the blocks only curl toward the object, so an object that is widest low down needs the
base farther out. The left finger is matched to the left contour, the right finger to the right
one; contours are resampled every ``contour_spacing`` along their length so the cost does not depend on
the image resolution.
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from planner.assembly import ROTATION_STEP
from planner.clearance import FingerBody, ObjectDistance
from planner.contours import extract_contours
from planner.kinematics import BLOCK_RADIUS, CAP_LENGTH, chain_shape, design_parameters
from planner.objectives import ShapeTarget, evaluate, finger_target, path_target
from planner.optimize import (DesignOptimizeResult, DesignSpace, design_space, solve_exact, solve_finger,
                              solve_pso)
from planner.optimize.finger_search import DEFAULT_OPTIONS as FINGER_OPTIONS
from planner.optimize.front_search import solve_finger_front
from planner.optimize.lookahead import block_shapes, lookahead_fields
from planner.optimize.space import MAX_BLOCKS
from planner.table import load_table

DEFAULT_MIN_STIFF_ROD_DIAMETER = 0.62e-3  # [m], the D of ID 57 used for the paper's stiff blocks
DEFAULT_CONTOUR_SPACING = 1e-3  # [m]
DEFAULT_BASE_OFFSETS = np.arange(0.0, 12.5e-3, 1e-3)  # outward from touching the bounding box [m]
PATH_EXACT_OPTIONS = {"max_width": 64, "polish_starts": 1}  # 12 rotations x 84 shapes per block: narrow
GRIPPER_CONFIGURATIONS = ((4, 2), (5, 3))  # (blocks, stiff top) of the paper's gripper: front and back fingers
PREPARED_CONFIGURATIONS = (*GRIPPER_CONFIGURATIONS, (5, 2))  # and of the benchmarks
METHODS = ("exact", "pso")


@dataclass(frozen=True)
class FingerDesign:
    """One optimized finger; geometry in the object frame (x right, z up) [m]."""

    side: str  # "left" or "right"
    design_ids: tuple[int, ...]  # base (top) first
    cost: float  # eq. (3) [m], including k = 1e11 if colliding
    collision: bool
    min_clearance_m: float  # smallest distance between the finger body and the object [m]; negative: overlap
    optimal: bool  # certified optimum for this finger
    lower_bound_m: float  # proven lower bound on this finger's optimum [m] (= cost when optimal)
    contour: np.ndarray  # (n, 2) the resampled target contour
    centerline: np.ndarray  # (m, 2) the finger's centerline samples, base first
    base: np.ndarray  # (2,) base centerline point
    result: DesignOptimizeResult


@dataclass(frozen=True)
class FingerDesignResult:
    left: FingerDesign | None
    right: FingerDesign | None
    success: bool
    message: str
    optimal: bool
    solve_time: float  # [s]


@dataclass(frozen=True)
class PathDesignResult:
    design_ids: tuple[int, ...]
    rotation_steps: tuple[int, ...]
    cost: float  # eq. (1) [m]
    success: bool
    message: str
    optimal: bool
    lower_bound: float  # proven lower bound on the optimum [m] (-inf if none)
    solve_time: float  # [s]
    centerline: np.ndarray  # (m, 3) in the chain base frame [m]
    result: DesignOptimizeResult


def _check_common(num_blocks, method: str) -> None:
    whole = isinstance(num_blocks, (int, np.integer)) and not isinstance(num_blocks, bool)
    if not whole or not 1 <= num_blocks <= MAX_BLOCKS:
        raise ValueError(f"num_blocks must be an integer 1..{MAX_BLOCKS}, got {num_blocks!r}")
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")


def _optimize(target: ShapeTarget, space: DesignSpace, method: str, *, seed, time_budget, callback, options):
    if method == "pso":
        return solve_pso(target, space, rng=np.random.default_rng(seed), options=options,
                         time_budget=time_budget, callback=callback)
    solve = solve_exact if target.body is None else solve_finger
    return solve(target, space, options=options, time_budget=time_budget, callback=callback)


def resample_polyline(points: np.ndarray, spacing: float) -> np.ndarray:
    """Points every ``spacing`` along a polyline (n, d), first and last point kept."""
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(step)])
    count = max(int(np.ceil(arc[-1] / spacing)), 1) + 1
    where = np.linspace(0.0, arc[-1], count)
    return np.stack([np.interp(where, arc, points[:, k]) for k in range(points.shape[1])], axis=1)


def _scaled_callback(callback, start: float, share: float):
    """Pass progress of one finger on as a fraction of the whole request."""
    if callback is None:
        return None

    def scaled(progress):
        callback(type(progress)(start + share * progress.fraction, progress.best_cost, progress.nfev,
                                progress.elapsed))

    return scaled


class _PairProgress:
    """The user's callback for two fingers designed at once: it hears the mean fraction done, one call at a
    time; once it cancels (StopIteration), both fingers stop."""

    def __init__(self, callback):
        self._callback = callback
        self._fractions = [0.0, 0.0]
        self._lock = threading.Lock()
        self._canceled = False

    def for_side(self, index: int):
        if self._callback is None:
            return None

        def report(progress):
            with self._lock:
                if not self._canceled:
                    self._fractions[index] = progress.fraction
                    try:
                        self._callback(type(progress)(0.5 * sum(self._fractions), progress.best_cost, progress.nfev,
                                                      progress.elapsed))
                    except StopIteration:
                        self._canceled = True
                if self._canceled:
                    raise StopIteration

        return report


def finger_problems(contours, base_offsets=DEFAULT_BASE_OFFSETS, contour_spacing: float = DEFAULT_CONTOUR_SPACING,
                    contact_tolerance_m: float = 0.0) -> dict[str, tuple[ShapeTarget, np.ndarray]]:
    """The eq. (3) target of each finger ("left", "right") of an object (``planner.contours.ObjectContours``)
    and its resampled contour in the object frame, placed as the module docstring says."""
    distance = ObjectDistance.from_contours(contours)
    problems = {}
    for side, contour, sign in (("left", contours.left, 1.0), ("right", contours.right, -1.0)):
        base_x = -sign * (contours.width / 2 + BLOCK_RADIUS)
        body = FingerBody(distance, base_x, sign, contact_tolerance_m=float(contact_tolerance_m))
        resampled = resample_polyline(contour, contour_spacing)
        finger_frame = np.stack([sign * (resampled[:, 0] - base_x), np.zeros(len(resampled)), -resampled[:, 1]], 1)
        problems[side] = (finger_target(finger_frame, body, base_offsets), resampled)
    return problems


def design_fingers(
    mask: np.ndarray,
    pixel_size: float,
    num_blocks: int,
    *,
    num_stiff_top: int = 0,
    min_stiff_rod_diameter: float = DEFAULT_MIN_STIFF_ROD_DIAMETER,
    method: str = "exact",
    time_budget: float | None = None,
    seed: int = 0,
    inventory: dict[int, int] | None = None,
    table=None,
    callback=None,
    options: dict | None = None,
    contour_spacing: float = DEFAULT_CONTOUR_SPACING,
    base_offsets=DEFAULT_BASE_OFFSETS,
    contact_tolerance_m: float = 0.0,
) -> FingerDesignResult:
    """Design a left and a right finger of ``num_blocks`` conforming to the object in ``mask`` (eq. 3).

    The top ``num_stiff_top`` blocks of each finger must have a rod diameter >= ``min_stiff_rod_diameter``
    [m]. ``inventory`` (design ID -> blocks on the shelf) is shared by both fingers: when their separate
    optima do not fit together, the right finger is redesigned from what the left one leaves (the pair is
    then not certified). ``callback(progress)`` gets a ``planner.optimize.Progress`` and may raise
    StopIteration to cancel. The two fingers are designed at once (two threads; the compiled search releases
    the GIL). ``time_budget`` [s] covers both fingers; the exact method certifies its result
    unless the budget ends it first (it then says so and reports a proven lower bound). ``options`` go to the
    optimizer (``planner.optimize.finger_search.DEFAULT_OPTIONS`` or ``planner.optimize.pso.DEFAULT_OPTIONS``).
    ``contact_tolerance_m``: how far the finger body may enter the object before it counts as a collision
    (0: touching only).
    """
    _check_common(num_blocks, method)
    if not isinstance(num_stiff_top, (int, np.integer)) or not 0 <= num_stiff_top <= num_blocks:
        raise ValueError(f"num_stiff_top must be an integer 0..num_blocks ({num_blocks}), got {num_stiff_top!r}")
    base_offsets = np.asarray(base_offsets, dtype=float).reshape(-1)
    if base_offsets.size == 0 or not np.all(np.isfinite(base_offsets) & (base_offsets >= 0)):
        raise ValueError("base_offsets must be one or more finite lengths >= 0 [m]")
    if not (np.isfinite(contour_spacing) and contour_spacing > 0):
        raise ValueError(f"contour_spacing must be a positive length [m], got {contour_spacing!r}")
    if inventory is not None and sum(inventory.values()) < 2 * num_blocks:
        raise ValueError(f"inventory holds {sum(inventory.values())} blocks; two fingers need {2 * num_blocks}")
    if time_budget is not None and not (np.isfinite(time_budget) and time_budget > 0):
        raise ValueError(f"time_budget must be a positive number of seconds or None, got {time_budget!r}")
    if not (np.isfinite(contact_tolerance_m) and 0.0 <= contact_tolerance_m < BLOCK_RADIUS):
        raise ValueError(f"contact_tolerance_m must be a length in [0, {BLOCK_RADIUS}) m, got {contact_tolerance_m!r}")
    table = load_table() if table is None else table
    contours = extract_contours(mask, pixel_size)
    space_for = lambda stock: design_space(  # noqa: E731
        table, num_blocks, stiff_positions=range(num_stiff_top), min_stiff_rod_diameter=min_stiff_rod_diameter,
        inventory=stock,
    )
    space = space_for(inventory)
    problems = finger_problems(contours, base_offsets, contour_spacing, contact_tolerance_m)

    started = time.perf_counter()
    progress = _PairProgress(callback)
    with ThreadPoolExecutor(max_workers=2) as pool:  # the two fingers are independent problems: both cores
        futures = {side: pool.submit(_optimize, problems[side][0], space, method, seed=seed,
                                     time_budget=time_budget, callback=progress.for_side(index), options=options)
                   for index, side in enumerate(("left", "right"))}
        results = {side: future.result() for side, future in futures.items()}
    shared_stock_ok = True
    if inventory is not None:
        used: dict[int, int] = {}
        for result in results.values():
            for design_id in result.design_ids:
                used[design_id] = used.get(design_id, 0) + 1
        if any(count > inventory.get(i, 0) for i, count in used.items()):
            shared_stock_ok = False
            left_over = dict(inventory)
            for design_id in results["left"].design_ids:
                left_over[design_id] -= 1
            budget = None if time_budget is None else max(time_budget - (time.perf_counter() - started), 1e-3)
            results["right"] = _optimize(problems["right"][0], space_for(left_over), method, seed=seed,
                                         time_budget=budget, callback=_scaled_callback(callback, 0.5, 0.5),
                                         options=options)

    fingers = {side: _finger(side, results[side], *problems[side], table) for side in results}
    success = all(r.success for r in results.values())
    optimal = all(r.optimal for r in results.values()) and shared_stock_ok
    message = "; ".join(f"{side}: {results[side].message}" for side in ("left", "right"))
    if not shared_stock_ok:
        message += "; right finger redesigned from the stock the left one leaves (pair not certified)"
    return FingerDesignResult(
        left=fingers["left"], right=fingers["right"], success=success, message=message, optimal=optimal,
        solve_time=time.perf_counter() - started,
    )


def prepare_finger_search(configurations=PREPARED_CONFIGURATIONS, table=None, progress=None) -> None:
    """Compile the finger search and build (or load) its lookahead fields for each (num_blocks,
    num_stiff_top), so that later requests start at once; both are kept on disk (numba's cache and
    ``planner.optimize.field_cache.cache_directory()``). ``progress(line)``, if given, hears of each step as it
    starts and ends (building takes tens of seconds per field the first time, loading a moment)."""
    report = progress or (lambda line: None)
    table = load_table() if table is None else table
    steps = len(configurations) + 1
    started = time.perf_counter()
    report(f"[1/{steps}] compiling the finger search kernels (numba; kept in its cache)")
    rows, columns = np.mgrid[:60, :40]
    ellipse = ((rows - 30) / 24.0) ** 2 + ((columns - 20) / 12.0) ** 2 < 1.0
    design_fingers(ellipse, 5e-4, 2, table=table)  # compiles every kernel on a small problem
    target = finger_problems(extract_contours(ellipse, 5e-4))["left"][0]
    for objects in (1, 2):  # the swap-front search of reconfiguration plans, for one and two objects, from a finger
        # as built (its evaluation compiles kernels of its own)
        solve_finger_front([target] * objects, [1.0] * objects, design_space(table, 2), current=np.zeros(2, np.int64))
    report(f"[1/{steps}] kernels ready in {time.perf_counter() - started:.1f} s")
    for step, (blocks, stiff) in enumerate(configurations, start=2):
        started = time.perf_counter()
        space = design_space(table, blocks, stiff_positions=range(stiff))
        counts = "/".join(str(len(choices)) for choices in space.choices)
        report(f"[{step}/{steps}] lookahead fields of {blocks} blocks, top {stiff} stiff "
               f"({counts} designs per position, base first): building or loading")
        lookahead_fields(block_shapes(space, CAP_LENGTH), space, BLOCK_RADIUS, FINGER_OPTIONS["field_spacing"],
                         FINGER_OPTIONS["region_spacing"])
        report(f"[{step}/{steps}] lookahead fields of {blocks} blocks, top {stiff} stiff ready in "
               f"{time.perf_counter() - started:.1f} s")


def _finger(side, result, target, contour, table) -> FingerDesign:
    theta, length, _ = design_parameters(table, np.array(result.design_ids))
    shape = chain_shape(theta, length, 0.0)
    base = target.bases[result.base]
    cost = evaluate(target, shape.points + base, shape.rotations[-1], shape.positions[-1] + base,
                    (theta, length, base[0]))
    return FingerDesign(
        side=side,
        design_ids=result.design_ids,
        cost=float(cost.total),
        collision=bool(cost.collision),
        min_clearance_m=float(target.body.clearance(theta, length, base[0])),
        optimal=result.optimal,
        lower_bound_m=result.lower_bound,
        contour=contour,
        centerline=target.body.to_object(shape.points + base),
        base=target.body.to_object(base),
        result=result,
    )


def design_path(
    path: np.ndarray,
    num_blocks: int,
    *,
    allow_rotation: bool = True,
    method: str = "exact",
    time_budget: float | None = None,
    seed: int = 0,
    table=None,
    callback=None,
    options: dict | None = None,
) -> PathDesignResult:
    """Design a chain of ``num_blocks`` whose centerline follows ``path`` (n, 3) [m], given in the chain base
    frame with the base first (eq. 1). ``allow_rotation`` False keeps the chain planar (all phi = 0)."""
    _check_common(num_blocks, method)
    path = np.asarray(path, dtype=float)
    if path.ndim != 2 or path.shape[1] != 3 or len(path) < 2:
        raise ValueError(f"path must be an (n, 3) array of at least 2 points [m], got shape {path.shape}")
    if not np.all(np.isfinite(path)):
        raise ValueError("path contains NaN or infinite coordinates")
    table = load_table() if table is None else table
    space = design_space(table, num_blocks, allow_rotation=allow_rotation)
    target = path_target(path)
    if method == "exact":
        options = PATH_EXACT_OPTIONS | (options or {})
    result = _optimize(target, space, method, seed=seed, time_budget=time_budget, callback=callback, options=options)
    theta, length, _ = design_parameters(table, np.array(result.design_ids))
    shape = chain_shape(theta, length, np.array(result.rotation_steps) * ROTATION_STEP)
    cost = evaluate(target, shape.points, shape.rotations[-1], shape.positions[-1])
    return PathDesignResult(
        design_ids=result.design_ids,
        rotation_steps=result.rotation_steps,
        cost=float(cost.total),
        success=result.success,
        message=result.message,
        optimal=result.optimal,
        lower_bound=result.lower_bound,
        solve_time=result.solve_time,
        centerline=shape.points,
        result=result,
    )
