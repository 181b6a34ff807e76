"""Reconfiguration: the next gripper from the robot as built and the shelf, with the fewest block swaps.

Inputs: the robot as built (an ``Assembly``), the shelf (design ID -> blocks not in the robot) and a
target: a weighted set of objects, each with its own contour sampling, base offsets and collision rule.
Every finger chain of the robot (a ``FingerSlot``: which side it grasps, how many top blocks must be stiff)
is redesigned for the weighted sum of the objects' eq. (3) costs.

One *swap* replaces the block at one position; a position whose shape does not change keeps its block.
``plan_reconfiguration`` returns, for every swap budget from 0 up to a full rebuild, the best gripper it
found and a proven lower bound: each finger's whole front comes from ``solve_finger_front`` (certified per
budget), the fronts are combined over the fingers by min-plus convolution, and a combination is only
taken when the blocks it needs are there (the shelf plus every block it removes; a removed block goes back
to the shelf). A point is certified when its gripper reaches the convolution of the fingers' bounds.
``swap_steps`` turns a chosen point into ordered operator steps that never draw a block the shelf does not
hold at that moment (when swaps form a cycle, one block is taken out first and its position filled last).
"""
from __future__ import annotations

import itertools
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from planner.assembly import Assembly, Chain, PlacedBlock
from planner.contours import ObjectContours
from planner.design import (DEFAULT_BASE_OFFSETS, DEFAULT_CONTOUR_SPACING, DEFAULT_MIN_STIFF_ROD_DIAMETER,
                            finger_problems)
from planner.kinematics import BLOCK_RADIUS
from planner.optimize import design_space, solve_finger
from planner.optimize.front_search import FrontResult, solve_finger_front
from planner.optimize.result import Progress, Status
from planner.table import load_table

SIDES = ("left", "right")
MAX_SHELF_BLOCKS = 10_000  # a shelf description larger than this is a mistake, not a shelf


@dataclass(frozen=True)
class FingerSlot:
    """A chain of the robot that is a finger: the contour side it grasps and its forced-stiff top blocks."""

    chain: str
    side: str  # "left" or "right"
    num_stiff_top: int = 0


GRIPPER_SLOTS = (FingerSlot("front_left", "left", 2), FingerSlot("front_right", "right", 2),
                 FingerSlot("back_left", "left", 3), FingerSlot("back_right", "right", 3))  # the paper's Figure 5


@dataclass(frozen=True)
class TargetObject:
    """One object of the target set, with the user's contour sampling and collision rule for it."""

    name: str
    contours: ObjectContours
    weight: float = 1.0
    base_offsets: np.ndarray = field(default_factory=lambda: DEFAULT_BASE_OFFSETS)
    contour_spacing: float = DEFAULT_CONTOUR_SPACING  # [m]
    contact_tolerance_m: float = 0.0


@dataclass(frozen=True)
class FingerPlan:
    chain: str
    design_ids: tuple[int, ...]
    swapped: tuple[bool, ...]  # per position: the block changes
    cost: float  # weighted objective of this finger [m]
    object_costs: tuple[float, ...]  # per object, eq. (3) [m]
    base_offsets_m: tuple[float, ...]  # per object, the chosen outward base offset [m]


@dataclass(frozen=True)
class ParetoPoint:
    """The best gripper found with at most ``max_swaps`` swaps (``swaps`` of them used)."""

    max_swaps: int
    swaps: int
    objective: float  # [m], inf when none was found within the shelf
    lower_bound: float  # proven [m]
    optimal: bool
    fingers: tuple[FingerPlan, ...]
    assembly: Assembly | None


@dataclass(frozen=True)
class SwapStep:
    """One operator action at one position; ``remove`` or ``insert`` is None when a cycle of swaps makes
    the operator take a block out first and fill the position later. ``layout`` is every chain's design IDs
    after the step (None: position empty), ``assembly`` the robot after it (None while a position is empty)."""

    chain: str
    position: int  # 0 = the block at the chain's base
    remove: int | None
    insert: int | None
    rotation_steps: int
    shelf: dict[int, int]  # after the step
    layout: dict[str, tuple[int | None, ...]]
    assembly: Assembly | None

    def describe(self) -> str:
        what = [f"remove design {self.remove}"] if self.remove is not None else []
        if self.insert is not None:
            what.append(f"insert design {self.insert} at rotation step {self.rotation_steps}")
        return f"finger {self.chain}, position {self.position}: " + ", ".join(what)


