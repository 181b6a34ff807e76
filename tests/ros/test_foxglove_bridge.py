"""The live view through a Foxglove WebSocket client (protocol foxglove.sdk.v1, on 127.0.0.1 only): the
stack's topics advertised with the schemas a recording holds, a subscription receiving hv/state, the latched
mounts reaching a late viewer (the last sample of each publisher, to that viewer only), a taken port refused by
name, and the shipped layout reading served topics."""
import inspect
import json
import struct
from contextlib import contextmanager

import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from ros_testing import wait_for
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import Image
from softblock_interfaces.msg import AssemblyState, HvChannelState, HvHeartbeat, HvState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from foxglove.websocket import ServerListener
from websockets.sync.client import connect

from recording.message_definitions import full_definition
from softblock_ros import foxglove_layout
from softblock_ros.assembly_state_node import AssemblyStateNode
from softblock_ros.foxglove_bridge_node import LIVE_TOPICS, FoxgloveBridgeNode, _Viewers, is_loopback
from softblock_ros.qos import LATCHED

pytestmark = pytest.mark.integration

# foxglove-sdk 0.30 names the Foxglove WebSocket protocol so; it refuses foxglove.websocket.v1
SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # binary opcode of a message on a subscription
RECEIVE_TIMEOUT = 15.0  # [s] generous: the suite runs on two loaded cores
HOST = "127.0.0.1"


@pytest.fixture(scope="module")
def bridge(ros_context, spin):
    """The bridge on a free port of 127.0.0.1, assembly_state and an hv/state publisher beside it."""
    node = FoxgloveBridgeNode(context=ros_context, parameter_overrides=[
        Parameter("port", value=0), Parameter("discovery_period_s", value=0.2)])
    assembly_state = AssemblyStateNode(context=ros_context)
    publisher = rclpy.create_node("hv_state_source", context=ros_context)
    hv = publisher.create_publisher(HvState, "hv/state", 10)
    publisher.create_publisher(HvHeartbeat, "hv/heartbeat", 10)  # a topic the live view does not serve
    for msg_type, topic in ((DiagnosticArray, "/diagnostics"), (Image, "camera/silhouette"),
                            (AssemblyState, "assembly/estimated")):  # the estimator's and the camera's
        publisher.create_publisher(msg_type, topic, 10)
    state = HvState(backend="sim", channels=[HvChannelState(name="front", measured_voltage=1234.5)])
    publisher.create_timer(0.05, lambda: hv.publish(state))
    spin(node, assembly_state, publisher)
    return node


class Viewer:
    """A Foxglove WebSocket client: the channels the server advertised, subscriptions, messages."""

    def __init__(self, socket):
        self.socket = socket
        self.server_info = None
        self.channels: dict[str, dict] = {}
        self.subscriptions: dict[int, str] = {}

    def _receive(self):
        frame = self.socket.recv(timeout=RECEIVE_TIMEOUT)
        if isinstance(frame, bytes):
            opcode, subscription, log_time = struct.unpack_from("<BIQ", frame)
            return opcode, subscription, log_time, frame[13:]
        message = json.loads(frame)
        if message["op"] == "serverInfo":
            self.server_info = message
        elif message["op"] == "advertise":
            self.channels.update({channel["topic"]: channel for channel in message["channels"]})
        return None

    def channel(self, topic: str) -> dict:
        while topic not in self.channels:
            self._receive()
        return self.channels[topic]

    def subscribe(self, topic: str) -> int:
        subscription = len(self.subscriptions) + 1
        self.subscriptions[subscription] = topic
        self.socket.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": subscription, "channelId": self.channel(topic)["id"]}]}))
        return subscription

    def message(self, subscription: int) -> bytes:
        while True:
            received = self._receive()
            if received and received[0] == MESSAGE_DATA and received[1] == subscription:
                return received[3]


@contextmanager
def viewing(port: int):
    with connect(f"ws://{HOST}:{port}", subprotocols=[SUBPROTOCOL], open_timeout=RECEIVE_TIMEOUT) as socket:
        yield Viewer(socket)


@pytest.fixture
def viewer(bridge):
    with viewing(bridge.port) as viewer:
        yield viewer


@pytest.mark.parametrize("topic, type_name", [
    ("/hv/state", "softblock_interfaces/msg/HvState"), ("/assembly/state", "softblock_interfaces/msg/AssemblyState"),
    ("/assembly/markers", "visualization_msgs/msg/MarkerArray"), ("/tf", "tf2_msgs/msg/TFMessage"),
    ("/tf_static", "tf2_msgs/msg/TFMessage"), ("/assembly/current", "softblock_interfaces/msg/Assembly"),
    ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"), ("/camera/silhouette", "sensor_msgs/msg/Image"),
    ("/assembly/estimated", "softblock_interfaces/msg/AssemblyState")])
def test_channels_are_advertised_with_the_schemas_a_recording_holds(viewer, topic, type_name):
    channel = viewer.channel(topic)
    assert channel["schemaName"] == type_name
    assert channel["encoding"] == "cdr" and channel["schemaEncoding"] == "ros2msg"
    assert channel["schema"] == full_definition(type_name)


