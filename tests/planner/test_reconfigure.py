"""Multi-object finger design and reconfiguration plans: the certified swap fronts against brute force (sample
and generated objects), the shelf never over-drawn (hypothesis), steps that rebuild the planned robot, and a
robot that already fits."""
import itertools
from collections import Counter

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planner import design
from planner.assembly import Assembly, Chain, PlacedBlock
from planner.contours import extract_contours, load_catalog_object
from planner.generated_objects import PIXEL_SIZE, lumpy_object
from planner.objectives import COLLISION_PENALTY
from planner.optimize import Status, design_costs, design_space
from planner.optimize.front_search import FingerFrontSearch, Front, Run, _node_bounds, solve_finger_front
from planner.optimize.result import RunControl
from planner.reconfigure import FingerSlot, TargetObject, plan_reconfiguration, swap_steps
from planner.table import load_table
from reconfigure_brute import generated_contours, plan_brute_force

pytestmark = pytest.mark.fast

TABLE = load_table()
OFFSETS = np.arange(0.0, 6.5e-3, 2e-3)
SHELF_IDS = (2, 8, 14, 19, 27, 33, 40, 45, 57, 61, 64, 71, 78)  # 57 stiff
SLOTS = (FingerSlot("left", "left"), FingerSlot("right", "right"))


def contours_of(name, seed=None):
    return load_catalog_object(name) if seed is None else extract_contours(lumpy_object(seed), PIXEL_SIZE)


def robot(left_ids, right_ids) -> Assembly:
    return Assembly("pair", tuple(Chain(name, "main", tuple(PlacedBlock(i) for i in ids))
                                  for name, ids in (("left", left_ids), ("right", right_ids))))


def weighted_costs(targets, weights, space, combos):
    """Weighted objective of every finger (rows of shape indices), each object at its best base."""
    total = np.zeros(len(combos))
    for weight, target in zip(weights, targets):
        bases = len(target.bases)
        shapes = np.repeat(combos, bases, axis=0)
        costs = design_costs(target, space, shapes, np.zeros_like(shapes), np.tile(np.arange(bases), len(combos)))
        total += weight * costs.reshape(len(combos), bases).min(axis=1)
    return total


def shape_stock(space, shelf):
    shape_of = {d: s for s, members in enumerate(space.members) for d in members}
    stock = np.zeros(len(space.theta), np.int64)
    for design_id, count in shelf.items():
        stock[shape_of[design_id]] += count
    return shape_of, stock


@pytest.mark.parametrize("blocks", [2, 3])
@pytest.mark.parametrize("objects", [[("strawberry", None), ("generated", 4)], [("gingerbread", None)],
                                     [("generated", 9), ("generated", 2)]])
