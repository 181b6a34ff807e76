"""The certified finger search against brute force, and the exact collision rule against an independent
dense rasterisation of the finger body (hypothesis), on sample and generated asymmetric objects."""
import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planner import design
from planner.contours import extract_contours, load_catalog_object
from planner.generated_objects import PIXEL_SIZE, lumpy_object
from planner.kinematics import chain_shape, design_parameters
from planner.objectives import COLLISION_PENALTY
from planner.optimize import Status, design_costs, design_space, solve_finger
from planner.optimize.finger_search import (_block_update, _leaf_bounds, _leaf_cost, _moved, _split, _start, new_state,
                                            search_problem)
from planner.table import load_table

pytestmark = pytest.mark.fast

TABLE = load_table()
# a shelf of 12 distinct designs (3 stiff) keeps brute force small; each may be used up to 3 times
SHELF = {i: 3 for i in (2, 8, 14, 19, 27, 33, 40, 45, 61, 64, 71, 78)}


def brute_force(target, space):
    """Lowest objective over every (base, blocks) combination of the space, and its argument."""
    combos = np.array(list(itertools.product(*space.choices)))
    shapes = np.repeat(combos, len(target.bases), axis=0)
    bases = np.tile(np.arange(len(target.bases)), len(combos))
    costs = design_costs(target, space, shapes, np.zeros_like(shapes), bases)
    best = int(np.argmin(costs))
    return float(costs[best]), shapes[best], int(bases[best])


OBJECTS = [("strawberry", None), ("gingerbread", None), ("generated", 1), ("generated", 7)]


@pytest.mark.parametrize("blocks, stiff", [(2, 0), (3, 1)])
@pytest.mark.parametrize("name, seed", OBJECTS)
def test_certified_search_equals_brute_force(name, seed, blocks, stiff):
    contours = (load_catalog_object(name) if seed is None else extract_contours(lumpy_object(seed), PIXEL_SIZE))
    offsets = np.arange(0.0, 6.5e-3, 2e-3)
    problems = design.finger_problems(contours, base_offsets=offsets)
    space = design_space(TABLE, blocks, stiff_positions=range(stiff), inventory=SHELF)
    for side in ("left", "right"):
        target = problems[side][0]
        result = solve_finger(target, space)
        cost, shapes, base = brute_force(target, space)
        assert result.status == Status.CERTIFIED and result.optimal
        assert result.fun == pytest.approx(cost, abs=1e-9), side
        assert result.design_ids == space.design_ids(shapes) and result.base == base, side
        assert result.lower_bound == pytest.approx(result.fun, abs=1e-9)


FRONT_FINGER = design_space(TABLE, 4, stiff_positions=range(2))  # every design; its fields are prepared at set-up


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 40), side=st.sampled_from(["left", "right"]), base=st.integers(0, 12),
       picks=st.lists(st.integers(0, 10**6), min_size=3, max_size=3))
def test_last_block_bounds_and_costs_match_the_objective(seed, side, base, picks):
    """The search's complete-finger kernels against the objective, for every last block after a drawn
    prefix: the bound never exceeds the objective of a collision-free finger and is infinite (a collision
    proven by the cover) only for colliding ones, the one-pass cost equals the objective, and a finger that
    pass rejects as too close is one the objective finds colliding."""
    target = design.finger_problems(extract_contours(lumpy_object(seed), PIXEL_SIZE))[side][0]
    problem = search_problem(target, FRONT_FINGER)
    prefix = [int(choices[pick % len(choices)]) for choices, pick in zip(FRONT_FINGER.choices, picks)]
    contour, x = problem[0], target.bases[base, 0]
    pose, alpha = np.array([x, 0.0, 0.0]), np.hypot(contour[:, 0] - x, contour[:, 1])
    for shape in prefix:
        after = np.empty_like(alpha)
        _block_update(problem, pose, alpha, shape, after)
        pose, alpha = _moved(problem, pose, shape), after
    last = FRONT_FINGER.choices[3]
    bounds = np.empty(len(last))
    _leaf_bounds(problem, 3, pose, alpha, bounds)
    shapes = np.array([prefix + [int(s)] for s in last])
    objective = design_costs(target, FRONT_FINGER, shapes, np.zeros_like(shapes), np.full(len(last), base))
    for k, shape in enumerate(last):
        colliding = objective[k] >= COLLISION_PENALTY
        assert colliding or np.isfinite(bounds[k]), (prefix, int(shape))
        cost = _leaf_cost(problem, pose, alpha, int(shape), np.inf)
        if cost < 0.0:
            assert colliding, (prefix, int(shape))
            continue
        if not colliding:
            assert bounds[k] <= cost + 1e-9, (prefix, int(shape))
            assert cost == pytest.approx(objective[k], abs=1e-9), (prefix, int(shape))
        cut = _leaf_cost(problem, pose, alpha, int(shape), 0.5 * cost)  # stops once the sum reaches the cutoff
        assert 0.5 * cost <= cut <= cost + 1e-12


