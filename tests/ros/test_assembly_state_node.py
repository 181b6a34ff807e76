"""Assembly-state node through real rclpy clients: latched assembly and safe voltage, predicted state
following a (fake) hv/state publisher, markers, and SetAssembly accepting a good and refusing bad ones."""
import itertools
import math

import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile
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

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
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
])
def test_set_assembly_refuses_an_invalid_one_and_keeps_the_old(ros_context, spin, client, table, edit, problem):
    message = assembly_msg(trunk(PlacedBlock(15), PlacedBlock(15)), table)
    edit(message)
    reply = set_assembly(client, message)
    assert not reply.success
    assert problem in reply.message
    current = late_joiner_inbox(ros_context, spin, Assembly, "assembly/current").wait()
    assert current.name == "gripper"


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