def test_swap_front_equals_brute_force(objects, blocks):
    targets = [design.finger_problems(contours_of(*o), base_offsets=OFFSETS)["right"][0] for o in objects]
    weights = np.linspace(1.0, 0.5, len(targets))
    space = design_space(TABLE, blocks)
    shape_of, stock = shape_stock(space, {i: 2 for i in SHELF_IDS})
    current = np.array([shape_of[i] for i in (78, 27, 64)[:blocks]])
    front = solve_finger_front(targets, weights, space, current=current, stock=stock)
    assert front.status == Status.CERTIFIED and front.optimal.all()
    usable = np.flatnonzero(stock > 0)
    combos = np.array([c for c in itertools.product(usable, repeat=blocks)
                       if np.all(np.bincount(c, minlength=len(stock)) <= stock)])
    costs = weighted_costs(targets, weights, space, combos)
    costs[costs >= COLLISION_PENALTY] = np.inf
    swaps = (combos != current).sum(axis=1)
    for budget in range(blocks + 1):
        expected = costs[swaps <= budget].min()
        assert front.fun[budget] == pytest.approx(expected, abs=1e-9), budget
        assert front.lower_bound[budget] == pytest.approx(expected, abs=1e-9)
        if np.isfinite(expected):
            assert front.swaps[budget] <= budget
            chosen = np.flatnonzero((combos == front.shapes[budget]).all(axis=1))
            assert costs[chosen[0]] == pytest.approx(expected, abs=1e-9)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_bounds_per_base_never_exceed_a_fingers_cost_and_the_front_equals_brute_force(data):
    """Generated pairs of objects: the root's bound and each object's bound per base and first block (what
    a child's bases are kept by) never exceed the true costs, and the certified front equals brute force."""
    blocks = data.draw(st.sampled_from([2, 3]), label="blocks")
    kinds = [data.draw(st.sampled_from(["ellipse", "polygon", "lumpy"]), label="kind") for _ in range(2)]
    seeds = [data.draw(st.integers(0, 10_000), label="seed") for _ in range(2)]
    weights = np.array([1.0, data.draw(st.sampled_from([0.4, 1.0, 2.5]), label="weight")])
    side = data.draw(st.sampled_from(["left", "right"]), label="side")
    targets = [design.finger_problems(generated_contours(k, s), base_offsets=OFFSETS)[side][0]
               for k, s in zip(kinds, seeds)]
    space = design_space(TABLE, blocks)
    shape_of, stock = shape_stock(space, {i: 2 for i in SHELF_IDS})
    current = np.array([shape_of[i] for i in (78, 27, 64)[:blocks]])
    search = FingerFrontSearch(targets, weights, space)
    usable = np.flatnonzero(stock > 0)
    combos = np.array([c for c in itertools.product(usable, repeat=blocks)
                       if np.all(np.bincount(c, minlength=len(stock)) <= stock)])
    per_base = []
    for target in targets:  # (finger, base) costs, inf where it collides
        bases = len(target.bases)
        shapes = np.repeat(combos, bases, axis=0)
        costs = design_costs(target, space, shapes, np.zeros_like(shapes), np.tile(np.arange(bases), len(combos)))
        per_base.append(np.where(costs >= COLLISION_PENALTY, np.inf, costs).reshape(len(combos), bases))
    costs = sum(w * c.min(axis=1) for w, c in zip(weights, per_base))
    assert search.root_bound <= costs.min() + 1e-9
    for problem, (poses, alphas, alive), cost in zip(search.problems, search.roots, per_base):
        first = np.asarray(space.choices[0])
        least, bound = np.empty(len(first)), np.empty((len(first), len(alive)))
        _node_bounds(problem, 0, poses, alphas, alive, blocks == 1, search.scratch, least, bound)
        for k, shape in enumerate(first):
            below = combos[:, 0] == shape
            if below.any():
                assert np.all(bound[k] <= cost[below].min(axis=0) + 1e-9)
    front = solve_finger_front(targets, weights, space, current=current, stock=stock, search=search)
    assert front.status in (Status.CERTIFIED, Status.INFEASIBLE) and front.optimal.all()
    swaps = (combos != current).sum(axis=1)
    for budget in range(blocks + 1):
        expected = costs[swaps <= budget].min()
        assert front.fun[budget] == pytest.approx(expected, abs=1e-9), budget


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_a_front_is_the_same_under_any_stock_within_what_its_search_needed(data):
    """What the joint search's kept fronts rest on: a search's front under a generated stock, and a fresh
    search under another stock that holds no more of any shape than the first one needed (but maybe more
    than it had) and still fits the front's fingers, with the same ceiling, find the same front."""
    blocks = data.draw(st.sampled_from([2, 3]), label="blocks")
    stiff_top = data.draw(st.integers(0, 1), label="stiff top")
    kind, seed = data.draw(st.sampled_from(["ellipse", "polygon", "lumpy"])), data.draw(st.integers(0, 999))
    target = design.finger_problems(generated_contours(kind, seed), base_offsets=OFFSETS)["left"][0]
    space = design_space(TABLE, blocks, stiff_positions=range(stiff_top))
    search = FingerFrontSearch([target], [1.0], space)
    shape_of, _ = shape_stock(space, {})
    stiff_ids = {d for members, stiff in zip(space.members, space.member_stiff) for d, q in zip(members, stiff) if q}
    shelf = {d: data.draw(st.integers(0, 2), label=f"design {d}") for d in SHELF_IDS}
    stock, stiff_stock = np.zeros(len(space.theta), np.int64), np.zeros(len(space.theta), np.int64)
    for d, count in shelf.items():
        stock[shape_of[d]] += count
        stiff_stock[shape_of[d]] += count if d in stiff_ids else 0
    current = np.array([shape_of[i] for i in (57, 27, 64)[:blocks]])
    factor = data.draw(st.sampled_from([np.inf, 1.0, 1.05, 1.3]), label="ceiling over the unlimited optimum")
    unlimited = solve_finger_front([target], [1.0], space, current=current, search=search)
    ceiling = np.where(np.isfinite(unlimited.fun), unlimited.fun * factor, np.inf)

    def front_under(stock, stiff_stock):
        front = Front(blocks, ceiling)
        run = Run(current, space.stiff_positions, np.zeros(blocks, bool), stock, stiff_stock, front.limit,
                  front.record)
        search.run(run, RunControl(None, None))
        return front, run.stock_needed()

    kept, (needed, needed_stiff) = front_under(stock, stiff_stock)
    used, used_stiff = np.zeros_like(stock), np.zeros_like(stock)
    for candidate in kept.chosen:
        if candidate is not None:
            used = np.maximum(used, np.bincount(candidate.shapes, minlength=len(stock)))
            used_stiff = np.maximum(used_stiff, np.bincount(candidate.shapes[space.stiff_positions],
                                                            minlength=len(stock)))
    assert np.all(used <= needed) and np.all(used_stiff <= needed_stiff)  # so the draws below can fit them
    other = np.array([data.draw(st.integers(int(u), int(n))) for u, n in zip(used, needed)])
    other_stiff = np.array([data.draw(st.integers(int(u), int(min(n, o)))) for u, n, o in zip(used_stiff, needed_stiff,
                                                                                               other)])
    fresh, _ = front_under(other, other_stiff)
    np.testing.assert_allclose(fresh.best, kept.best, rtol=0, atol=1e-12)


