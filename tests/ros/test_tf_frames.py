"""The chains in TF: the frames on /tf and /tf_static compose back to planner.kinematics' frames, /tf_static
reaches a late joiner, and a recording carries TFMessage as mcap-ros2-support reads it back."""
import numpy as np
import pytest
import rclpy
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.parameter import Parameter
from ros_testing import Inbox, wait_for
from scipy.spatial.transform import Rotation
from softblock_interfaces.msg import HvChannelState, HvState
from tf2_msgs.msg import TFMessage
from tf_testing import in_root

from planner.assembly import load_assembly
from planner.frames import link_transforms
from planner.kinematics import assembly_centerlines
from planner.table import load_table
from softblock_ros.assembly_state_node import AssemblyStateNode
from softblock_ros.paths import resolve_path
from softblock_ros.qos import LATCHED
from softblock_ros.recording.recorder_node import RecorderNode
from softblock_ros.tf_frames import ESTIMATED_PREFIX, blocks_msg, chain_frame, mounts_msg

GRIPPER = load_assembly(resolve_path("config/assemblies/gripper.yaml"))
ROOT = "gripper_base"  # assembly_state's frame_id
VOLTAGES = {"front": 1800.0, "back": 600.0}


def test_link_transforms_compose_back_to_the_frames():
    rng = np.random.default_rng(3)
    rotations = Rotation.random(6, random_state=4).as_matrix()
    positions = rng.normal(size=(6, 3))
    relative, translations = link_transforms(rotations, positions)
    frame_rotation, frame_position = rotations[0], positions[0]
    for k in range(5):
        frame_position = frame_position + frame_rotation @ translations[k]
        frame_rotation = frame_rotation @ relative[k]
        np.testing.assert_allclose(frame_rotation, rotations[k + 1], atol=1e-12)
        np.testing.assert_allclose(frame_position, positions[k + 1], atol=1e-12)


def test_the_tf_frames_of_the_gripper_match_the_planners_kinematics():
    shapes = assembly_centerlines(GRIPPER, load_table(), VOLTAGES)
    frames = in_root(mounts_msg(GRIPPER.chains, ROOT).transforms + blocks_msg(shapes).transforms, ROOT)
    assert len(frames) == sum(len(chain.blocks) + 1 for chain in GRIPPER.chains)
    for chain in GRIPPER.chains:
        shape = shapes[chain.name]
        for k in range(len(chain.blocks) + 1):
            frame = frames[chain_frame(chain.name, k)]
            np.testing.assert_allclose(frame[:3, 3], shape.positions[k], atol=1e-12)
            np.testing.assert_allclose(frame[:3, :3], shape.rotations[k], atol=1e-12)
    # the tip of the front left finger moves with its channel's voltage
    tip = chain_frame("front_left", len(GRIPPER.chains[0].blocks))
    at_rest = in_root(mounts_msg(GRIPPER.chains, ROOT).transforms
                      + blocks_msg(assembly_centerlines(GRIPPER, load_table(), {})).transforms, ROOT)
    assert np.linalg.norm(at_rest[tip][:3, 3] - frames[tip][:3, 3]) > 1e-3


def test_the_estimated_frames_have_their_own_prefix():
    shapes = assembly_centerlines(GRIPPER, load_table(), {})
    names = {t.child_frame_id for t in blocks_msg(shapes, ESTIMATED_PREFIX).transforms}
    assert names and all(name.startswith(ESTIMATED_PREFIX) for name in names)
    assert chain_frame("front_left", 0, ESTIMATED_PREFIX) == "estimated/front_left/base"


@pytest.fixture(scope="module")
def recording(ros_context, spin, tmp_path_factory):
    """assembly_state publishing, and a recorder of /tf and /tf_static beside it."""
    path = tmp_path_factory.mktemp("tf") / "tf.mcap"
    node = AssemblyStateNode(context=ros_context, parameter_overrides=[Parameter("publish_rate_hz", value=20.0)])
    recorder = RecorderNode(output=str(path), topics=["/tf", "/tf_static"], context=ros_context)
    client = rclpy.create_node("tf_test_client", context=ros_context)
    spin(node, recorder, client)
    return path, recorder, client


def test_a_late_joiner_receives_the_mounts_on_tf_static(ros_context, spin, recording):
    late = rclpy.create_node("tf_static_late_joiner", context=ros_context)
    inbox = Inbox(late, TFMessage, "/tf_static", LATCHED)
    spin(late)
    mounts = inbox.wait()
    assert {t.child_frame_id for t in mounts.transforms} == {chain_frame(c.name, 0) for c in GRIPPER.chains}
    assert {t.header.frame_id for t in mounts.transforms} == {ROOT}


def test_tf_follows_the_measured_voltage(recording):
    _, _, client = recording
    inbox = Inbox(client, TFMessage, "/tf")
    hv = client.create_publisher(HvState, "hv/state", 10)
    tip = chain_frame("front_left", len(GRIPPER.chains[0].blocks))
    shapes = assembly_centerlines(GRIPPER, load_table(), {"front": 1800.0})

    def at_voltage(message):
        hv.publish(HvState(channels=[HvChannelState(name="front", measured_voltage=1800.0)]))
        frames = in_root(list(mounts_msg(GRIPPER.chains, ROOT).transforms) + list(message.transforms), ROOT)
        return np.allclose(frames[tip][:3, 3], shapes["front_left"].positions[-1], atol=1e-9)

    assert inbox.wait(at_voltage)


def test_the_recording_carries_tf_as_mcap_ros2_support_reads_it(recording):
    path, recorder, _ = recording
    wait_for(lambda: recorder.recorded_topics == ["/tf", "/tf_static"], what="the recorder on /tf and /tf_static")
    wait_for(lambda: recorder.writer.message_counts.get("/tf", 0) >= 3, what="three /tf messages recorded")
    recorder.close_recording()
    with open(path, "rb") as stream:
        decoded = list(make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    by_topic = {}
    for schema, channel, _, message in decoded:
        assert schema.name == "tf2_msgs/msg/TFMessage"
        by_topic.setdefault(channel.topic, []).append(message)
    assert {t.child_frame_id for t in by_topic["/tf_static"][0].transforms} == {
        chain_frame(c.name, 0) for c in GRIPPER.chains}
    blocks = {t.child_frame_id for t in by_topic["/tf"][-1].transforms}
    assert chain_frame("back_right", len(GRIPPER.chains[-1].blocks)) in blocks
