"""Assembly-state node through real rclpy clients: latched assembly and safe voltage, predicted state
following a (fake) hv/state publisher, markers, and SetAssembly accepting a good and refusing bad ones."""
import itertools
import math

import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from ros_testing import Inbox, call, wait_for
from softblock_interfaces.msg import Assembly, AssemblyState, HvChannelState, HvState
from softblock_interfaces.srv import SetAssembly
from std_msgs.msg import Float64
from visualization_msgs.msg import Marker, MarkerArray

from planner.assembly import Assembly as CoreAssembly
from planner.assembly import Chain, PlacedBlock, load_assembly
from planner.table import load_table
from softblock_ros.assembly_state_node import AssemblyStateNode
from softblock_ros.conversions import assembly_msg
from softblock_ros.paths import resolve_path
from softblock_ros.qos import LATCHED

pytestmark = pytest.mark.integration

LATE_JOINERS = itertools.count()
GRIPPER = load_assembly(resolve_path("config/assemblies/gripper.yaml"))


@pytest.fixture(scope="module")
def table():
    return load_table()


@pytest.fixture(scope="module")
def client(ros_context, spin):
    node = AssemblyStateNode(context=ros_context, parameter_overrides=[Parameter("publish_rate_hz", value=50.0)])
    client = rclpy.create_node("assembly_state_test_client", context=ros_context)
    spin(node, client)
    return client


def set_assembly(client, message):
    return call(client.create_client(SetAssembly, "assembly/set"), SetAssembly.Request(assembly=message))


def late_joiner_inbox(ros_context, spin, msg_type, topic):
    """A subscriber on a fresh node, created after the latched message was published."""
    node = rclpy.create_node(f"late_joiner_{next(LATE_JOINERS)}", context=ros_context)
    inbox = Inbox(node, msg_type, topic, LATCHED)
    spin(node)
    return inbox


def test_late_joiner_receives_the_latched_assembly_with_table_designs(ros_context, spin, client, table):
    current = late_joiner_inbox(ros_context, spin, Assembly, "assembly/current").wait()
    assert current.name == "gripper"
    assert current.header.frame_id == "gripper_base"
    assert [c.name for c in current.chains] == [c.name for c in GRIPPER.chains]
    top = current.chains[0].blocks[0].design
    assert top.id == 57
    assert top.rod_diameter == pytest.approx(table.design(57).rod_diameter)
    assert top.safe_voltage == pytest.approx(table.design(57).safe_voltage)


def test_safe_voltage_is_latched_and_the_lowest_over_the_blocks(ros_context, spin, client, table):
    latched = late_joiner_inbox(ros_context, spin, Float64, "assembly/safe_voltage").wait()
    ids = {i for chain in GRIPPER.chains for i in chain.design_ids}
    assert latched.data == pytest.approx(min(table.design(i).safe_voltage for i in ids))


def test_predicted_angles_follow_the_measured_channel_voltage(client, table):
    states = Inbox(client, AssemblyState, "assembly/state")
    at_rest = states.wait()
    front = next(c for c in at_rest.chains if c.name == "front_left")
    assert front.voltage == 0.0
    np.testing.assert_allclose(front.block_angles, [table.design(i).theta0 for i in (57, 57, 1, 11)])
    assert len(front.centerline) > len(front.block_angles)

    hv = client.create_publisher(HvState, "hv/state", 10)
    voltage = 1000.0
    message = HvState(channels=[HvChannelState(name="front", measured_voltage=voltage)])

    def actuated_state():
        hv.publish(message)  # again until the node has discovered the publisher
        return next((s for s in reversed(states.messages) if s.chains[0].voltage == voltage), None)

    actuated = wait_for(actuated_state, what="assembly/state at the raised front voltage")
    by_name = {c.name: c for c in actuated.chains}
    expected, valid = table.angle_at([57, 57, 1, 11], voltage)
    np.testing.assert_allclose(by_name["front_right"].block_angles, expected)
    assert list(by_name["front_right"].block_valid) == valid.tolist()
    assert not np.allclose(by_name["front_right"].block_angles, front.block_angles)
    assert by_name["back_left"].voltage == 0.0  # channel "back" absent from hv/state: not actuated
    assert by_name["front_left"].centerline[-1] != front.centerline[-1]