@dataclass(frozen=True)
class ReconfigurationResult:
    """scipy style: ``success`` (a gripper within the shelf exists for the largest budget), ``message``,
    ``status``, the points (index = swap budget), each finger's front and the time taken [s]."""

    success: bool
    status: Status
    message: str
    points: tuple[ParetoPoint, ...]
    fronts: dict[str, FrontResult]
    solve_time: float

    @property
    def pareto(self) -> tuple[ParetoPoint, ...]:
        """The non-dominated points: each needs more swaps than the one before and is strictly better."""
        kept, best = [], np.inf
        for point in self.points:
            if point.objective < best:
                kept.append(point)
                best = point.objective
        return tuple(kept)


def _check_shelf(shelf, table) -> dict[int, int]:
    if not isinstance(shelf, dict):
        raise ValueError("shelf must map design IDs to block counts")
    known = set(int(i) for i in table.ids)
    clean = {}
    for key, count in shelf.items():
        if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or int(key) not in known:
            raise ValueError(f"shelf: {key!r} is not a design ID of the table")
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
            raise ValueError(f"shelf: design {key} has count {count!r}; counts are integers >= 0")
        clean[int(key)] = int(count)
    if sum(clean.values()) > MAX_SHELF_BLOCKS:
        raise ValueError(f"shelf holds {sum(clean.values())} blocks, more than {MAX_SHELF_BLOCKS}")
    return clean


def _check_slots(assembly: Assembly, slots) -> None:
    if not slots:
        raise ValueError("slots: at least one finger chain is needed")
    names = [slot.chain for slot in slots]
    if len(set(names)) != len(names):
        raise ValueError(f"slots name a chain twice: {names}")
    for slot in slots:
        if slot.side not in SIDES:
            raise ValueError(f"slot {slot.chain!r}: side must be one of {SIDES}, got {slot.side!r}")
        try:
            chain = assembly.chain(slot.chain)
        except KeyError as missing:
            raise ValueError(str(missing.args[0])) from None
        if not 0 <= slot.num_stiff_top <= len(chain.blocks):
            raise ValueError(f"slot {slot.chain!r}: num_stiff_top must be 0..{len(chain.blocks)}")


def _check_objects(objects) -> None:
    if not objects:
        raise ValueError("objects: the target needs at least one object")
    for item in objects:
        if not (np.isfinite(item.weight) and item.weight > 0):
            raise ValueError(f"object {item.name!r}: weight must be > 0, got {item.weight!r}")
        if not (np.isfinite(item.contact_tolerance_m) and 0.0 <= item.contact_tolerance_m < BLOCK_RADIUS):
            raise ValueError(f"object {item.name!r}: contact_tolerance_m must be in [0, {BLOCK_RADIUS}) m")
        if not (np.isfinite(item.contour_spacing) and item.contour_spacing > 0):
            raise ValueError(f"object {item.name!r}: contour_spacing must be a positive length [m]")
        offsets = np.asarray(item.base_offsets, dtype=float).reshape(-1)
        if offsets.size == 0 or not np.all(np.isfinite(offsets) & (offsets >= 0)):
            raise ValueError(f"object {item.name!r}: base_offsets must be one or more lengths >= 0 [m]")


class _Finger:
    """One slot's design space, current shapes, stock limits and targets."""

    def __init__(self, slot: FingerSlot, chain: Chain, objects, pool: Counter, shelf: Counter, table,
                 min_stiff_rod_diameter):
        self.slot, self.chain = slot, chain
        self.space = design_space(table, len(chain.blocks), stiff_positions=range(slot.num_stiff_top),
                                  min_stiff_rod_diameter=min_stiff_rod_diameter)
        self.shape_of = {d: s for s, members in enumerate(self.space.members) for d in members}
        self.stiff_ids = {d for members, stiff in zip(self.space.members, self.space.member_stiff)
                          for d, q in zip(members, stiff) if q}
        self.current = np.array([
            self.shape_of[b.design_id] if (not self.space.stiff_positions[k] or b.design_id in self.stiff_ids) else -1
            for k, b in enumerate(chain.blocks)], np.int64)  # a soft block at a stiff position must go
        self.shared = self.limits(pool)  # every block of the robot may be freed: a relaxation, for bounds
        self.own = self.limits(shelf + Counter(b.design_id for b in chain.blocks))  # what it can surely use
        self.targets, self.offsets = [], []
        for item in objects:
            target = finger_problems(item.contours, item.base_offsets, item.contour_spacing,
                                     item.contact_tolerance_m)[slot.side][0]
            self.targets.append(target)
            self.offsets.append(-target.bases[:, 0])
        self.weights = np.array([item.weight for item in objects])

    def limits(self, blocks: Counter) -> tuple[np.ndarray, np.ndarray]:
        """(stock, stiff stock) per shape of a collection of blocks."""
        stock, stiff = np.zeros(len(self.space.theta), np.int64), np.zeros(len(self.space.theta), np.int64)
        for design_id, count in blocks.items():
            stock[self.shape_of[design_id]] += count
            if design_id in self.stiff_ids:
                stiff[self.shape_of[design_id]] += count
        return stock, stiff


