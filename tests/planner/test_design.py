"""The paper's design cases through the high-level API (section 2.4-2.5) and its failure paths."""
import json

import numpy as np
import pytest
import yaml

from planner import design
from planner.assembly import load_assembly
from planner.cli import main as cli_main
from planner.contours import OBJECTS_CATALOG, load_mask
from planner.kinematics import chain_blocks, chain_shape
from planner.table import load_table

pytestmark = pytest.mark.fast

BUDGET = 3.0  # [s] for problems the tests do not need certified: whatever the budget, a collision-free finger


@pytest.fixture(scope="module")
def table():
    return load_table()


def sample(name):
    entry = yaml.safe_load(OBJECTS_CATALOG.read_text())[name]
    return load_mask(OBJECTS_CATALOG.parent / entry["file"]), float(entry["pixel_size_m"])


def stiff(table, ids):
    return [table.rod_diameter[table.index_of(np.array([i]))[0]] >= 0.62e-3 - 1e-12 for i in ids]


def test_asymmetric_object_gets_four_non_identical_fingers(table):
    mask, pixel = sample("asymmetric")
    front = design.design_fingers(mask, pixel, 4, num_stiff_top=2, table=table, time_budget=BUDGET)
    back = design.design_fingers(mask, pixel, 5, num_stiff_top=3, table=table, time_budget=BUDGET)
    fingers = [front.left, front.right, back.left, back.right]
    assert front.success and back.success
    assert len({f.design_ids for f in fingers}) == 4
    for finger, top in zip(fingers, (2, 2, 3, 3)):
        assert all(stiff(table, finger.design_ids[:top]))
        assert not finger.collision and finger.cost < 2.0 and finger.min_clearance_m >= -2e-6
        assert finger.lower_bound_m <= finger.cost
        assert finger.centerline.shape[1] == 2 and finger.contour.shape[1] == 2
    # fingers sit outside the object on their own side
    assert front.left.base[0] < -0.0184 < 0.0184 < front.right.base[0]


def test_gingerbread_fingers_are_stiff_and_near_identical(table):
    mask, pixel = sample("gingerbread")
    result = design.design_fingers(mask, pixel, 3, num_stiff_top=3, table=table)
    assert result.optimal and result.success
    for finger in (result.left, result.right):
        assert all(stiff(table, finger.design_ids)) and not finger.collision
        index = table.index_of(np.array(finger.design_ids))
        assert np.ptp(table.rod_diameter[index]) == 0
        # a flat slab wants straight fingers: blocks from the straightest quarter of the stiff designs
        straightest = np.percentile(table.theta0[stiff(table, table.ids)], 25)
        assert np.all(table.theta0[index] <= straightest)


@pytest.mark.parametrize("name, blocks", [("strawberry", 4), ("gingerbread", 3)])
def test_certified_exact_is_not_worse_than_pso_on_the_sample_objects(name, blocks, table):
    mask, pixel = sample(name)
    exact = design.design_fingers(mask, pixel, blocks, num_stiff_top=2, table=table)
    assert exact.optimal
    for seed in (0, 1, 2):
        pso = design.design_fingers(mask, pixel, blocks, num_stiff_top=2, method="pso", seed=seed, table=table)
        assert exact.left.cost + exact.right.cost <= pso.left.cost + pso.right.cost + 1e-9


def test_trunk_path_is_recovered(table):
    chain = load_assembly("config/assemblies/trunk.yaml").chain("trunk")
    theta, length, phi, _ = chain_blocks(chain, table)
    centerline = chain_shape(theta, length, phi).points
    path = np.vstack([centerline[:-1:3], centerline[-1:]])  # every third sample and the tip
    result = design.design_path(path, 17, table=table, options={"max_width": 8, "polish_starts": 0})
    assert result.success and len(result.design_ids) == 17
    assert result.cost < 0.01 * len(path) * 1e-3  # under 0.01 mm per path point on average
    assert result.design_ids == chain.design_ids
    assert result.rotation_steps == tuple(b.rotation_steps for b in chain.blocks)


def test_collision_is_detected(table):
    mask, pixel = sample("strawberry")
    # a single base right at the bounding box and the most bent blocks: the finger must hit the berry
    result = design.design_fingers(mask, pixel, 3, table=table, base_offsets=[0.0], inventory={21: 6})
    assert result.left.collision and result.left.cost > 1e10
    assert not result.success and "no collision-free design" in result.message


