"""Streams a recorder reads reliably keep REPAIR_HISTORY_S of samples, so a sample dropped on the way (a loaded
host's full socket or shared-memory port, a lossy link) can still be sent again at the writer's next periodic
heartbeat. A fresh-clone run of the demo lost 2 /arm/pose samples while the arm kept 10 (0.2 s at 50 Hz)."""
import math

import pytest
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy

from softblock_ros.assembly_state_node import AssemblyStateNode
from softblock_ros.hv_driver_node import HvDriverNode
from softblock_ros.qos import LATCHED, REPAIR_HISTORY_S, stream_qos
from softblock_ros.sim_arm_node import SimArmNode
from softblock_ros.sim_camera_node import SimCameraNode

pytestmark = pytest.mark.integration


def publisher_profile(node, topic: str):
    return next(p.qos_profile for p in node.publishers if p.topic_name == topic)


def assert_repairable(profile, rate_hz: float) -> None:
    assert profile.reliability == ReliabilityPolicy.RELIABLE
    assert profile.history == HistoryPolicy.KEEP_LAST
    assert profile.depth >= math.ceil(REPAIR_HISTORY_S * rate_hz), \
        f"depth {profile.depth} holds {profile.depth / rate_hz:.2f} s at {rate_hz:g} Hz"


@pytest.mark.parametrize("rate_hz, depth", [(50.0, 400), (0.1, 1), (1000.0, 8000)])
def test_a_stream_keeps_the_repair_window_at_its_rate(rate_hz, depth):
    profile = stream_qos(rate_hz)
    assert profile.depth == depth
    assert profile.durability == DurabilityPolicy.VOLATILE and profile.reliability == ReliabilityPolicy.RELIABLE


def test_latched_keeps_the_newest_value_for_late_readers():
    assert LATCHED.depth == 1 and LATCHED.durability == DurabilityPolicy.TRANSIENT_LOCAL


# (node, its rate parameter, the stream's topic, a rate): the camera's depth of 1 lost one of the demo's images to a
# recorder starved under load
RATE_STREAMS = [(SimArmNode, "publish_rate_hz", "/arm/pose", rate) for rate in (50.0, 200.0)] + \
               [(SimCameraNode, "rate_hz", "/camera/silhouette", rate) for rate in (1.0, 5.0)]


@pytest.mark.parametrize("node_type, rate_parameter, topic, rate_hz", RATE_STREAMS)
def test_a_stream_at_its_node_rate_keeps_the_repair_window(ros_context, node_type, rate_parameter, topic, rate_hz):
    node = node_type(context=ros_context, parameter_overrides=[Parameter(rate_parameter, value=rate_hz)])
    try:
        assert_repairable(publisher_profile(node, topic), rate_hz)
    finally:
        node.destroy_node()


def test_the_assembly_streams_keep_the_repair_window(ros_context):
    node = AssemblyStateNode(context=ros_context, parameter_overrides=[Parameter("publish_rate_hz", value=10.0)])
    try:
        for topic in ("/assembly/state", "/assembly/markers"):
            assert_repairable(publisher_profile(node, topic), 10.0)
    finally:
        node.destroy_node()


def test_the_hv_state_stream_keeps_the_repair_window(ros_context):
    node = HvDriverNode(context=ros_context, parameter_overrides=[Parameter("publish_rate_hz", value=50.0)])
    try:
        assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
        assert_repairable(publisher_profile(node, "/hv/state"), 50.0)
        assert node.trigger_cleanup() == TransitionCallbackReturn.SUCCESS
    finally:
        node.destroy_node()