def test_a_stiff_block_at_a_free_position_gives_way_when_its_kind_is_needed():
    """A shape with one stiff and one free block in stock: the free position holds the stiff one, and the
    forced-stiff position wants that shape too. Keeping it leaves no stiff block for the other position; the
    free position may take the free block of the same shape instead (one swap). Against brute force over the
    shapes and both ways of filling the free position."""
    space = design_space(TABLE, 2, stiff_positions=[0])
    shape_of, _ = shape_stock(space, {})
    twin, free = shape_of[57], shape_of[14]
    stock, stiff_stock = np.zeros(len(space.theta), np.int64), np.zeros(len(space.theta), np.int64)
    stock[twin], stiff_stock[twin], stock[free] = 2, 1, 1
    current = np.array([shape_of[64], twin])
    targets = [design.finger_problems(contours_of("generated", 5), base_offsets=OFFSETS)["left"][0]]
    front = solve_finger_front(targets, [1.0], space, current=current, stock=stock, stiff_stock=stiff_stock,
                               keeps_stiff=np.array([True, True]), releasable=np.array([False, True]))
    best = np.full(3, np.inf)
    for first, second in itertools.product([twin], [twin, free]):
        for release in ((False, True) if second == current[1] else (False,)):
            stiff_use = 1 + (second == twin and not release)
            if stiff_use > stiff_stock[twin] or [first, second].count(twin) > stock[twin]:
                continue
            swaps = int(first != current[0]) + int(second != current[1] or release)
            cost = weighted_costs(targets, [1.0], space, np.array([[first, second]]))[0]
            if cost < COLLISION_PENALTY:
                best[swaps:] = np.minimum(best[swaps:], cost)
    assert np.isfinite(best[2]), "the scenario needs a collision-free finger"
    assert front.status == Status.CERTIFIED
    assert front.fun == pytest.approx(best, abs=1e-9)
    if front.shapes[2].tolist() == [twin, twin]:
        assert front.swapped[2].tolist() == [True, True]  # the stiff block gave way: two swaps