def test_viewers_only_watch_and_see_only_the_served_topics(bridge, viewer):
    viewer.channel("/hv/state")
    assert viewer.server_info["capabilities"] == []  # no publishing, services or parameters from a client
    wait_for(lambda: "/hv/state" in bridge.served_topics, what="/hv/state served")
    assert "/hv/heartbeat" not in bridge.served_topics and "/hv/heartbeat" not in viewer.channels


def test_a_subscription_receives_hv_state(viewer):
    state = deserialize_message(viewer.message(viewer.subscribe("/hv/state")), HvState)
    assert state.backend == "sim"
    assert [(c.name, c.measured_voltage) for c in state.channels] == [("front", 1234.5)]


def test_a_late_viewer_receives_the_latched_mounts(bridge, viewer):
    viewer.message(viewer.subscribe("/tf_static"))  # the mounts went through the bridge once
    with viewing(bridge.port) as late:  # connects after that
        mounts = deserialize_message(late.message(late.subscribe("/tf_static")), TFMessage)
    assert {t.child_frame_id for t in mounts.transforms} >= {"front_left/base", "back_right/base"}


@pytest.fixture
def latched_topic(ros_context, spin):
    """A bridge serving one latched topic, /latched_probe, with two publishers that keep their last sample."""
    bridge = FoxgloveBridgeNode(context=ros_context, parameter_overrides=[
        Parameter("port", value=0), Parameter("discovery_period_s", value=0.2),
        Parameter("topics", value=["/latched_probe"])])
    sources = rclpy.create_node("latched_sources", context=ros_context)
    first, second = (sources.create_publisher(String, "/latched_probe", LATCHED) for _ in range(2))
    spin(bridge, sources)
    wait_for(lambda: "/latched_probe" in bridge.served_topics, what="/latched_probe served")
    return bridge, first, second


def texts(viewer: Viewer, subscription: int, until: str) -> list[str]:
    """The samples a subscription receives up to and with ``until``."""
    received = []
    while not received or received[-1] != until:
        received.append(deserialize_message(viewer.message(subscription), String).data)
    return received


def test_a_late_viewer_gets_the_last_sample_of_each_publisher_and_no_viewer_gets_one_twice(latched_topic):
    bridge, first, second = latched_topic
    with viewing(bridge.port) as early:
        watching = early.subscribe("/latched_probe")
        # the bridge follows the viewer's subscription with a ROS subscription matching both publishers
        wait_for(lambda: first.get_subscription_count() >= 1 and second.get_subscription_count() >= 1,
                 what="the bridge to subscribe for the viewer")
        # one at a time: a publisher that keeps one sample may replace it before sending it on
        for publisher, text in ((first, "mounts of the old assembly"), (first, "mounts of the new assembly"),
                                (second, "the other publisher's")):
            publisher.publish(String(data=text))
            assert texts(early, watching, text) == [text]
        with viewing(bridge.port) as late:
            joined = late.subscribe("/latched_probe")
            caught_up = [deserialize_message(late.message(joined), String).data for _ in range(2)]
            assert sorted(caught_up) == ["mounts of the new assembly", "the other publisher's"]
            first.publish(String(data="next"))
            assert texts(late, joined, "next") == ["next"]  # nothing older came after the catch-up
            assert texts(early, watching, "next") == ["next"]  # the early viewer got none of it again


def test_a_taken_port_is_refused_by_name(ros_context, bridge):
    with pytest.raises(OSError, match=f"cannot serve the live view on {HOST}:{bridge.port}: .*in use"):
        FoxgloveBridgeNode(context=ros_context, parameter_overrides=[Parameter("port", value=bridge.port)])


def test_the_listener_answers_every_callback_of_the_servers_protocol():
    # The server calls each (on_unsubscribe when a viewer leaves); a missing one failed every such call.
    listener = _Viewers()
    callbacks = [name for name, _ in inspect.getmembers(ServerListener, inspect.isfunction) if name.startswith("on_")]
    assert "on_unsubscribe" in callbacks
    assert all(callable(getattr(listener, name, None)) for name in callbacks)
    client, channel = type("Client", (), {"id": 3})(), type("Channel", (), {"id": 7})()
    listener.on_subscribe(client, channel)
    listener.on_unsubscribe(client, channel)
    assert listener.take() == [(True, 3, 7), (False, 3, 7)] and listener.take() == []


def test_only_loopback_hosts_count_as_this_machine():
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5")


def test_the_shipped_layout_is_current_and_reads_served_topics():
    assert foxglove_layout.main(["--check"]) == 0
    document = json.loads(foxglove_layout.LAYOUT_FILE.read_text())
    served = {topic if topic.startswith("/") else f"/{topic}" for topic in LIVE_TOPICS}
    assert foxglove_layout.topics_read(document) <= served
    assert {"/hv/state", "/assembly/markers", "/camera/silhouette", "/diagnostics",
            "/sequencer/events"} <= foxglove_layout.topics_read(document)
