"""Reconfiguration: the next gripper from the robot as built and the shelf, with the fewest block swaps.

Inputs: the robot as built (an ``Assembly``), the shelf (design ID -> blocks not in the robot) and a
target: a weighted set of objects, each with its own contour sampling, base offsets and collision rule.
Every finger chain of the robot (a ``FingerSlot``: which side it grasps, how many top blocks must be stiff)
is redesigned for the weighted sum of the objects' eq. (3) costs.

One *swap* is an operator action at one position: its block is replaced, or re-seated at another snap-fit;
a position whose block stays keeps it. The designs are planar with every block at snap-fit 0; the finger
as built, with blocks at step 6 (mirrored: they and the blocks after them bend the other way), is its own
0-swap candidate, evaluated as it is; other steps leave the plane: such blocks are re-seated or replaced.
``plan_reconfiguration`` returns, for every swap budget from 0 up to a full rebuild, the best gripper and a
proven lower bound: each finger's front over every block of the robot and the shelf comes from
``solve_finger_front`` (a relaxation that bounds the finger), and ``solve_gripper_front`` combines the
fingers exactly under the one shelf they share (the shelf plus every block a gripper removes; a removed
block goes back to the shelf). Complete, every point is certified and "no gripper" is proven; stopped, every
point carries its bound.
``swap_steps`` turns a chosen point into ordered operator steps that never draw a block the shelf does not
hold at that moment (when swaps form a cycle, one block is taken out first and its position filled last).
"""
from __future__ import annotations

import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from planner.assembly import SNAP_FITS, Assembly, Chain, PlacedBlock
from planner.contours import ObjectContours
from planner.design import (DEFAULT_BASE_OFFSETS, DEFAULT_CONTOUR_SPACING, DEFAULT_MIN_STIFF_ROD_DIAMETER,
                            finger_problems)
from planner.kinematics import BLOCK_RADIUS
from planner.objectives import COLLISION_PENALTY
from planner.optimize import design_costs, design_space, solve_finger
from planner.optimize.front_search import Candidate, FingerFrontSearch, FrontResult, solve_finger_front
from planner.optimize.gripper_search import FingerProblem, GripperFront, solve_gripper_front
from planner.optimize.result import Progress, RunControl, Status
from planner.table import load_table

SIDES = ("left", "right")
MAX_SHELF_BLOCKS = 10_000  # a shelf description larger than this is a mistake, not a shelf
WORKERS = 2  # fingers searched side by side (the machine's cores)
MIRROR_STEPS = SNAP_FITS // 2  # a block at this snap-fit bends to the other side, in the same plane


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


def check_shelf(shelf, table) -> dict[int, int]:
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
    """One slot's design space, what it keeps without a swap, its targets and its prepared search."""

    def __init__(self, slot: FingerSlot, chain: Chain, objects, pool: Counter, table, min_stiff_rod_diameter):
        self.slot, self.chain = slot, chain
        self.space = space = design_space(table, len(chain.blocks), stiff_positions=range(slot.num_stiff_top),
                                          min_stiff_rod_diameter=min_stiff_rod_diameter)
        self.shape_of = {d: s for s, members in enumerate(space.members) for d in members}
        self.stiff_ids = {d for members, stiff in zip(space.members, space.member_stiff)
                          for d, q in zip(members, stiff) if q}
        forced = space.stiff_positions
        block_stiff = np.array([b.design_id in self.stiff_ids for b in chain.blocks])
        upright = np.array([b.rotation_steps == 0 for b in chain.blocks])
        shapes = np.array([self.shape_of[b.design_id] for b in chain.blocks], np.int64)
        # a block stays only upright (the designs are planar, every block at snap-fit 0) and, at a forced-
        # stiff position, stiff; a stiff block at a free position may give way to a free one of its shape
        self.current = np.where(upright & (~forced | block_stiff), shapes, -1)
        self.keeps_stiff = forced | block_stiff
        has_free = np.array([not all(space.member_stiff[s]) for s in shapes])
        self.releasable = ~forced & block_stiff & (self.current >= 0) & has_free
        self.shared = self.limits(pool)  # every block of the robot may be freed: a relaxation, for bounds
        self.targets, self.offsets = [], []
        for item in objects:
            target = finger_problems(item.contours, item.base_offsets, item.contour_spacing,
                                     item.contact_tolerance_m)[slot.side][0]
            self.targets.append(target)
            self.offsets.append(-target.bases[:, 0])
        self.weights = np.array([item.weight for item in objects])
        self.search = FingerFrontSearch(self.targets, self.weights, space)
        self.extra = self._as_built(shapes, block_stiff)

    def limits(self, blocks: Counter) -> tuple[np.ndarray, np.ndarray]:
        """(stock, stiff stock) per shape of a collection of blocks."""
        stock, stiff = np.zeros(len(self.space.theta), np.int64), np.zeros(len(self.space.theta), np.int64)
        for design_id, count in blocks.items():
            stock[self.shape_of[design_id]] += count
            if design_id in self.stiff_ids:
                stiff[self.shape_of[design_id]] += count
        return stock, stiff

    def _as_built(self, shapes, block_stiff) -> tuple[Candidate, ...]:
        """The finger exactly as built when a block sits at another snap-fit than 0 (outside the planar design
        space): at step 6 a block bends to the other side, and so does every block after it; any other step
        turns the finger out of the plane of its object, which the planar finger model cannot grasp with."""
        rotations = np.array([b.rotation_steps for b in self.chain.blocks])
        if (not rotations.any() or np.any((rotations != 0) & (rotations != MIRROR_STEPS))
                or np.any(self.space.stiff_positions & ~block_stiff)):
            return ()
        side = np.cumprod(np.where(rotations == MIRROR_STEPS, -1.0, 1.0))
        mirrored = replace(self.space, theta=side * self.space.theta[shapes], length=self.space.length[shapes])
        order = np.arange(len(shapes))
        costs, bases = [], []
        for target in self.targets:
            count = len(target.bases)
            per_base = design_costs(target, mirrored, np.tile(order, (count, 1)), np.zeros((count, len(order)),
                                                                                           np.int64), np.arange(count))
            best = int(np.argmin(per_base))
            if per_base[best] >= COLLISION_PENALTY:
                return ()
            costs.append(float(per_base[best]))
            bases.append(best)
        costs = np.array(costs)
        return (Candidate(shapes, np.zeros(len(shapes), bool), costs, np.array(bases), float(self.weights @ costs),
                          as_built=True),)

    def problem(self, front: FrontResult) -> FingerProblem:
        return FingerProblem(self.search, self.current, self.keeps_stiff, self.releasable, self.extra, front)


