"""softblock_ros.conversions and softblock_ros.markers without ROS running: messages <-> planner data."""
import math

import numpy as np
import pytest
from geometry_msgs.msg import Point
from softblock_interfaces.msg import Assembly as AssemblyMsg
from softblock_interfaces.msg import HvChannelState, HvState
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

from planner.assembly import Assembly, Chain, PlacedBlock, load_assembly
from planner.kinematics import assembly_centerlines
from planner.table import load_table
from softblock_ros.conversions import (
    BLOCK_DESIGN_FIELDS,
    assembly_from_msg,
    assembly_msg,
    block_design_msg,
    channel_voltages,
    designed_chain_msg,
    image_msg,
    inventory_from_lists,
    mask_from_image,
    path_from_points,
    safe_voltage,
)
from softblock_ros.markers import INVALID_COLOR, assembly_markers
from softblock_ros.paths import resolve_path

pytestmark = pytest.mark.fast

TABLE = load_table()
GRIPPER = load_assembly(resolve_path("config/assemblies/gripper.yaml"))


def test_block_design_carries_the_table_row():
    design = block_design_msg(TABLE, 57)
    row = TABLE.design(57)
    assert design.id == 57
    for name in BLOCK_DESIGN_FIELDS:
        assert getattr(design, name) == pytest.approx(getattr(row, name)), name


def test_assembly_round_trips_with_rotations_and_calibration():
    chain = Chain("arm", "front", (PlacedBlock(15, 3, "S-1"), PlacedBlock(40, 0)), (0.01, 0.0, -0.02),
                  (0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
    assembly = Assembly("test", (chain, *GRIPPER.chains))
    message = assembly_msg(assembly, TABLE, {"S-1": -0.02})
    assert message.chains[0].blocks[0].rotation == pytest.approx(math.pi / 2)
    assert message.chains[0].blocks[0].calibration_offset == -0.02
    back, calibration = assembly_from_msg(message, TABLE)
    assert back == assembly
    assert calibration == {"S-1": -0.02}


def edited_gripper(edit) -> AssemblyMsg:
    message = assembly_msg(GRIPPER, TABLE)
    edit(message)
    return message


@pytest.mark.parametrize("edit, problem", [
    (lambda m: setattr(m.chains[1].blocks[2].design, "id", 85), "chain 'front_right', block 2: unknown design ID 85"),
    (lambda m: setattr(m.chains[1].blocks[2].design, "id", 0), "chain 'front_right': design_id must be a positive"),
    (lambda m: setattr(m.chains[0].blocks[1], "rotation", math.radians(45)), "chain 'front_left': rotation"),
    (lambda m: setattr(m.chains[0].blocks[1], "rotation", math.nan), "not a multiple of 30 degrees"),
    (lambda m: setattr(m.chains[3], "blocks", []), "chain 'back_right' has no blocks"),
    (lambda m: setattr(m.chains[0], "name", ""), "chain name must not be empty"),
    (lambda m: setattr(m.chains[0].base_pose.orientation, "w", 2.0), "unit quaternion"),
    (lambda m: setattr(m.chains[1], "name", "front_left"), "duplicate chain names ['front_left']"),
    (lambda m: setattr(m, "chains", []), "assembly 'gripper' has no chains"),
])
def test_invalid_assemblies_are_refused_naming_the_problem(edit, problem):
    with pytest.raises(ValueError) as refused:
        assembly_from_msg(edited_gripper(edit), TABLE)
    assert problem in str(refused.value)


def test_safe_voltage_is_the_lowest_over_all_blocks():
    trunk = Assembly("t", (Chain("a", "front", (PlacedBlock(1), PlacedBlock(84))),))
    assert safe_voltage(trunk, TABLE) == min(TABLE.design(1).safe_voltage, TABLE.design(84).safe_voltage)


def test_designed_chain_places_blocks_by_id_and_rotation_steps():
    chain = designed_chain_msg("path", [5, 6, 7], TABLE, rotation_steps=[0, 2, 11])
    assert [b.design.id for b in chain.blocks] == [5, 6, 7]
    assert [b.rotation for b in chain.blocks] == pytest.approx([0.0, math.pi / 3, 11 * math.pi / 6])
    assert chain.base_pose.orientation.w == 1.0
    with pytest.raises(ValueError):
        designed_chain_msg("path", [5, 6], TABLE, rotation_steps=[0])


def test_mask_round_trips_through_an_image_and_honours_row_padding():
    mask = np.zeros((4, 5), dtype=np.uint8)
    mask[1:3, 1:4] = 255
    np.testing.assert_array_equal(mask_from_image(image_msg(mask)), mask)
    padded = image_msg(np.pad(mask, ((0, 0), (0, 3))))
    padded.width = 5  # 3 bytes of padding at the end of every row
    np.testing.assert_array_equal(mask_from_image(padded), mask)


def test_image_with_wrong_encoding_or_size_is_refused():
    image = image_msg(np.zeros((3, 3), dtype=np.uint8))
    image.encoding = "rgb8"
    with pytest.raises(ValueError, match="image encoding must be mono8, got 'rgb8'"):
        mask_from_image(image)
    truncated = image_msg(np.zeros((3, 3), dtype=np.uint8))
    truncated.data = truncated.data[:-1]
    with pytest.raises(ValueError, match="image data has 8 bytes, expected height 3 x step 3"):
        mask_from_image(truncated)


def test_path_points_become_an_array_and_nan_is_refused():
    points = [Point(x=0.0, y=0.0, z=0.0), Point(x=0.001, y=0.0, z=0.02)]
    np.testing.assert_array_equal(path_from_points(points), [[0, 0, 0], [0.001, 0, 0.02]])
    assert path_from_points([]).shape == (0, 3)
    with pytest.raises(ValueError, match=r"path point 1 is not finite: \[0.0, nan, 0.0\]"):
        path_from_points([Point(), Point(y=math.nan)])


def test_channel_voltages_clamp_readback_noise_and_skip_missing_readings():
    state = HvState(channels=[HvChannelState(name="front", measured_voltage=-2.5),
                              HvChannelState(name="back", measured_voltage=math.nan),
                              HvChannelState(name="aux", measured_voltage=1200.0)])
    assert channel_voltages(state) == {"front": 0.0, "aux": 1200.0}


def test_inventory_lists_become_a_mapping():
    assert inventory_from_lists([], []) is None
    assert inventory_from_lists([57, 15, 57], [2, 4, 1]) == {57: 3, 15: 4}
    with pytest.raises(ValueError, match="inventory_ids has 2 entries but inventory_counts has 1"):
        inventory_from_lists([57, 15], [2])


def test_markers_draw_each_block_and_flag_blocks_beyond_their_safe_voltage():
    # just above the lowest safe voltage of the front chain's blocks, below the highest
    safe = [float(TABLE.design(i).safe_voltage) for i in GRIPPER.chains[0].design_ids]
    beyond = min(safe) + 1.0
    assert beyond < max(safe)
    shapes = assembly_centerlines(GRIPPER, TABLE, {"front": beyond})
    markers = assembly_markers(GRIPPER, shapes, TABLE, Header(frame_id="gripper_base")).markers
    assert markers[0].action == Marker.DELETEALL
    front_left = [m for m in markers if m.ns == "front_left"]
    assert [m.id for m in front_left] == [0, 1, 2, 3]
    assert [m.color == INVALID_COLOR for m in front_left] == [limit < beyond for limit in safe]
    samples = shapes["front_left"].samples_per_block
    assert front_left[3].points[-1].z == pytest.approx(shapes["front_left"].points[-1][2])
    assert all(len(m.points) == samples + 1 for m in front_left)