def plan_reconfiguration(assembly: Assembly, shelf: dict[int, int], objects, *, slots=GRIPPER_SLOTS, table=None,
                         time_budget: float | None = None, callback=None,
                         min_stiff_rod_diameter: float = DEFAULT_MIN_STIFF_ROD_DIAMETER) -> ReconfigurationResult:
    """The Pareto set between the weighted objective of ``objects`` (``TargetObject``s) and the number of
    block swaps from ``assembly``, drawing on ``shelf``; ``slots`` say which chains are fingers.
    ``time_budget`` [s] is shared by the fingers; ``callback(Progress)`` may raise StopIteration to cancel
    (every point then carries its proven bound)."""
    table = load_table() if table is None else table
    shelf = _check_shelf(shelf, table)
    _check_slots(assembly, slots)
    _check_objects(objects)
    if time_budget is not None and not (np.isfinite(time_budget) and time_budget > 0):
        raise ValueError(f"time_budget must be a positive number of seconds or None, got {time_budget!r}")
    started = time.perf_counter()
    in_robot = Counter(b.design_id for slot in slots for b in assembly.chain(slot.chain).blocks)
    pool = Counter(shelf) + in_robot
    fingers = [_Finger(slot, assembly.chain(slot.chain), objects, pool, Counter(shelf), table, min_stiff_rod_diameter)
               for slot in slots]
    fronts, candidates, seeds, floors, canceled = {}, {f.slot.chain: [] for f in fingers}, {}, {}, False

    def search(finger, limits, index, count):
        nonlocal canceled
        budget = None
        if time_budget is not None:
            budget = max((time_budget - (time.perf_counter() - started)) / (count - index), 1e-3)
        earlier, front_start = candidates[finger.slot.chain], 0.0
        if not earlier:  # each object's own optimum (the compiled single-object search) to start from; when
            own = []     # all are certified, their weighted sum bounds every finger
            for j, target in enumerate(finger.targets):  # the first half of this search's share of the progress
                own.append(solve_finger(target, finger.space, time_budget=budget, callback=_cancel if canceled else
                                        _share(callback, index + 0.5 * j / len(finger.targets), count,
                                               0.5 / len(finger.targets))))
                canceled |= own[-1].status == Status.CANCELED
            seeds[finger.slot.chain] = [r.shapes for r in own]
            floors[finger.slot.chain] = float(finger.weights @ [r.lower_bound for r in own])
            front_start = 0.5
        front = solve_finger_front(finger.targets, finger.weights, finger.space, current=finger.current,
                                   stock=limits[0], stiff_stock=limits[1], time_budget=budget,
                                   callback=_cancel if canceled else
                                   _share(callback, index + front_start, count, 1.0 - front_start),
                                   starts=seeds[finger.slot.chain] + [s for f in earlier for s in f.shapes
                                                                      if s[0] >= 0],
                                   floor=floors[finger.slot.chain])
        canceled |= front.status == Status.CANCELED
        candidates[finger.slot.chain].append(front)
        return front

    for index, finger in enumerate(fingers):  # over every block of the robot: the bounds
        fronts[finger.slot.chain] = search(finger, finger.shared, index, 2 * len(fingers))
    points = _combine(assembly, shelf, fingers, fronts, candidates)
    if not all(p.optimal for p in points):  # fingers may want the same blocks: candidates that surely combine
        for index, finger in enumerate(fingers):
            if any(not np.array_equal(a, b) for a, b in zip(finger.own, finger.shared)):
                search(finger, finger.own, len(fingers) + index, 2 * len(fingers))
        points = _combine(assembly, shelf, fingers, fronts, candidates)
    statuses = {front.status for front in fronts.values()}
    status = (Status.CANCELED if Status.CANCELED in statuses else Status.TIME_BUDGET if Status.TIME_BUDGET in statuses
              else Status.CERTIFIED if all(p.optimal for p in points if np.isfinite(p.objective)) else Status.FINISHED)
    success = np.isfinite(points[-1].objective)
    certified = sum(p.optimal for p in points)
    message = (f"{certified} of {len(points)} swap budgets certified; best {points[-1].objective:.6g} m with "
               f"{points[-1].swaps} swaps" if success else "no gripper within the shelf and the robot's blocks")
    if status in (Status.CANCELED, Status.TIME_BUDGET):
        message += f" ({status.name.lower().replace('_', ' ')}: uncertified points carry their bound)"
    return ReconfigurationResult(success=bool(success), status=status, message=message, points=points,
                                 fronts=fronts, solve_time=time.perf_counter() - started)


