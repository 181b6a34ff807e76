"""Several fingers that share one stock of blocks: the exact trade-off between block swaps and their summed
objective.

Each finger alone has its swap front (``front_search``); searched over the whole stock, each front bounds
that finger in any gripper (a relaxation), and their min-plus convolution bounds the gripper. When the
fingers' own best fingers do not fit the stock together (they want the same blocks), the fingers are
combined by a nested branch and bound: finger 1's depth-first search, each of its complete fingers followed
by finger 2's search on the blocks finger 1 leaves, and so on. With ``inc[s]`` the best gripper found with
at most ``s`` swaps and ``rest[j]`` the convolved bounds of the fingers after finger j, a prefix of finger j
(bound ``b``, ``u`` swaps, after fingers costing ``c`` with ``w`` swaps) can only improve budget ``s`` if
``c + b + rest[j][s - w - u] < inc[s]``; its limit is the largest such margin over ``s``, refreshed
whenever a gripper improves. The last finger's exact front for a leftover stock is kept and reused for
every earlier choice that leaves a stock differing from it only in blocks that search never wanted below its
limit (``_KeptFronts``). The fingers are nested in the order of their relaxed searches' sizes, largest
first, so the finger searched again per leftover stock is the cheapest. Each finger's search runs on two
threads. Searches start from the relaxed fronts' fingers (the usual answer when the stock is ample).

Complete: every budget's gripper is the optimum, and a budget without one has none. Stopped (time budget,
callback): a budget's proven bound is the smallest over the prefixes not yet visited (plus the bounds of
the fingers after them) and the convolution, whichever is higher.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.optimize.front_search import Candidate, FingerFrontSearch, Front, FrontResult, Run, within
from planner.optimize.result import RunControl, Status, Stop

WORKERS = 2  # threads of each finger's search (the machine's cores)


@dataclass(frozen=True)
class FingerProblem:
    """One finger of the gripper: its prepared search, what it keeps without swaps (see ``Run``), the
    fingers outside the design space it may also keep (as built, rotations included) and its relaxed front
    (over the whole stock)."""

    search: FingerFrontSearch
    current: np.ndarray
    keeps_stiff: np.ndarray
    releasable: np.ndarray
    extra: tuple[Candidate, ...]
    relaxed: FrontResult

    @property
    def blocks(self) -> int:
        return len(self.current)

    def usage(self, candidate: Candidate) -> tuple[np.ndarray, np.ndarray]:
        """Blocks per shape the candidate takes from the stock, and how many of them must be stiff."""
        size = len(self.search.space.theta)
        stiff = self.search.space.stiff_positions | (~candidate.swapped & self.keeps_stiff)
        return (np.bincount(candidate.shapes, minlength=size), np.bincount(candidate.shapes[stiff], minlength=size))

    def fits(self, candidate: Candidate, stock, stiff_stock) -> bool:
        stiff = self.search.space.stiff_positions | (~candidate.swapped & self.keeps_stiff)
        return within(candidate.shapes, stiff, stock, stiff_stock)

    def seeds(self) -> list[Candidate]:
        """The relaxed front's fingers and the extra ones, each once."""
        seen, out = set(), []
        for candidate in [c for c in self.relaxed.candidates if c is not None] + list(self.extra):
            key = (candidate.shapes.tobytes(), candidate.swapped.tobytes(), candidate.as_built)
            if key not in seen:
                seen.add(key)
                out.append(candidate)
        return out


@dataclass
class GripperFront:
    """Per total swap budget s: the best gripper's cost ``fun[s]`` [m] (inf: none), its fingers
    (``chosen[s]``, one ``Candidate`` per finger), the proven ``lower_bound[s]`` and ``optimal[s]``;
    ``status``: CERTIFIED when the search completed, else why it stopped."""

    fun: np.ndarray
    lower_bound: np.ndarray
    optimal: np.ndarray
    chosen: list
    status: Status
    bound: np.ndarray  # the relaxed fronts' convolution


def convolve(a, b) -> np.ndarray:
    """Min-plus convolution: out[s] = min over i + k = s of a[i] + b[k]."""
    out = np.full(len(a) + len(b) - 1, np.inf)
    for i, value in enumerate(a):
        out[i:i + len(b)] = np.minimum(out[i:i + len(b)], value + np.asarray(b))
    return out


