"""Foxglove bridge: the stack's topics, live, on Foxglove's WebSocket server (foxglove-sdk).

Each of ``topics`` that has a publisher becomes a channel named by its full topic name, with the schema a
recording holds for it (name ``pkg/msg/Type``, encoding ``ros2msg``, the full definition; messages in ``cdr``),
so one Foxglove layout (config/foxglove/softblock_layout.json) opens the live stream and an MCAP recording
alike. The node subscribes raw and forwards the CDR bytes unchanged. Topics are looked for every
``discovery_period_s``, so nodes started later appear.

A latched (transient-local) topic is served to each viewer through a ROS subscription of its own, made when the
viewer subscribes and ended when it unsubscribes or leaves: like any late joiner, the viewer gets what each
publisher keeps for late joiners (the stack's latched publishers keep their last sample: the mounts on
``/tf_static`` of the assembly as it is now, not of one it replaced), then every new sample, and no other viewer
gets those samples again.

The server binds to ``host`` (127.0.0.1: this machine only; another address is warned about at start) on
``port`` (0: a free port, logged). Clients only watch: the server offers no publishing, services or parameters.
"""
from __future__ import annotations

import ipaddress
import sys
import threading

import foxglove
from foxglove.websocket import ServerListener
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy

from recording.message_definitions import SCHEMA_ENCODING, DefinitionNotFoundError, full_definition

from .parameters import Param, declare
from .recording.message_types import UnknownMessageTypeError, import_message_type
from .recording.qos_metadata import recording_qos
from .runner import run_node

MESSAGE_ENCODING = "cdr"
VIEWER_PERIOD = 0.1  # [s] how often viewers' new and ended subscriptions of latched channels are taken up
LIVE_TOPICS = ["hv/state", "assembly/state", "assembly/estimated", "assembly/markers", "assembly/current",
               "camera/silhouette", "/diagnostics", "sequencer/events", "arm/pose", "/tf", "/tf_static"]
SERVING = "live view on ws://"  # the start of the line the node logs once its server listens (the demo waits for it)

PARAMETERS = (
    Param("host", "127.0.0.1", "address the WebSocket server binds to; 127.0.0.1 serves this machine only",
          kind=str),
    Param("port", 8765, "port of the WebSocket server (ws://host:port); 0 = a free port, logged", "", 0, 65535,
          kind=int),
    Param("topics", LIVE_TOPICS, "topics served (relative names resolve in the node's namespace)", kind=str,
          size=(1, 1000)),
    Param("discovery_period_s", 1.0, "time between looks for the topics' publishers", "s", 0.05, 60.0),
)


def is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name
        return host == "localhost"


class _Viewers(ServerListener):
    """The server's listener: the (client, channel) subscriptions viewers made and ended since the last take()
    (called on the server's thread). The protocol's other callbacks keep its defaults."""

    def __init__(self):
        self._lock = threading.Lock()
        self._changes: list[tuple[bool, int, int]] = []  # (subscribed, client id, channel id), in order

    def on_subscribe(self, client, channel) -> None:
        with self._lock:
            self._changes.append((True, client.id, channel.id))

    def on_unsubscribe(self, client, channel) -> None:
        with self._lock:
            self._changes.append((False, client.id, channel.id))

    def take(self) -> list[tuple[bool, int, int]]:
        with self._lock:
            changes, self._changes = self._changes, []
        return changes