PAIR_SHELF = {2: 1, 14: 1, 40: 2, 64: 1, 71: 1}
PAIR_OBJECTS = [("strawberry", None), ("generated", 5)]


def pair_plan(left=(78, 27), right=(19, 45), shelf=PAIR_SHELF, **kwargs):
    objects = [TargetObject(f"{n}{s}", contours_of(n, s), weight=w, base_offsets=OFFSETS)
               for (n, s), w in zip(PAIR_OBJECTS, (1.0, 0.7))]
    return robot(left, right), objects, plan_reconfiguration(robot(left, right), shelf, objects, slots=SLOTS,
                                                             **kwargs)


def test_the_order_of_the_slots_changes_no_point_of_a_plan():
    """The nested search puts the finger with the costlier search first whatever the slots' order; every
    point keeps each chain's own finger."""
    shelf = {2: 1, 14: 1, 40: 1, 64: 1, 71: 1}  # the fingers' searches differ in size
    built, objects, result = pair_plan(left=(78, 27, 64), right=(19, 45, 2), shelf=shelf)
    swapped = plan_reconfiguration(built, shelf, objects, slots=SLOTS[::-1])
    for point, other in zip(result.points, swapped.points):
        assert other.objective == pytest.approx(point.objective, abs=1e-12)
        mine = {f.chain: f.cost for f in point.fingers}  # a left finger's cost differs from a right one's
        assert {f.chain: f.cost for f in other.fingers} == pytest.approx(mine, abs=1e-9)


def test_pair_plan_equals_brute_force_and_its_steps_rebuild_it():
    built, objects, result = pair_plan()
    assert result.success and len(result.points) == 5
    space = design_space(TABLE, 2)
    pool = Counter(PAIR_SHELF) + Counter((78, 27, 19, 45))
    ids = sorted(pool)
    per_side = {}
    for side in ("left", "right"):
        targets = [design.finger_problems(o.contours, base_offsets=OFFSETS)[side][0] for o in objects]
        pairs = np.array(list(itertools.product(ids, repeat=2)))
        shape_of = {d: s for s, m in enumerate(space.members) for d in m}
        costs = weighted_costs(targets, [1.0, 0.7], space, np.vectorize(shape_of.get)(pairs))
        per_side[side] = {tuple(p): c for p, c in zip(pairs, costs) if c < COLLISION_PENALTY}
    best = np.full(5, np.inf)
    for (left, lc), (right, rc) in itertools.product(per_side["left"].items(), per_side["right"].items()):
        if all(n <= pool[d] for d, n in Counter(left + right).items()):
            swaps = sum(a != b for a, b in zip(left + right, (78, 27, 19, 45)))
            best[swaps:] = np.minimum(best[swaps:], lc + rc)
    for point, expected in zip(result.points, best):
        assert point.lower_bound <= expected + 1e-9 <= point.objective + 2e-9
        if point.optimal:
            assert point.objective == pytest.approx(expected, abs=1e-9)
    chosen = result.points[-1]
    steps = swap_steps(built, chosen.assembly, PAIR_SHELF)
    assert len(steps) >= chosen.swaps and steps[-1].assembly == chosen.assembly
    assert Counter(d for c in chosen.assembly.chains for d in c.design_ids) <= pool
    assert "insert design" in steps[0].describe() or "remove design" in steps[0].describe()


def replay(built, target, shelf, steps):
    """Apply the steps one by one: each takes out the block the position holds and inserts one the shelf
    holds at that moment; returns the layout at the end."""
    layout = {c.name: [b.design_id for b in c.blocks] for c in built.chains}
    stock = Counter({d: n for d, n in shelf.items() if n})
    for step in steps:
        assert layout[step.chain][step.position] == step.remove
        if step.remove is not None:
            stock[step.remove] += 1
        if step.insert is not None:
            assert stock[step.insert] > 0, f"over-drawn: {step.describe()}"
            stock[step.insert] -= 1
        layout[step.chain][step.position] = step.insert
        assert {d: n for d, n in stock.items() if n} == step.shelf
    assert layout == {c.name: list(c.design_ids) for c in target.chains}
    return layout