def solve_gripper_front(fingers: list[FingerProblem], stock, stiff_stock, control: RunControl,
                        fraction=lambda done: done) -> GripperFront:
    """The exact front of the fingers sharing ``stock`` / ``stiff_stock`` (blocks per shape, the same
    shape indices in every finger's space); ``control`` may stop it (see the module doc). The nested search
    takes the fingers whose relaxed searches placed the most blocks first: the last finger is searched again
    for every leftover stock, so the cheapest goes there."""
    order = sorted(range(len(fingers)), key=lambda j: -fingers[j].relaxed.nfev)
    front = _solve_in_order([fingers[j] for j in order], stock, stiff_stock, control, fraction)
    back = np.argsort(order)
    front.chosen = [None if picked is None else tuple(picked[k] for k in back) for picked in front.chosen]
    return front


class _KeptFronts:
    """The last finger's exact fronts, each with the stock it was searched under and what that search needed
    of it (``Run.stock_needed``). A kept front is the front of another leftover stock too when that stock
    holds no more of any shape than the search needed, the front's fingers fit it, and its ceiling is no
    higher: every finger of that stock below the ceiling was then either met by the search, or cut by a
    bound at or above a kept finger that fits it. Leftover stocks that differ only in shapes the last finger
    never wanted below its limit share one search."""

    def __init__(self):
        self.fronts, self.needed, self.needed_stiff, self.ceilings = [], [], [], []

    def find(self, finger: FingerProblem, left, left_stiff, ceiling) -> Front | None:
        if not self.fronts:
            return None
        usable = (np.all(np.asarray(self.needed) >= left, axis=1) & np.all(np.asarray(self.needed_stiff) >= left_stiff,
                                                                           axis=1)
                  & np.all(np.asarray(self.ceilings) >= ceiling, axis=1))
        for k in np.flatnonzero(usable):
            front = self.fronts[k]
            if all(c is None or finger.fits(c, left, left_stiff) for c in front.chosen):
                return front
        return None

    def add(self, front: Front, needed, needed_stiff) -> None:
        self.fronts.append(front)
        self.needed.append(needed)
        self.needed_stiff.append(needed_stiff)
        self.ceilings.append(front.ceiling)