class FoxgloveBridgeNode(Node):
    def __init__(self, **kwargs):
        super().__init__("foxglove_bridge", **kwargs)
        value = declare(self, PARAMETERS)
        host, port = value["host"], value["port"]
        self._wanted = {self.resolve_topic_name(topic) for topic in value["topics"]}
        self._live = foxglove.Context()  # this node's channels only (tests run several nodes in one process)
        self._viewers = _Viewers()
        try:
            self._server = foxglove.start_server(name="softblock", host=host, port=port, context=self._live,
                                                 server_listener=self._viewers)
        except RuntimeError as error:
            raise OSError(f"cannot serve the live view on {host}:{port}: {error}") from None
        self.port = self._server.port
        self._bridged: dict[str, foxglove.Channel] = {}  # topic -> its channel
        self._latched: dict[int, tuple[str, type, object]] = {}  # channel id -> (topic, message type, QoS)
        self._forwarding = []  # the subscriptions of the volatile topics, shared by every viewer
        self._per_viewer: dict[tuple[int, int], object] = {}  # (client id, latched channel id) -> its subscription
        self._skipped: set[str] = set()
        if not is_loopback(host):
            self.get_logger().warning(f"serving the live view beyond this machine (host {host}): whoever reaches "
                                      f"port {self.port} sees the stack's topics")
        self.get_logger().info(f"{SERVING}{host}:{self.port} (open it in Foxglove)")
        self.create_timer(value["discovery_period_s"], self._discover)
        self.create_timer(VIEWER_PERIOD, self._follow_viewers)
        self._discover()

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic not in self._wanted or topic in self._bridged or topic in self._skipped:
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if len(types) != 1:
                self._skip(topic, f"it carries several types {types}")
            elif publishers:  # the QoS to ask for is known once a publisher exists
                self._bridge(topic, types[0], [info.qos_profile for info in publishers])

    def _skip(self, topic: str, reason: str) -> None:
        self._skipped.add(topic)
        self.get_logger().warning(f"not serving {topic}: {reason}")

    def _bridge(self, topic: str, type_name: str, offered) -> None:
        try:
            msg_type = import_message_type(type_name, topic)
            schema = foxglove.Schema(name=type_name, encoding=SCHEMA_ENCODING,
                                     data=full_definition(type_name).encode())
        except (UnknownMessageTypeError, DefinitionNotFoundError) as error:
            self._skip(topic, str(error))
            return
        channel = foxglove.Channel(topic, schema=schema, message_encoding=MESSAGE_ENCODING, context=self._live)
        qos = recording_qos(offered)
        self._bridged[topic] = channel
        if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL:
            self._latched[channel.id()] = (topic, msg_type, qos)
        else:
            self._forwarding.append(self.create_subscription(msg_type, topic, self._forward(channel), qos, raw=True))
        self.get_logger().info(f"serving {topic} ({type_name})")

    def _forward(self, channel: foxglove.Channel, sink: int | None = None):
        """The callback that logs each raw sample on ``channel``: to every subscribed viewer, or to ``sink``."""
        def forward(data: bytes) -> None:
            channel.log(data, log_time=self.get_clock().now().nanoseconds, sink_id=sink)
        return forward

    def _follow_viewers(self) -> None:
        """A viewer's subscription of a latched channel gets a ROS subscription of its own, which DDS first hands
        what each publisher keeps for late joiners; it ends with the viewer's."""
        for subscribed, client, channel_id in self._viewers.take():
            key = (client, channel_id)
            if not subscribed and key in self._per_viewer:
                self.destroy_subscription(self._per_viewer.pop(key))
            elif subscribed and channel_id in self._latched and key not in self._per_viewer:
                topic, msg_type, qos = self._latched[channel_id]
                # foxglove-sdk 0.30 numbers each connected viewer's sink alike with its client id (both counters
                # advance only with connected viewers: the node opens no other sink), and offers no other way
                # to log to one viewer; tests/ros/test_foxglove_bridge.py checks that only that viewer gets it.
                forward = self._forward(self._bridged[topic], sink=client)
                self._per_viewer[key] = self.create_subscription(msg_type, topic, forward, qos, raw=True)

    @property
    def served_topics(self) -> list[str]:
        return sorted(self._bridged)

    def destroy_node(self):
        self._server.stop()
        return super().destroy_node()


def main(args=None):
    sys.exit(run_node(FoxgloveBridgeNode, "foxglove_bridge", args=args))


if __name__ == "__main__":
    main()