def assert_plan_is_brute_force(built, shelf, objects, slots, result):
    """Every point against brute force: certified points equal to it, every bound at most it, "no gripper"
    only where there is none; each point's steps rebuild its robot without over-drawing the shelf."""
    expected = plan_brute_force(built, shelf, objects, slots)
    assert len(result.points) == len(expected)
    for point, best in zip(result.points, expected):
        assert point.lower_bound <= best + 1e-9, (point.max_swaps, point.lower_bound, best)
        assert point.objective >= best - 1e-9
        if point.optimal:
            assert point.objective == pytest.approx(best, abs=1e-9) or np.isinf(best) == np.isinf(point.objective)
            assert np.isinf(best) == np.isinf(point.objective), (point.max_swaps, point.objective, best)
        if point.assembly is None:
            continue
        steps = swap_steps(built, point.assembly, shelf)
        replay(built, point.assembly, shelf, steps)
        assert sum(s.insert is not None for s in steps) == point.swaps <= point.max_swaps
        rotated = sum(a.rotation_steps != b.rotation_steps for slot in slots for a, b in
                      zip(built.chain(slot.chain).blocks, point.assembly.chain(slot.chain).blocks))
        assert rotated <= point.swaps
    if result.status == Status.CERTIFIED:
        assert all(p.optimal for p in result.points) and result.success
    if not result.success:
        assert result.status in (Status.INFEASIBLE, Status.TIME_BUDGET, Status.CANCELED)
        assert result.status != Status.INFEASIBLE or np.isinf(expected).all()


def test_fingers_that_want_the_same_shelf_blocks_still_get_the_best_gripper():
    """Both fingers' own best fingers want the shelf's only 29 and 24: the gripper must share them out (it
    was reported as "no gripper", certified)."""
    slots = (FingerSlot("left", "left"), FingerSlot("right", "right"))
    built, shelf = robot((18, 12), (17, 23)), {29: 1, 24: 1}
    objects = [TargetObject("lumpy99", contours_of("generated", 99))]
    result = plan_reconfiguration(built, shelf, objects, slots=slots)
    assert result.success and result.status == Status.CERTIFIED
    assert_plan_is_brute_force(built, shelf, objects, slots, result)


@pytest.mark.parametrize("reports", [1, 4, 16, 32, 48])
def test_a_plan_stopped_anywhere_keeps_bounds_below_the_optimum(reports):
    """Canceled after a number of progress reports (in the fingers' own fronts, or while they are combined
    over the contested shelf): every point's bound stays at or below brute force, every certified point is it."""
    slots = (FingerSlot("left", "left"), FingerSlot("right", "right"))
    built, shelf = robot((18, 12, 40), (17, 23, 40)), {29: 1, 24: 1, 3: 1}
    objects = [TargetObject("lumpy99", contours_of("generated", 99))]
    heard = []

    def cancel_late(progress):
        heard.append(progress)
        if len(heard) >= reports:
            raise StopIteration

    result = plan_reconfiguration(built, shelf, objects, slots=slots, callback=cancel_late)
    assert_plan_is_brute_force(built, shelf, objects, slots, result)


CONTESTED = (3, 12, 18, 24, 29, 40, 45, 57, 64, 71)  # 45 and later stiff


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_plans_equal_brute_force_on_scarce_shelves(data):
    """Built robots (some blocks mirrored at snap-fit 6), scarce shelves the fingers compete for, and
    objects the planner has not seen: every point as brute force finds it."""
    blocks = data.draw(st.sampled_from((2, 2, 3)), label="blocks")
    stiff_top = data.draw(st.integers(0, 1), label="stiff top")
    slots = (FingerSlot("left", "left", stiff_top), FingerSlot("right", "right", stiff_top))

    def finger():
        return tuple(PlacedBlock(data.draw(st.sampled_from(CONTESTED[6:] if k < stiff_top else CONTESTED)),
                                 data.draw(st.sampled_from((0, 0, 0, 6)))) for k in range(blocks))

    built = Assembly("pair", (Chain("left", "main", finger()), Chain("right", "main", finger())))
    shelf = {d: data.draw(st.integers(0, 1)) for d in data.draw(st.sets(st.sampled_from(CONTESTED), max_size=5))}
    kinds = data.draw(st.lists(st.tuples(st.sampled_from(("ellipse", "polygon", "lumpy")), st.integers(0, 999)),
                               min_size=1, max_size=2), label="objects")
    objects = [TargetObject(f"{kind}{seed}", generated_contours(kind, seed), weight=1.0 / (1 + k))
               for k, (kind, seed) in enumerate(kinds)]
    result = plan_reconfiguration(built, shelf, objects, slots=slots)
    assert_plan_is_brute_force(built, shelf, objects, slots, result)


