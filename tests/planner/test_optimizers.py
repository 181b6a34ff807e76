"""Design optimizers on small synthetic problems: brute force, certificates, PSO, budgets, inventory."""
import itertools
from types import SimpleNamespace

import numpy as np
import pytest

from planner.kinematics import chain_shape
from planner.objectives import COLLISION_PENALTY, path_target
from planner.optimize import Status, design_costs, design_space, solve_exact, solve_pso
from planner.optimize.exact import _beam, _Prefixes

pytestmark = pytest.mark.fast


def small_table():
    """Six designs, two of them stiff; IDs 5 and 6 share a shape (merged)."""
    return SimpleNamespace(
        ids=np.array([1, 2, 3, 4, 5, 6]),
        rod_length=np.array([0.010, 0.0125, 0.015, 0.010, 0.015, 0.015]),
        rod_diameter=np.array([0.31e-3, 0.31e-3, 0.44e-3, 0.62e-3, 0.62e-3, 0.763e-3]),
        theta0=np.radians([30.0, 20.0, 12.0, 6.0, 4.0, 4.0]),
        stiffness=np.array([1.0, 1.5, 2.0, 3.0, 4.0, 5.0]),
    )


def target_chain(ids, steps=None):
    table = small_table()
    index = np.searchsorted(table.ids, ids)
    phi = np.zeros(len(ids)) if steps is None else np.array(steps) * np.pi / 6
    return chain_shape(table.theta0[index], table.rod_length[index], phi).points


def brute_force(target, space):
    options = [(s, r) for s in range(len(space.theta)) for r in range(space.rotations)]
    combos = np.array([c for c in itertools.product(options, repeat=space.num_blocks)
                       if all(s in space.choices[i] for i, (s, _) in enumerate(c))])
    return float(design_costs(target, space, combos[..., 0], combos[..., 1]).min())


def test_shapes_merged_and_ties_go_to_the_stiffest():
    space = design_space(small_table(), 2)
    assert len(space.theta) == 5
    merged = [m for m in space.members if len(m) == 2][0]
    assert merged == (6, 5)  # stiffer first


def test_exact_equals_brute_force_with_rotations_and_is_certified():
    points = target_chain([2, 3], [0, 3])[::2] + np.array([0.002, -0.001, 0.0])
    target = path_target(points)
    space = design_space(small_table(), 2, allow_rotation=True)
    result = solve_exact(target, space, options={"max_width": None})
    assert result.success and result.optimal and result.status == Status.CERTIFIED
    assert result.fun == pytest.approx(brute_force(target, space), abs=1e-7)
    assert result.lower_bound == result.fun


def test_uncertified_result_reports_an_honest_lower_bound():
    points = target_chain([1, 2, 3, 2])[::3] + np.array([0.003, 0.0, 0.0])
    target = path_target(points)
    space = design_space(small_table(), 4)
    optimum = solve_exact(target, space, options={"max_width": None}).fun
    narrow = solve_exact(target, space, options={"initial_width": 1, "max_width": 1})
    assert narrow.lower_bound <= optimum + 1e-7 and optimum <= narrow.fun + 1e-7
    if not narrow.optimal:
        assert "not certified" in narrow.message
    else:
        assert narrow.fun == pytest.approx(optimum)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_never_worse_than_pso(seed):
    points = target_chain([1, 3, 5], [0, 2, 0])[::2]
    target = path_target(points)
    space = design_space(small_table(), 3, allow_rotation=True)
    exact = solve_exact(target, space, options={"max_width": None})
    pso = solve_pso(target, space, rng=seed, options={"swarm_size": 20, "maxiter": 30})
    assert exact.optimal
    assert exact.fun <= pso.fun + 1e-7  # same design up to rounding noise
    assert not pso.optimal and pso.success


def test_pso_is_reproducible_for_a_seed():
    target = path_target(target_chain([1, 2, 3])[::2])
    space = design_space(small_table(), 3)
    first = solve_pso(target, space, rng=7, options={"maxiter": 10})
    second = solve_pso(target, space, rng=np.random.default_rng(7), options={"maxiter": 10})
    assert first.design_ids == second.design_ids and first.fun == second.fun
    assert first.nfev == 40 * 11