def _solve_in_order(fingers: list[FingerProblem], stock, stiff_stock, control: RunControl,
                    fraction) -> GripperFront:
    total = sum(f.blocks for f in fingers)
    rest = [np.zeros(1)]
    for finger in reversed(fingers):
        rest.insert(0, convolve(finger.relaxed.lower_bound, rest[0]))
    inc, chosen = np.full(total + 1, np.inf), [None] * (total + 1)
    active, kept, done = [], _KeptFronts(), [0.0]

    def top(share: float) -> float:  # the first finger's search tells how far the whole search is
        done[0] = share
        return fraction(share)

    def inner(_share: float) -> float:
        return fraction(done[0])
    stock, stiff_stock = np.asarray(stock, np.int64), np.asarray(stiff_stock, np.int64)

    def margin(j, cost, swaps) -> np.ndarray:
        """Per swap count u of finger j's prefixes: the largest cost finger j may have and still improve some
        budget s, given the cost and swaps of the fingers before it, its own bound for u' >= u swaps and the
        bounds of the fingers after it (-inf: no budget left to improve)."""
        floor, after = fingers[j].relaxed.lower_bound, rest[j + 1]
        best_at = np.full(len(floor), -np.inf)
        for u in range(len(floor)):
            budgets = np.arange(swaps + u, total + 1)
            later = after[np.minimum(budgets - swaps - u, len(after) - 1)]
            reachable = np.isfinite(later) & (cost + floor[u] + later < inc[budgets])
            if reachable.any():
                best_at[u] = np.max(inc[budgets][reachable] - cost - later[reachable])
        # contiguous, as every other limit: a reversed view would compile the search kernels a second time
        return np.ascontiguousarray(np.maximum.accumulate(best_at[::-1])[::-1])

    def offer(picked) -> None:
        cost, swaps = sum(c.cost for c in picked), sum(c.swaps for c in picked)
        if cost >= inc[swaps]:
            return
        for s in range(swaps, total + 1):
            if cost < inc[s]:
                inc[s], chosen[s] = cost, tuple(picked)
        for entry in active:
            entry["refresh"]()

    def finish(j, cost, swaps, used, used_stiff, picked) -> None:
        """The last finger: its exact front on the stock left (kept, see ``_KeptFronts``), every point
        offered."""
        finger = fingers[j]
        left = np.minimum(stock - used, finger.blocks)  # a finger never takes more blocks of one shape
        left_stiff = np.minimum(stiff_stock - used_stiff, finger.blocks)
        ceiling = inc[np.minimum(swaps + np.arange(finger.blocks + 1), total)] - cost
        front = kept.find(finger, left, left_stiff, ceiling)
        if front is None:
            front = Front(finger.blocks, ceiling, finger.relaxed.lower_bound)

            def on_leaf(candidate):
                front.record(candidate)
                offer(picked + [candidate])

            relaxed = finger.relaxed
            for candidate in finger.seeds():
                if finger.fits(candidate, left, left_stiff):
                    on_leaf(candidate)
            if all(relaxed.optimal[v] and (relaxed.candidates[v] is None
                                           or finger.fits(relaxed.candidates[v], left, left_stiff))
                   for v in range(finger.blocks + 1)):  # the relaxed front fits: it is this stock's front
                front.ceiling[:] = np.inf
                needed = np.full((2, len(left)), finger.blocks)
            else:
                def refresh():
                    front.tighten(inc[np.minimum(swaps + np.arange(finger.blocks + 1), total)] - cost)

                run = Run(finger.current, finger.keeps_stiff, finger.releasable, left, left_stiff, front.limit,
                          on_leaf)
                entry = {"j": j, "cost": cost, "swaps": swaps, "run": run, "refresh": refresh}
                active.append(entry)
                finger.search.run(run, control, top if j == 0 else inner, workers=WORKERS)
                active.remove(entry)
                needed = run.stock_needed()
            kept.add(front, *needed)
        for candidate in front.chosen:  # a kept front: its points for this choice of the earlier fingers
            if candidate is not None:
                offer(picked + [candidate])

    def descend(j, cost, swaps, used, used_stiff, picked) -> None:
        if j == len(fingers) - 1:
            finish(j, cost, swaps, used, used_stiff, picked)
            return
        finger = fingers[j]
        left, left_stiff = stock - used, stiff_stock - used_stiff
        limit = margin(j, cost, swaps)

        def on_leaf(candidate):
            if candidate.cost >= limit[candidate.swaps]:
                return
            more, more_stiff = finger.usage(candidate)
            descend(j + 1, cost + candidate.cost, swaps + candidate.swaps, used + more, used_stiff + more_stiff,
                    picked + [candidate])

        def refresh():
            limit[:] = margin(j, cost, swaps)

        run = Run(finger.current, finger.keeps_stiff, finger.releasable, left, left_stiff, limit, on_leaf)
        entry = {"j": j, "cost": cost, "swaps": swaps, "run": run, "refresh": refresh}
        active.append(entry)
        for candidate in finger.seeds():  # the likely answers first: good grippers to prune with
            if finger.fits(candidate, left, left_stiff):
                on_leaf(candidate)
        finger.search.run(run, control, top if j == 0 else inner, workers=WORKERS)
        active.remove(entry)

    status, begun = Status.CERTIFIED, False
    bound = rest[0][:total + 1]
    try:
        control.report(fraction(0.0), inc[-1], 0)
        begun = True
        descend(0, 0.0, 0, np.zeros_like(stock), np.zeros_like(stock), [])
    except Stop as stop:
        status = stop.status
    if status == Status.CERTIFIED:
        lower = inc.copy()
    elif not begun:  # stopped before anything was searched: the relaxed fronts' bounds
        lower = bound.copy()
    else:
        lower = inc.copy()
        for entry in active:
            j, cost, swaps, run = entry["j"], entry["cost"], entry["swaps"], entry["run"]
            pending = [(0.0, 0)] if run.frames is None else run.frontier()
            after = rest[j + 1] if run.frames is not None else rest[j]
            for prefix_bound, u in pending:
                budgets = np.arange(swaps + u, total + 1)
                later = after[np.minimum(budgets - swaps - u, len(after) - 1)]
                lower[budgets] = np.minimum(lower[budgets], cost + prefix_bound + later)
        lower = np.maximum(lower, bound)
    lower = np.maximum.accumulate(lower[::-1])[::-1]  # fewer swaps never do better
    lower = np.minimum(lower, inc)
    optimal = (inc <= lower + 1e-9) | (np.isinf(inc) & np.isinf(lower))
    return GripperFront(fun=inc, lower_bound=np.where(optimal, inc, lower), optimal=optimal, chosen=chosen,
                        status=status, bound=bound)
