"""Reconfiguration toward a 3D path (a trunk): every swap budget against brute force over the shelf's and the
chain's blocks at every rotation, steps that rebuild the chain, bad input named."""
import numpy as np
import pytest

from planner.assembly import Assembly, Chain, PlacedBlock
from planner.optimize import Status
from planner.reconfigure import swap_steps
from planner.reconfigure_path import plan_path_reconfiguration
from reconfigure_brute import path_brute_force

pytestmark = pytest.mark.fast


def trunk(*blocks) -> Assembly:
    return Assembly("trunk", (Chain("trunk", "main", tuple(PlacedBlock(i, r) for i, r in blocks)),
                              Chain("other", "main", (PlacedBlock(5),))))


def helix(turn: float, rise: float, points: int = 12) -> np.ndarray:
    t = np.linspace(0.0, 1.0, points)
    radius = 0.012
    return np.stack([radius * (1 - np.cos(turn * t)), radius * np.sin(turn * t), rise * t], axis=1)


@pytest.mark.parametrize("blocks, shelf, path", [
    (((22, 0), (40, 3)), {13: 1, 64: 1}, helix(2.0, 0.045)),
    (((40, 0), (40, 0)), {19: 1}, helix(-1.5, 0.05)),
    (((64, 6), (22, 0), (13, 2)), {40: 1}, helix(2.5, 0.07)),
])
def test_path_plan_equals_brute_force_and_its_steps_rebuild_it(blocks, shelf, path):
    built = trunk(*blocks)
    result = plan_path_reconfiguration(built, "trunk", shelf, path)
    expected = path_brute_force(built.chain("trunk"), shelf, path)
    assert result.status == Status.CERTIFIED and result.success
    for point, best in zip(result.points, expected):
        assert point.optimal and point.objective == pytest.approx(best, abs=1e-9), point.max_swaps
        assert point.swaps <= point.max_swaps
        steps = swap_steps(built, point.assembly, shelf)
        assert len(steps) >= point.swaps
        if steps:
            assert steps[-1].assembly == point.assembly
        assert point.assembly.chain("other") == built.chain("other")
    assert result.points[0].swaps == 0 and result.points[0].assembly == built


def test_a_stopped_path_plan_keeps_proven_bounds():
    built = trunk((22, 0), (40, 3), (13, 0))
    def cancel(progress):
        raise StopIteration

    result = plan_path_reconfiguration(built, "trunk", {64: 1, 19: 1}, helix(2.0, 0.06), callback=cancel)
    expected = path_brute_force(built.chain("trunk"), {64: 1, 19: 1}, helix(2.0, 0.06))
    assert result.status == Status.CANCELED and "canceled" in result.message
    for point, best in zip(result.points, expected):
        assert point.lower_bound <= best + 1e-9 <= point.objective + 2e-9


@pytest.mark.parametrize("change, match", [
    (dict(chain="arm"), "no chain 'arm'"),
    (dict(shelf={999: 1}), "999 is not a design ID"),
    (dict(path=np.zeros((1, 3))), r"path must be an \(n, 3\) array"),
    (dict(path=np.full((3, 3), np.nan)), "NaN"),
    (dict(time_budget=-1.0), "time_budget"),
])
def test_bad_path_plan_input_is_named(change, match):
    arguments = dict(chain="trunk", shelf={}, path=helix(1.0, 0.04)) | change
    with pytest.raises(ValueError, match=match):
        plan_path_reconfiguration(trunk((22, 0), (40, 0)), arguments.pop("chain"), arguments.pop("shelf"),
                                  arguments.pop("path"), **arguments)