def test_a_mirrored_block_of_the_robot_counts_as_built():
    """A block at snap-fit 6 bends to the other side, and every block after it too: the robot as built
    (0 swaps) is that finger, kept with its rotation; re-seating the block upright is one swap. At any
    other snap-fit the finger leaves the plane: no finger as built."""
    slots = (FingerSlot("left", "left"), FingerSlot("right", "right"))
    objects = [TargetObject("ellipse", generated_contours("ellipse", 5))]
    upright = plan_reconfiguration(robot((64, 40), (64, 40)), {}, objects, slots=slots)
    mirrored = Assembly("pair", (Chain("left", "main", (PlacedBlock(64), PlacedBlock(40, 6))),
                                 Chain("right", "main", (PlacedBlock(64), PlacedBlock(40)))))
    result = plan_reconfiguration(mirrored, {}, objects, slots=slots)
    assert_plan_is_brute_force(mirrored, {}, objects, slots, result)
    as_built = result.points[0]
    assert as_built.optimal and as_built.swaps == 0
    assert as_built.objective != pytest.approx(upright.points[0].objective, abs=1e-6)
    assert [b.rotation_steps for b in as_built.assembly.chain("left").blocks] == [0, 6]
    turned = Assembly("pair", (Chain("left", "main", (PlacedBlock(64), PlacedBlock(40, 3))),
                               Chain("right", "main", (PlacedBlock(64), PlacedBlock(40)))))
    out_of_plane = plan_reconfiguration(turned, {}, objects, slots=slots)
    assert np.isinf(out_of_plane.points[0].objective) and out_of_plane.points[0].optimal
    steps = swap_steps(turned, out_of_plane.points[1].assembly, {})
    assert [s.describe() for s in steps] == ["finger left, position 1: remove design 40, insert design 40 at "
                                             "rotation step 0"]


def test_a_robot_that_already_fits_plans_zero_swaps():
    _, _, first = pair_plan()
    fitted = first.points[-1].assembly
    left, right = fitted.chain("left").design_ids, fitted.chain("right").design_ids
    leftover = Counter(PAIR_SHELF) + Counter((78, 27, 19, 45)) - Counter(left + right)
    _, _, again = pair_plan(left, right, shelf=dict(leftover))
    assert all(p.swaps == 0 for p in again.points) and again.points[0].optimal
    assert again.points[-1].objective == pytest.approx(first.points[-1].objective, abs=1e-9)
    assert swap_steps(fitted, again.points[-1].assembly, dict(leftover)) == ()


def test_a_canceled_plan_keeps_proven_bounds():
    def cancel(progress):
        raise StopIteration

    _, _, result = pair_plan(callback=cancel)
    assert result.status == Status.CANCELED and "canceled" in result.message
    for point in result.points:
        assert point.lower_bound <= point.objective and not (point.optimal and point.max_swaps > 0)


def test_a_cancel_stops_the_single_object_searches_that_seed_the_front(monkeypatch):
    """The seeds (each object's own optimum) are long work too: a cancel must reach them, not wait for them."""
    from planner import reconfigure
    statuses = []

    def recording_solve_finger(*args, **kwargs):
        result = solve_finger(*args, **kwargs)
        statuses.append(result.status)
        return result

    solve_finger = reconfigure.solve_finger
    monkeypatch.setattr(reconfigure, "solve_finger", recording_solve_finger)
    def cancel(progress):
        raise StopIteration

    _, _, result = pair_plan(callback=cancel)
    assert result.status == Status.CANCELED
    assert statuses and all(status == Status.CANCELED for status in statuses), statuses