def plan_reconfiguration(assembly: Assembly, shelf: dict[int, int], objects, *, slots=GRIPPER_SLOTS, table=None,
                         time_budget: float | None = None, callback=None,
                         min_stiff_rod_diameter: float = DEFAULT_MIN_STIFF_ROD_DIAMETER) -> ReconfigurationResult:
    """The Pareto set between the weighted objective of ``objects`` (``TargetObject``s) and the number of
    block swaps from ``assembly``, drawing on ``shelf``; ``slots`` say which chains are fingers.
    ``time_budget`` [s] is shared by the searches; ``callback(Progress)`` may raise StopIteration to cancel
    (every point then carries its proven bound)."""
    table = load_table() if table is None else table
    shelf = check_shelf(shelf, table)
    _check_slots(assembly, slots)
    _check_objects(objects)
    if time_budget is not None and not (np.isfinite(time_budget) and time_budget > 0):
        raise ValueError(f"time_budget must be a positive number of seconds or None, got {time_budget!r}")
    started = time.perf_counter()
    in_robot = Counter(b.design_id for slot in slots for b in assembly.chain(slot.chain).blocks)
    pool = Counter(shelf) + in_robot
    fingers = [_Finger(slot, assembly.chain(slot.chain), objects, pool, table, min_stiff_rod_diameter)
               for slot in slots]
    meter = _Meter(callback, 2 * len(fingers) + 1)  # progress: seeds and a front per finger, then the joint
    rounds = -(-len(fingers) // WORKERS)
    stage = None if time_budget is None else time_budget * rounds / (rounds + 1) / rounds  # per finger

    def relaxed(index: int, finger: _Finger) -> FrontResult:
        """One finger over every block of the robot and the shelf: its bounds and first fingers. Each
        object's own optimum (the compiled single-object search) starts it; when all are certified, their
        weighted sum bounds every finger."""
        begin = time.perf_counter()
        own = [solve_finger(target, finger.space, time_budget=None if stage is None else stage / 2 / len(objects),
                            callback=meter.part((index, 0), j / len(objects), 1.0 / len(objects)))
               for j, target in enumerate(finger.targets)]
        return solve_finger_front(
            finger.targets, finger.weights, finger.space, current=finger.current, stock=finger.shared[0],
            stiff_stock=finger.shared[1], callback=meter.part((index, 1)),
            time_budget=None if stage is None else max(stage - (time.perf_counter() - begin), 1e-3),
            starts=[r.shapes for r in own], floor=float(finger.weights @ [r.lower_bound for r in own]),
            search=finger.search, keeps_stiff=finger.keeps_stiff, releasable=finger.releasable, extra=finger.extra)

    with ThreadPoolExecutor(max_workers=WORKERS) as workers:  # the compiled searches release the GIL
        fronts = dict(zip([f.slot.chain for f in fingers], workers.map(relaxed, range(len(fingers)), fingers)))
    pool_stock, pool_stiff = fingers[0].limits(pool)
    budget = None if time_budget is None else max(time_budget - (time.perf_counter() - started), 1e-3)
    joint = solve_gripper_front([f.problem(fronts[f.slot.chain]) for f in fingers], pool_stock, pool_stiff,
                                RunControl(budget, meter.part("joint")))
    canceled = meter.canceled or any(f.status == Status.CANCELED for f in fronts.values())
    points = _points(assembly, shelf, fingers, joint)
    status = joint.status
    if canceled:
        status = Status.CANCELED
    elif status == Status.CERTIFIED and not np.isfinite(points[-1].objective):
        status = Status.INFEASIBLE
    success = np.isfinite(points[-1].objective)
    certified = sum(p.optimal for p in points)
    if success:
        message = (f"{certified} of {len(points)} swap budgets certified; best {points[-1].objective:.6g} m with "
                   f"{points[-1].swaps} swaps")
    elif status == Status.INFEASIBLE:
        message = "no gripper within the shelf and the robot's blocks (proven)"
    else:
        message = "no gripper found"
    if status in (Status.CANCELED, Status.TIME_BUDGET):
        message += f" ({status.name.lower().replace('_', ' ')}: uncertified points carry their bound)"
    return ReconfigurationResult(success=bool(success), status=status, message=message, points=points,
                                 fronts=fronts, solve_time=time.perf_counter() - started)


def cancel_now(progress):
    raise StopIteration


def share_progress(callback, start: float, count: int, width: float = 1.0):
    """Progress of one search as a fraction of a whole of ``count`` searches: it spans ``width`` of them
    from ``start``."""
    if callback is None:
        return None
    return lambda p: callback(Progress((start + width * p.fraction) / count, p.best_cost, p.nfev, p.elapsed))


class _Meter:
    """The progress of searches that run side by side, as one: each part reports its own fraction, the
    plan's is their sum over ``parts`` (never going back), one report at a time. Once the callback has
    canceled, every later report cancels too."""

    def __init__(self, callback, parts: int):
        self.callback, self.parts, self.done = callback, parts, {}
        self.lock, self.shown, self.canceled = threading.Lock(), 0.0, False

    def part(self, key, start: float = 0.0, width: float = 1.0):
        if self.callback is None:
            return None

        def report(progress):
            with self.lock:
                if self.canceled:
                    raise StopIteration
                self.done[key] = start + width * progress.fraction
                self.shown = max(self.shown, sum(self.done.values()) / self.parts)
                try:
                    self.callback(Progress(self.shown, progress.best_cost, progress.nfev, progress.elapsed))
                except StopIteration:
                    self.canceled = True
                    raise
        return report


def _points(assembly, shelf, fingers, joint: GripperFront) -> tuple[ParetoPoint, ...]:
    """One point per swap budget from the joint front: its gripper's design IDs and assembly."""
    points = []
    for budget, (cost, picked) in enumerate(zip(joint.fun, joint.chosen)):
        bound, optimal = float(joint.lower_bound[budget]), bool(joint.optimal[budget])
        if picked is None:
            points.append(ParetoPoint(budget, -1, np.inf, bound, optimal, (), None))
            continue
        plans = _assign(fingers, picked, shelf)
        points.append(ParetoPoint(budget, sum(c.swaps for c in picked), float(cost), bound, optimal, plans,
                                  _assembly_with(assembly, plans)))
    return tuple(points)


def _assign(fingers, picked, shelf) -> tuple[FingerPlan, ...]:
    """Design IDs for one gripper: kept positions keep their block; swapped ones draw on the shelf plus
    every removed block, stiff positions first, free positions free designs first."""
    available = Counter(shelf)
    for finger, candidate in zip(fingers, picked):
        for block, out in zip(finger.chain.blocks, candidate.swapped):
            available[block.design_id] += int(out)
    ids = {}
    for stiff_pass in (True, False):
        for finger, candidate in zip(fingers, picked):
            for k in np.flatnonzero(candidate.swapped):
                if bool(finger.space.stiff_positions[k]) != stiff_pass:
                    continue
                shape = candidate.shapes[k]
                members = [d for d, q in zip(finger.space.members[shape], finger.space.member_stiff[shape])
                           if available[d] > 0 and (q or not stiff_pass)]
                members.sort(key=lambda d: d in finger.stiff_ids)  # keep stiff designs for where they are needed
                available[members[0]] -= 1  # the search counted the blocks: one is there
                ids[finger.slot.chain, int(k)] = members[0]
    return tuple(FingerPlan(
        chain=finger.slot.chain,
        design_ids=tuple(ids.get((finger.slot.chain, k), b.design_id) for k, b in enumerate(finger.chain.blocks)),
        swapped=tuple(bool(x) for x in candidate.swapped), cost=candidate.cost,
        object_costs=tuple(float(c) for c in candidate.costs),
        base_offsets_m=tuple(float(o[b]) for o, b in zip(finger.offsets, candidate.bases)))
        for finger, candidate in zip(fingers, picked))


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