@pytest.mark.parametrize("name, seed", [("gingerbread", None), ("generated", 4), ("generated", 9)])
def test_split_search_agrees_with_one_worker(name, seed):
    contours = load_catalog_object(name) if seed is None else extract_contours(lumpy_object(seed), PIXEL_SIZE)
    space = design_space(TABLE, 3, stiff_positions=[0], inventory=SHELF)
    for side, (target, _) in design.finger_problems(contours).items():
        alone = solve_finger(target, space, options={"workers": 1})
        shared = solve_finger(target, space, options={"workers": 2})
        assert alone.optimal and shared.optimal, side
        assert shared.fun == pytest.approx(alone.fun, abs=1e-12), side
        assert shared.design_ids == alone.design_ids and shared.base == alone.base, side


def test_split_deals_every_first_level_child_to_one_worker():
    target = design.finger_problems(load_catalog_object("gingerbread"))["right"][0]
    space = design_space(TABLE, 3, stiff_positions=[0], inventory=SHELF)
    problem = search_problem(target, space)
    state = new_state(problem, space)
    _start(problem, state)
    children = state[3][0, : state[2][0]]
    assert len(children) > 3
    shares = _split(state, 3)
    dealt = np.concatenate([share[3][0, : share[2][0]] for share in shares])
    assert sorted(dealt.tolist()) == sorted(children.tolist())
    assert all(share[17] is state[17] for share in shares)  # the incumbent, and nothing else, is shared
    assert all(share[12] is not state[12] and share[13] is not state[13] for share in shares)
    assert sum(int(share[14][1]) for share in shares) == int(state[14][1])


@pytest.mark.parametrize("workers", [1, 2])
def test_stopped_search_reports_a_proven_lower_bound(workers):
    contours = extract_contours(lumpy_object(3), PIXEL_SIZE)
    target = design.finger_problems(contours, base_offsets=[0.0, 4e-3])["left"][0]
    space = design_space(TABLE, 3, inventory=SHELF)
    optimum = solve_finger(target, space).fun
    calls = []

    def stop_early(progress):  # in the search proper (the beams report no evaluations)
        if progress.nfev:
            calls.append(progress)
        if len(calls) == 2:
            raise StopIteration

    stopped = solve_finger(target, space, callback=stop_early, options={"expansions_per_check": 1, "workers": workers})
    assert stopped.status == Status.CANCELED and not stopped.optimal and not stopped.success
    assert stopped.lower_bound <= optimum + 1e-9 <= stopped.fun + 2e-9
    assert "lower bound" in stopped.message


def test_bad_options_and_targets_are_refused():
    contours = load_catalog_object("strawberry")
    target = design.finger_problems(contours)["left"][0]
    space = design_space(TABLE, 2)
    with pytest.raises(ValueError, match="unknown keys"):
        solve_finger(target, space, options={"width": 3})
    with pytest.raises(ValueError, match="field_spacing"):
        solve_finger(target, space, options={"field_spacing": 0.0})
    with pytest.raises(ValueError, match="workers"):
        solve_finger(target, space, options={"workers": 0})
    with pytest.raises(ValueError, match="planar"):
        solve_finger(target, design_space(TABLE, 2, allow_rotation=True))


