import math
from pathlib import Path

import pytest

from planner.assembly import (
    Assembly, Chain, PlacedBlock, assembly_from_dict, assembly_to_dict, load_assembly, save_assembly,
)

pytestmark = pytest.mark.fast

CONFIG = Path(__file__).resolve().parents[2] / "config" / "assemblies"


def test_gripper_yaml_loads_with_two_channels():
    gripper = load_assembly(CONFIG / "gripper.yaml")
    assert gripper.hv_channels == ("front", "back")
    assert [len(c.blocks) for c in gripper.chains] == [4, 4, 5, 5]
    assert gripper.chain("back_left").design_ids[:3] == (57, 57, 57)


def test_round_trip_through_yaml(tmp_path):
    gripper = load_assembly(CONFIG / "gripper.yaml")
    save_assembly(gripper, tmp_path / "copy.yaml")
    assert load_assembly(tmp_path / "copy.yaml") == gripper
    assert assembly_from_dict(assembly_to_dict(gripper)) == gripper


def test_rotation_steps_are_snap_fits():
    assert PlacedBlock(15, rotation_steps=1).rotation == pytest.approx(math.pi / 6)
    assert PlacedBlock.steps_from_rotation(math.pi) == 6
    assert PlacedBlock.steps_from_rotation(-math.pi / 6) == 11
    with pytest.raises(ValueError, match="multiple of 30"):
        PlacedBlock.steps_from_rotation(0.3)
    with pytest.raises(ValueError, match="rotation_steps"):
        PlacedBlock(15, rotation_steps=12)


@pytest.mark.parametrize(
    "data, message",
    [
        ({"name": "x"}, "'name' and 'chains'"),
        ({"name": "x", "chains": [{"name": "a", "blocks": [{"id": 1}]}]}, "chain 'a': missing key 'hv_channel'"),
        ({"name": "x", "chains": [{"name": "a", "hv_channel": "c", "blocks": []}]}, "has no blocks"),
        ({"name": "x", "chains": [{"name": "a", "hv_channel": "c", "blocks": [{"id": 0}]}]}, "design_id"),
        (
            {"name": "x", "chains": [{"name": "a", "hv_channel": "c", "blocks": [{"id": 1}],
                                      "base_orientation": [0, 0, 0, 2]}]},
            "unit quaternion",
        ),
        ({"name": "x", "chains": [{"name": "a", "hv_channel": "c", "blocks": [{"id": True}]}]},
         "chain 'a': design_id must be a positive integer, got True"),
        ({"name": "x", "chains": [{"name": "a", "hv_channel": "c", "blocks": [{"id": 1, "rotation_steps": True}]}]},
         "chain 'a': rotation_steps must be an integer 0..11, got True"),
        ({"name": "x", "chains": [{"name": "a", "hv_channel": "c",
                                   "blocks": [{"id": 1}, {"id": 2, "rotaton_steps": 3}]}]},
         r"chain 'a': block 1: unknown key\(s\) \['rotaton_steps'\]; allowed: \['id', 'rotation_steps', 'serial'\]"),
        ({"name": "x", "chains": [{"name": "a", "hv_chanel": "c", "blocks": [{"id": 1}]}]},
         r"chain 'a': unknown key\(s\) \['hv_chanel'\]"),
        ({"name": "x", "chains": [], "colour": "red"}, r"assembly: unknown key\(s\) \['colour'\]"),
        ({"name": "x", "chains": ["a"]}, "chain 0: expected a mapping"),
        ({"name": "x", "chains": [{"name": "a", "hv_channel": "c", "blocks": 5}]}, "'blocks' must be a list"),
    ],
)
def test_bad_assemblies_name_the_problem(data, message):
    with pytest.raises(ValueError, match=message):
        assembly_from_dict(data)


def test_duplicate_chain_names_rejected():
    chain = Chain("a", "c", (PlacedBlock(1),))
    with pytest.raises(ValueError, match="duplicate chain names"):
        Assembly("x", (chain, chain))


def test_with_chains_replaces_by_name():
    gripper = load_assembly(CONFIG / "gripper.yaml")
    new_front = Chain("front_left", "front", (PlacedBlock(57), PlacedBlock(57), PlacedBlock(15), PlacedBlock(15)))
    updated = gripper.with_chains(new_front)
    assert updated.chain("front_left").design_ids == (57, 57, 15, 15)
    assert [c.name for c in updated.chains] == [c.name for c in gripper.chains]


def test_unreadable_file_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="cannot read assembly file"):
        load_assembly(tmp_path / "missing.yaml")