def test_recovers_a_chain_from_its_own_centerline():
    ids, steps = [4, 2, 1, 3], [0, 1, 0, 11]
    target = path_target(target_chain(ids, steps))
    result = solve_exact(target, design_space(small_table(), 4, allow_rotation=True), options={"max_width": 64})
    assert result.fun < 1e-6
    assert result.design_ids == tuple(ids) and result.rotation_steps == tuple(steps)


def test_stiff_positions_and_inventory_are_respected():
    target = path_target(target_chain([1, 1, 1]))  # the free optimum is three ID 1
    inventory = {1: 1, 2: 1, 4: 1, 5: 2}
    space = design_space(small_table(), 3, stiff_positions=[0], inventory=inventory)
    for result in (solve_exact(target, space, options={"max_width": None}),
                   solve_pso(target, space, rng=0, options={"maxiter": 60})):
        ids = result.design_ids
        assert small_table().rod_diameter[ids[0] - 1] >= 0.62e-3
        assert all(ids.count(i) <= inventory.get(i, 0) for i in set(ids)), ids
        assert result.fun < COLLISION_PENALTY


def test_time_budget_and_cancel_end_the_run_without_raising():
    target = path_target(target_chain([1, 2, 3, 4])[::2])
    space = design_space(small_table(), 4, allow_rotation=True)
    late = solve_exact(target, space, time_budget=1e-9)
    assert not late.success and late.status == Status.TIME_BUDGET and "time budget" in late.message

    def cancel(progress):
        assert 0.0 <= progress.fraction <= 1.0
        raise StopIteration

    for result in (solve_exact(target, space, callback=cancel), solve_pso(target, space, rng=0, callback=cancel)):
        assert not result.success and result.status == Status.CANCELED and "canceled" in result.message


@pytest.mark.parametrize(
    "kwargs, problem",
    [
        ({"num_blocks": 0}, "num_blocks"),
        ({"num_blocks": 21}, "num_blocks"),
        ({"num_blocks": 2, "stiff_positions": [2]}, "stiff_positions"),
        ({"num_blocks": 2, "inventory": {99: 3}}, "unknown design IDs"),
        ({"num_blocks": 3, "inventory": {1: 2}}, "fewer than num_blocks"),
        ({"num_blocks": 2, "stiff_positions": [0, 1], "inventory": {1: 5, 4: 1}}, "stiff"),
    ],
)
def test_design_space_rejects_bad_constraints(kwargs, problem):
    n = kwargs.pop("num_blocks")
    with pytest.raises(ValueError, match=problem):
        design_space(small_table(), n, **kwargs)


def test_bad_options_are_rejected():
    target = path_target(target_chain([1, 2]))
    space = design_space(small_table(), 2)
    with pytest.raises(ValueError, match="unknown keys"):
        solve_pso(target, space, options={"swarm": 3})
    with pytest.raises(ValueError, match="swarm_size"):
        solve_pso(target, space, options={"swarm_size": 0})
    with pytest.raises(ValueError, match="growth"):
        solve_exact(target, space, options={"growth": 1})
    with pytest.raises(ValueError, match="time_budget"):
        solve_exact(target, space, time_budget=-1.0)


def test_beam_keeps_the_global_best_and_the_best_of_every_base():
    rank = np.array([0.1, 0.2, 0.3, 0.4, 5.0, 6.0, 7.0, 8.0, 0.5, 9.0])
    base = np.array([0, 0, 0, 0, 1, 1, 1, 1, 0, 2])
    fields = {name: np.zeros(len(rank)) for name in _Prefixes.__dataclass_fields__}
    prefixes = _Prefixes(**(fields | {"rank": rank, "base": base, "counts": None, "stiff_counts": None}))
    keep = _beam(prefixes, width=3, bases=3)
    # global top 3 all come from base 0; bases 1 and 2 still keep their best (width // bases = 1)
    assert np.flatnonzero(keep).tolist() == [0, 1, 2, 4, 9]
    assert _beam(prefixes, width=20, bases=3).all()