def test_a_plans_progress_rises_from_0_to_1():
    fractions = []
    _, _, result = pair_plan(callback=lambda progress: fractions.append(progress.fraction))
    assert result.success and fractions
    assert all(0.0 <= f <= 1.0 for f in fractions) and fractions == sorted(fractions), fractions
    fractions.clear()  # fingers that compete for the shelf: their combined search reports too
    built, shelf = robot((18, 12), (17, 23)), {29: 1, 24: 1}
    result = plan_reconfiguration(built, shelf, [TargetObject("lumpy99", contours_of("generated", 99))], slots=SLOTS,
                                  callback=lambda progress: fractions.append(progress.fraction))
    assert result.success and fractions and fractions == sorted(fractions), fractions


@pytest.mark.parametrize("change, match", [
    (dict(shelf={999: 1}), "999 is not a design ID"),
    (dict(shelf={2: -1}), "counts are integers >= 0"),
    (dict(slots=(FingerSlot("middle", "left"),)), "no chain 'middle'"),
    (dict(slots=(FingerSlot("left", "up"),)), "side must be one of"),
    (dict(time_budget=0.0), "time_budget"),
])
def test_bad_input_is_named(change, match):
    objects = [TargetObject("strawberry", contours_of("strawberry"))]
    arguments = dict(shelf=PAIR_SHELF, slots=SLOTS) | change
    with pytest.raises(ValueError, match=match):
        plan_reconfiguration(robot((78, 27), (19, 45)), arguments.pop("shelf"), objects, **arguments)
    with pytest.raises(ValueError, match="weight must be > 0"):
        plan_reconfiguration(robot((78, 27), (19, 45)), PAIR_SHELF,
                             [TargetObject("s", contours_of("strawberry"), weight=0.0)], slots=SLOTS)


def test_swap_steps_refuse_a_target_the_shelf_cannot_supply():
    with pytest.raises(ValueError, match=r"lack designs \{15: 1\}"):
        swap_steps(robot((78, 27), (19, 45)), robot((15, 27), (19, 45)), {2: 3})


DESIGNS = (2, 14, 40, 57, 64)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_steps_never_overdraw_the_shelf_and_rebuild_the_target(data):
    """Any current robot and any target the shelf plus the robot can supply (cycles of swaps included):
    the shelf never goes below zero, every step changes one position, the last layout is the target."""
    lengths = data.draw(st.lists(st.integers(1, 4), min_size=1, max_size=3))
    current = [data.draw(st.lists(st.sampled_from(DESIGNS), min_size=n, max_size=n)) for n in lengths]
    every = Counter(d for ids in current for d in ids)
    shelf = Counter({d: data.draw(st.integers(0, 2)) for d in DESIGNS})
    pool = list((every + shelf).elements())
    order = data.draw(st.permutations(pool))
    target, start = [], 0
    for n in lengths:
        target.append(order[start:start + n])
        start += n

    def make(layout):
        return Assembly("r", tuple(Chain(f"c{k}", "main", tuple(PlacedBlock(i) for i in ids))
                                   for k, ids in enumerate(layout)))

    steps = swap_steps(make(current), make(target), dict(shelf))
    layout = [list(ids) for ids in current]
    stock = Counter(shelf)
    for step in steps:
        k = int(step.chain[1:])
        assert layout[k][step.position] == step.remove
        if step.remove is not None:
            stock[step.remove] += 1
        if step.insert is not None:
            assert stock[step.insert] > 0, "drew a block the shelf does not hold"
            stock[step.insert] -= 1
        layout[k][step.position] = step.insert
        assert {d: n for d, n in stock.items() if n} == step.shelf
    assert layout == [list(t) for t in target]
    assert steps == () or steps[-1].assembly == make(target)
    changed = sum(a != b for c, t in zip(current, target) for a, b in zip(c, t))
    assert sum(s.insert is not None for s in steps) == changed
