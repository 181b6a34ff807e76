"""The assembly-state node adds the per-block calibration file's offsets to its predictions: by serial, a
client's non-zero offset winning over the file's, a block calibrated as another design refused."""
import pytest
import rclpy
import yaml
from rclpy.parameter import Parameter
from ros_testing import Inbox, call
from softblock_interfaces.msg import AssemblyState
from softblock_interfaces.srv import SetAssembly

from planner.assembly import Assembly, Chain, PlacedBlock
from planner.table import load_table
from softblock_ros.assembly_state_node import AssemblyStateNode
from softblock_ros.conversions import assembly_msg

FILE_OFFSET = 0.03  # [rad]


@pytest.fixture(scope="module")
def client(ros_context, spin, tmp_path_factory):
    path = tmp_path_factory.mktemp("calibration") / "block_calibration.yaml"
    path.write_text(yaml.safe_dump({"blocks": {"B-1": {"design_id": 15, "offset_rad": FILE_OFFSET},
                                               "B-2": {"design_id": 8, "offset_rad": 0.01}}}))
    node = AssemblyStateNode(context=ros_context, parameter_overrides=[
        Parameter("publish_rate_hz", value=50.0), Parameter("block_calibration_file", value=str(path))])
    client = rclpy.create_node("assembly_calibration_test_client", context=ros_context)
    spin(node, client)
    return client


def set_chain(client, *blocks, sent=None):
    assembly = Assembly("rig", (Chain("rig", "front", blocks),))
    message = assembly_msg(assembly, load_table(), sent)
    return call(client.create_client(SetAssembly, "assembly/set"), SetAssembly.Request(assembly=message))


def predicted(client):
    state = Inbox(client, AssemblyState, "assembly/state").wait(lambda s: s.assembly_name == "rig")
    return list(state.chains[0].block_angles)


def test_the_files_offsets_are_added_to_the_predicted_angles_by_serial(client):
    reply = set_chain(client, PlacedBlock(15, 0, "B-1"), PlacedBlock(15, 0, "unlisted"), PlacedBlock(15))
    assert reply.success, reply.message
    theta0 = load_table().design(15).theta0
    assert predicted(client) == pytest.approx([theta0 + FILE_OFFSET, theta0, theta0])


def test_an_offset_sent_with_the_assembly_wins_over_the_files(client):
    reply = set_chain(client, PlacedBlock(15, 0, "B-1"), PlacedBlock(15), sent={"B-1": -0.02})
    assert reply.success, reply.message
    theta0 = load_table().design(15).theta0
    assert predicted(client) == pytest.approx([theta0 - 0.02, theta0])


def test_a_block_the_file_knows_as_another_design_is_refused(client):
    reply = set_chain(client, PlacedBlock(15, 0, "B-2"))
    assert not reply.success
    assert "'B-2' is calibrated as design 8, not 15" in reply.message