# ----------------------------------------------------------------------------- collision rule
def tube_points(theta, length, base_x, radius):
    """Dense rasterisation of the body in the finger frame: the centerline every ~0.1 mm and, around each
    point, circles of radius 0, r/2 and r - 2 um at 720 angles (rim spacing 0.11 mm)."""
    centre = chain_shape(theta, length, 0.0, samples_per_block=200).points[:, [0, 2]] + [base_x, 0.0]
    angles = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    rings = np.concatenate([[0.0], [radius / 2, radius - 2e-6]])
    offsets = (rings[:, None, None] * np.stack([np.cos(angles), np.sin(angles)], -1)).reshape(-1, 2)
    return (centre[:, None, :] + offsets[None]).reshape(-1, 2)


def on_object_pixel(contours, points) -> np.ndarray:
    """Which object-frame points (..., 2) [m] fall on an object pixel, straight from the mask and the frame
    definition of ``planner.contours``."""
    column0, row0 = contours.origin_pixel
    column = np.floor(points[..., 0] / contours.pixel_size + column0).astype(int)
    row = np.floor(row0 - points[..., 1] / contours.pixel_size).astype(int)
    rows, columns = contours.mask.shape
    inside = (column >= 0) & (column < columns) & (row >= 0) & (row < rows)
    return np.where(inside, contours.mask[row.clip(0, rows - 1), column.clip(0, columns - 1)], False)


def body_enters_object(contours, body, theta, length, base_x) -> bool:
    points = tube_points(theta, length, base_x, body.radius)
    return bool(on_object_pixel(contours, body.to_object(points)).any())


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 50), ids=st.lists(st.sampled_from(TABLE.ids.tolist()), min_size=1, max_size=4),
       offset=st.floats(0.0, 0.012), side=st.sampled_from(["left", "right"]))
def test_collision_free_designs_never_enter_the_object(seed, ids, offset, side):
    contours = extract_contours(lumpy_object(seed), PIXEL_SIZE)
    body = design.finger_problems(contours)[side][0].body
    theta, length, _ = design_parameters(TABLE, np.array(ids))
    clearance = float(body.clearance(theta, length, -offset))
    colliding = bool(body.colliding(theta, length, -offset))
    assert colliding == (clearance < -1e-6 - 1e-9) or abs(clearance) < 2e-6
    if not colliding:
        assert not body_enters_object(contours, body, theta, length, -offset)
    if clearance < -2e-4:  # well beyond the rasterisation's resolution: the raster sees it too
        assert body_enters_object(contours, body, theta, length, -offset)


@pytest.mark.parametrize("name, seed", OBJECTS)
def test_certified_fingers_touch_but_never_enter(name, seed):
    contours = load_catalog_object(name) if seed is None else extract_contours(lumpy_object(seed), PIXEL_SIZE)
    problems = design.finger_problems(contours)
    space = design_space(TABLE, 3, stiff_positions=[0], inventory=SHELF)
    for side in ("left", "right"):
        target = problems[side][0]
        result = solve_finger(target, space)
        theta, length, _ = design_parameters(TABLE, np.array(result.design_ids))
        base_x = target.bases[result.base, 0]
        assert result.optimal and not body_enters_object(contours, target.body, theta, length, base_x)
        assert float(target.body.clearance(theta, length, base_x)) >= -2e-6  # overlaps under 1 um are touching


def test_exact_distance_equals_distance_to_the_pixel_squares():
    contours = extract_contours(lumpy_object(5), PIXEL_SIZE)
    distance = design.finger_problems(contours)["left"][0].body.distance
    rng = np.random.default_rng(0)
    points = rng.uniform([-0.04, -0.09], [0.04, 0.01], (400, 2))
    rows, cols = np.nonzero(contours.mask)
    column0, row0 = contours.origin_pixel
    x0, z1 = (cols - column0) * PIXEL_SIZE, (row0 - rows) * PIXEL_SIZE
    dx = np.maximum(np.maximum(x0[None] - points[:, :1], points[:, :1] - (x0[None] + PIXEL_SIZE)), 0)
    dz = np.maximum(np.maximum((z1[None] - PIXEL_SIZE) - points[:, 1:], points[:, 1:] - z1[None]), 0)
    assert np.allclose(distance.exact(points), np.sqrt(dx**2 + dz**2).min(axis=1), atol=1e-12)