def _cancel(progress):
    raise StopIteration


def _share(callback, start: float, count: int, width: float = 1.0):
    """Progress of one search as a fraction of the whole plan of ``count`` searches: it spans ``width`` of
    them from ``start``."""
    if callback is None:
        return None
    return lambda p: callback(Progress((start + width * p.fraction) / count, p.best_cost, p.nfev, p.elapsed))


def _combine(assembly, shelf, fingers, fronts, candidates) -> tuple[ParetoPoint, ...]:
    """Per swap budget, the cheapest combination of the fingers' candidate fingers whose blocks are there,
    and the min-plus convolution of the fingers' bounds (``fronts``: proven bounds on every combination).
    The candidates of a finger come from its front over every block of the robot and from its front over
    the shelf and its own blocks only (those combine unless two fingers want the same shelf block)."""
    sizes = [len(f.chain.blocks) for f in fingers]
    total = sum(sizes)
    bound = np.zeros(1)
    for finger in fingers:
        low = fronts[finger.slot.chain].lower_bound
        bound = np.array([min(bound[a] + low[s - a] for a in range(len(bound)) if 0 <= s - a < len(low))
                          for s in range(len(bound) + len(low) - 1)])
    options = []
    for finger in fingers:
        seen, entries = set(), []
        for front in candidates[finger.slot.chain]:
            for s in range(len(front.fun)):
                key = tuple(front.shapes[s])
                if np.isfinite(front.fun[s]) and key not in seen:
                    seen.add(key)
                    entries.append((front, s))
        options.append(entries)
    best: list[tuple | None] = [None] * (total + 1)
    for combo in itertools.product(*options):
        swaps = sum(int(front.swaps[s]) for front, s in combo)
        cost = sum(float(front.fun[s]) for front, s in combo)
        if best[swaps] is not None and best[swaps][0] <= cost:
            continue
        plans = _assign(fingers, combo, shelf)
        if plans is not None:
            best[swaps] = (cost, plans)
    points, carried = [], None
    for budget in range(total + 1):
        if best[budget] is not None and (carried is None or best[budget][0] < carried[0]):
            carried = best[budget] + (budget,)
        if carried is None:
            points.append(ParetoPoint(budget, -1, np.inf, float(bound[budget]), bool(np.isinf(bound[budget])), (),
                                      None))
            continue
        cost, plans, swaps = carried
        certified = cost <= bound[budget] + 1e-9  # the bounds are proven whether a search ended or not
        points.append(ParetoPoint(budget, swaps, cost, float(min(bound[budget], cost)), bool(certified), plans,
                                  _assembly_with(assembly, plans)))
    return tuple(points)