def test_markers_draw_every_block_in_the_assembly_frame(client):
    markers = Inbox(client, MarkerArray, "assembly/markers").wait().markers
    assert markers[0].action == Marker.DELETEALL
    blocks = markers[1:]
    assert len(blocks) == sum(len(chain.blocks) for chain in GRIPPER.chains)
    assert {m.header.frame_id for m in blocks} == {"gripper_base"}
    assert {m.ns for m in blocks} == {chain.name for chain in GRIPPER.chains}
    assert all(m.type == Marker.LINE_STRIP and len(m.points) >= 2 for m in blocks)


def trunk(*blocks: PlacedBlock) -> CoreAssembly:
    return CoreAssembly("trunk", (Chain("trunk", "front", blocks),))


def test_set_assembly_replaces_and_relatches_it(ros_context, spin, client, table):
    message = assembly_msg(trunk(PlacedBlock(15, 1, "B-7"), PlacedBlock(15, 11)), table, {"B-7": 0.05})
    try:
        reply = set_assembly(client, message)
        assert reply.success, reply.message
        current = late_joiner_inbox(ros_context, spin, Assembly, "assembly/current").wait(
            lambda m: m.name == "trunk")
        blocks = current.chains[0].blocks
        assert [b.rotation for b in blocks] == pytest.approx([math.pi / 6, 11 * math.pi / 6])
        assert (blocks[0].serial, blocks[0].calibration_offset) == ("B-7", 0.05)
        states = Inbox(client, AssemblyState, "assembly/state")
        state = states.wait(lambda s: s.assembly_name == "trunk")
        predicted, _ = table.angle_at([15], state.chains[0].voltage)
        assert state.chains[0].block_angles[0] == pytest.approx(predicted[0] + 0.05)
    finally:
        assert set_assembly(client, assembly_msg(GRIPPER, table)).success


@pytest.mark.parametrize("edit, problem", [
    (lambda m: setattr(m.chains[0].blocks[1].design, "id", 99), "chain 'trunk', block 1: unknown design ID 99"),
    (lambda m: setattr(m.chains[0].blocks[0], "rotation", 0.1), "not a multiple of 30 degrees"),
    (lambda m: setattr(m.chains[0], "blocks", []), "chain 'trunk' has no blocks"),
    (lambda m: setattr(m, "chains", []), "has no chains"),
    (lambda m: setattr(m.chains[0].blocks[0], "calibration_offset", math.nan),
     "chain 'trunk', block 0: calibration_offset=nan rad: must be finite and within +-0.175 rad"),
    (lambda m: setattr(m.chains[0].blocks[0], "calibration_offset", -math.inf), "calibration_offset=-inf rad"),
    (lambda m: setattr(m.chains[0].blocks[0], "calibration_offset", 1.0), "calibration_offset=1.0 rad: must be"),
    (lambda m: setattr(m.chains[0].blocks[1], "calibration_offset", 0.05),
     "chain 'trunk', block 1: calibration_offset=0.05 rad: needs the block's serial"),
])
def test_set_assembly_refuses_an_invalid_one_and_keeps_the_old(ros_context, spin, client, table, edit, problem):
    message = assembly_msg(trunk(PlacedBlock(15, 0, "B-1"), PlacedBlock(15)), table)
    edit(message)
    reply = set_assembly(client, message)
    assert not reply.success
    assert problem in reply.message
    current = late_joiner_inbox(ros_context, spin, Assembly, "assembly/current").wait()
    assert current.name == "gripper"
    states = Inbox(client, AssemblyState, "assembly/state")
    assert states.wait().assembly_name == "gripper"  # still predicting, from the old assembly


def test_negative_readback_noise_counts_as_rest_and_the_node_carries_on(client, table):
    states = Inbox(client, AssemblyState, "assembly/state")
    hv = client.create_publisher(HvState, "hv/state", 10)

    def state_at(voltage, expected_voltage):
        message = HvState(channels=[HvChannelState(name="front", measured_voltage=voltage)])

        def matching():
            hv.publish(message)
            return next((s for s in reversed(states.messages) if s.chains[0].voltage == expected_voltage), None)
        return wait_for(matching, what=f"assembly/state after a readback of {voltage} V")

    state_at(500.0, 500.0)
    at_rest = state_at(-3.0, 0.0)
    np.testing.assert_allclose(at_rest.chains[0].block_angles, [table.design(i).theta0 for i in (57, 57, 1, 11)])
    state_at(700.0, 700.0)  # still running