def test_shared_inventory_is_respected(table):
    mask, pixel = sample("gingerbread")
    inventory = {78: 3, 64: 2, 71: 2, 15: 4}
    result = design.design_fingers(mask, pixel, 3, num_stiff_top=1, inventory=inventory, table=table)
    used = list(result.left.design_ids) + list(result.right.design_ids)
    assert all(used.count(i) <= inventory[i] for i in set(used)), used


def test_cancel_and_time_budget_give_unsuccessful_results(table):
    mask, pixel = sample("gingerbread")
    calls = []

    def cancel_once(progress):
        calls.append(progress.fraction)
        if len(calls) == 1:
            raise StopIteration

    canceled = design.design_fingers(mask, pixel, 4, table=table, callback=cancel_once)
    assert not canceled.success and len(calls) == 1
    assert "left: canceled" in canceled.message and "right: canceled" in canceled.message
    late = design.design_path(np.array([[0, 0, 0], [0, 0, 0.05]]), 3, table=table, time_budget=1e-9)
    assert not late.success and "time budget" in late.message


@pytest.mark.parametrize("method", ["exact", "pso"])
def test_result_flags_and_numbers_are_plain_python_types(table, method):
    """ROS message fields take Python bool/float only: a numpy bool from a comparison aborted the planner
    node in the C conversion of its response."""
    for budget in (1e-9, None):
        result = design.design_path(np.array([[0, 0, 0], [0.01, 0, 0.03]]), 2, method=method, table=table,
                                    time_budget=budget)
        assert type(result.success) is bool and type(result.optimal) is bool
        assert type(result.cost) is float and type(result.lower_bound) is float


@pytest.mark.parametrize(
    "call, problem",
    [
        (lambda m, p: design.design_fingers(m, p, 0), "num_blocks"),
        (lambda m, p: design.design_fingers(m, p, 21), "num_blocks"),
        (lambda m, p: design.design_fingers(m, p, 3, method="annealing"), "method"),
        (lambda m, p: design.design_fingers(m, p, 3, num_stiff_top=4), "num_stiff_top"),
        (lambda m, p: design.design_fingers(m, p, 3, inventory={57: 5}), "two fingers need 6"),
        (lambda m, p: design.design_fingers(m, -1.0, 3), "pixel_size"),
        (lambda m, p: design.design_fingers(m, p, 3, contact_tolerance_m=-1e-3), "contact_tolerance_m"),
        (lambda m, p: design.design_fingers(m, p, 3, options={"max_width": 4}), "unknown keys"),
        (lambda m, p: design.design_path(np.array([[0, 0, 0], [np.nan, 0, 1]]), 3), "NaN"),
        (lambda m, p: design.design_path(np.zeros((4, 2)), 3), "path"),
        (lambda m, p: design.design_path(np.zeros((4, 3)), 3, method="x"), "method"),
    ],
)
def test_bad_requests_name_the_problem(call, problem):
    mask, pixel = sample("gingerbread")
    with pytest.raises(ValueError, match=problem):
        call(mask, pixel)


def test_cli_design_finger_and_path(tmp_path, capsys):
    out = tmp_path / "fingers.json"
    png = tmp_path / "fingers.png"
    code = cli_main(["design-finger", "gingerbread", "--blocks", "3", "--stiff-top", "3", "--method", "pso",
                     "--json", str(out), "--png", str(png)])
    report = json.loads(out.read_text())
    assert code == 0 and report["success"] and png.stat().st_size > 0
    assert len(report["left"]["design_ids"]) == 3 and isinstance(report["right"]["collision"], bool)
    centerline = np.array(report["left"]["centerline_m"])
    assert centerline.shape == (31, 2) and np.allclose(centerline[0], report["left"]["base_m"])
    assert report["left"]["min_clearance_m"] >= -2e-6 and report["contact_tolerance_m"] == 0.0
    points = tmp_path / "path.csv"
    points.write_text("x,y,z\n0,0,0\n0.002,0,0.02\n0.008,0.001,0.04\n")
    assembly = tmp_path / "chain.yaml"
    code = cli_main(["design-path", str(points), "--blocks", "2", "--yaml", str(assembly),
                     "--json", str(tmp_path / "path.json")])
    assert code == 0 and len(load_assembly(assembly).chain("path").blocks) == 2
    assert "progress" not in capsys.readouterr().out