def _assign(fingers, combo, shelf) -> tuple[FingerPlan, ...] | None:
    """Design IDs for one combination: kept positions keep their block; swapped ones draw on the shelf plus
    every removed block, stiff positions first; None when the blocks are not there."""
    available = Counter(shelf)
    chosen = []
    for finger, (front, s) in zip(fingers, combo):
        shapes = front.shapes[s]
        swapped = shapes != finger.current
        chosen.append((finger, front, s, shapes, swapped))
        for block, out in zip(finger.chain.blocks, swapped):
            available[block.design_id] += int(out)
    ids = {}
    for stiff_pass in (True, False):
        for finger, _, _, shapes, swapped in chosen:
            for k in np.flatnonzero(swapped):
                if bool(finger.space.stiff_positions[k]) != stiff_pass:
                    continue
                members = [d for d, q in zip(finger.space.members[shapes[k]], finger.space.member_stiff[shapes[k]])
                           if available[d] > 0 and (q or not stiff_pass)]
                if not stiff_pass:  # keep stiff designs for where they are needed: soft ones first
                    members.sort(key=lambda d: d in finger.stiff_ids)
                if not members:
                    return None
                available[members[0]] -= 1
                ids[finger.slot.chain, int(k)] = members[0]
    plans = []
    for finger, front, s, shapes, swapped in chosen:
        design_ids = tuple(ids.get((finger.slot.chain, k), b.design_id) for k, b in enumerate(finger.chain.blocks))
        plans.append(FingerPlan(
            chain=finger.slot.chain, design_ids=design_ids, swapped=tuple(bool(x) for x in swapped),
            cost=float(front.fun[s]), object_costs=tuple(float(c) for c in front.object_costs[s]),
            base_offsets_m=tuple(float(o[b]) for o, b in zip(finger.offsets, front.bases[s]))))
    return tuple(plans)


def _assembly_with(assembly: Assembly, plans) -> Assembly:
    chains = []
    for plan in plans:
        chain = assembly.chain(plan.chain)
        blocks = tuple(block if not out else PlacedBlock(design_id, 0)
                       for block, design_id, out in zip(chain.blocks, plan.design_ids, plan.swapped))
        chains.append(Chain(chain.name, chain.hv_channel, blocks, chain.base_position, chain.base_orientation))
    return assembly.with_chains(*chains)


def swap_steps(current: Assembly, target: Assembly, shelf: dict[int, int]) -> tuple[SwapStep, ...]:
    """Ordered operator steps from ``current`` to ``target`` (same chains and lengths): each position whose
    block differs is swapped; a step only inserts a design the shelf holds at that moment (removed blocks go
    back to it). ValueError when the shelf and the removed blocks cannot supply the target."""
    shelf_now = Counter({int(k): int(v) for k, v in shelf.items()})
    layout = {c.name: [b.design_id for b in c.blocks] for c in current.chains}
    blocks = {c.name: list(c.blocks) for c in current.chains}
    pending = []
    for chain in target.chains:
        old = current.chain(chain.name)
        if len(old.blocks) != len(chain.blocks):
            raise ValueError(f"chain {chain.name!r}: target has {len(chain.blocks)} blocks, the robot "
                             f"{len(old.blocks)}")
        pending += [(chain.name, k, a.design_id, b) for k, (a, b) in enumerate(zip(old.blocks, chain.blocks))
                    if a.design_id != b.design_id or a.rotation_steps != b.rotation_steps]
    need = Counter(p[3].design_id for p in pending)
    supply = shelf_now + Counter(p[2] for p in pending)
    short = {d: n - supply[d] for d, n in need.items() if n > supply[d]}
    if short:
        raise ValueError(f"the shelf and the removed blocks lack designs {dict(sorted(short.items()))}")
    steps = []

    def record(name, position, remove, insert, rotation):
        assembled = all(v is not None for ids in layout.values() for v in ids)
        steps.append(SwapStep(
            chain=name, position=position, remove=remove, insert=insert, rotation_steps=rotation,
            shelf={d: n for d, n in sorted(shelf_now.items()) if n > 0},
            layout={k: tuple(v) for k, v in layout.items()},
            assembly=current.with_chains(*[Chain(c.name, c.hv_channel, tuple(blocks[c.name]), c.base_position,
                                                 c.base_orientation) for c in current.chains]) if assembled else None))

    while pending:
        ready = next((p for p in pending if shelf_now[p[3].design_id] + (p[2] == p[3].design_id) > 0), None)
        if ready is None:  # a cycle: take one block out now, fill its position when its design is back
            name, position, old, new = pending.pop(0)
            if old is not None:
                shelf_now[old] += 1
                layout[name][position] = None
                record(name, position, old, None, 0)
            pending.append((name, position, None, new))
            continue
        pending.remove(ready)
        name, position, old, new = ready
        if old is not None:
            shelf_now[old] += 1
        shelf_now[new.design_id] -= 1
        layout[name][position] = new.design_id
        blocks[name][position] = new
        record(name, position, old, new.design_id, new.rotation_steps)
    return tuple(steps)