@pytest.fixture
def calibrated(tmp_path):
    """An assembly with serial-numbered blocks and a calibration file for two of them."""
    assembly = tmp_path / "trunk.yaml"
    assembly.write_text("name: calibrated\nchains:\n  - {name: trunk, hv_channel: front, blocks: "
                        "[{id: 15, serial: S-1}, {id: 15, serial: S-2}, {id: 15}]}\n")
    calibration = tmp_path / "calibration.yaml"
    calibration.write_text("blocks:\n  S-1: {design_id: 15, offset_rad: 0.03}\n"
                           "  S-2: {design_id: 15, offset_rad: -0.02}\n")
    return assembly, calibration


def start_node(ros_context, spin, namespace, **parameters):
    node = AssemblyStateNode(context=ros_context, namespace=namespace, parameter_overrides=[
        Parameter(name, value=value) for name, value in {"publish_rate_hz": 50.0, **parameters}.items()])
    spin(node)
    return node


def test_the_block_calibration_file_offsets_the_predicted_angles(ros_context, spin, client, table, calibrated):
    assembly, calibration = calibrated
    start_node(ros_context, spin, "/calibrated", assembly_file=str(assembly), block_calibration=str(calibration))
    state = Inbox(client, AssemblyState, "/calibrated/assembly/state").wait()
    theta0 = table.design(15).theta0
    assert state.chains[0].block_angles == pytest.approx([theta0 + 0.03, theta0 - 0.02, theta0])
    current = late_joiner_inbox(ros_context, spin, Assembly, "/calibrated/assembly/current").wait()
    assert [b.calibration_offset for b in current.chains[0].blocks] == [0.03, -0.02, 0.0]
    # a request's own offset wins for its block; the file still holds for the other
    message = assembly_msg(trunk(PlacedBlock(15, 0, "S-1"), PlacedBlock(15, 0, "S-2")), table, {"S-1": 0.01})
    assert call(client.create_client(SetAssembly, "/calibrated/assembly/set"),
                SetAssembly.Request(assembly=message)).success
    states = Inbox(client, AssemblyState, "/calibrated/assembly/state")
    state = states.wait(lambda s: s.assembly_name == "trunk")
    assert state.chains[0].block_angles == pytest.approx([theta0 + 0.01, theta0 - 0.02])


def test_a_block_placed_as_another_design_than_calibrated_is_refused(ros_context, spin, client, table, calibrated):
    _, calibration = calibrated
    start_node(ros_context, spin, "/mismatch", block_calibration=str(calibration))
    message = assembly_msg(trunk(PlacedBlock(16, 0, "S-1")), table)
    reply = call(client.create_client(SetAssembly, "/mismatch/assembly/set"), SetAssembly.Request(assembly=message))
    assert not reply.success
    assert "chain 'trunk', block 0: block 'S-1' is calibrated as design 15, not 16" in reply.message


def test_block_calibration_defaults_to_the_config_file_and_a_missing_file_stops_the_start(ros_context, tmp_path):
    node = AssemblyStateNode(context=ros_context, namespace="/default_calibration")
    try:
        assert node.get_parameter("block_calibration").value == "block_calibration.yaml"
    finally:
        node.destroy_node()
    with pytest.raises(ValueError, match=r"block_calibration file .*none.yaml not found \(empty = no calibration\)"):
        AssemblyStateNode(context=ros_context, namespace="/missing_calibration", parameter_overrides=[
            Parameter("block_calibration", value=str(tmp_path / "none.yaml"))])


def test_an_empty_block_calibration_means_none(ros_context, spin, client, table, calibrated):
    assembly, _ = calibrated
    start_node(ros_context, spin, "/uncalibrated", assembly_file=str(assembly), block_calibration="")
    state = Inbox(client, AssemblyState, "/uncalibrated/assembly/state").wait()
    assert state.chains[0].block_angles == pytest.approx([table.design(15).theta0] * 3)
