"""Player node: republishes a recording with its timing and recorded QoS, optionally /clock.

Each topic is published with the Python class of its recorded type (`pkg.msg.Type`) and the
recorded bytes as they are. A type that cannot be imported stops the player before anything is
published (UnknownMessageTypeError names type and topic), unless `skip_unknown` is set: then
that topic is left out with a warning and the rest plays. Command topics (HV heartbeat, safe
voltage, action internals) are played only with `include_commands`, state topics (hv/state, /diagnostics,
...) under their own names only with `include_state` (else under /replay); both are logged.
"""
import sys
import threading

import rclpy
from builtin_interfaces.msg import Time
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile
from rosgraph_msgs.msg import Clock

from recording.playback import STATE_NAMESPACE, PlaybackClock, PlaybackOptions, Recording, play

from ..runner import init
from .message_types import UnknownMessageTypeError, import_message_type
from recording.qos_profiles import parse_offered_qos

from .qos_metadata import playback_qos

# [s] liveness bound only: how long a latched topic's replay waits for its subscribers' acknowledgements before it
# goes on (with a warning) past a subscriber that has stopped answering
ACKNOWLEDGEMENT_TIMEOUT_S = 10.0


class PlayerNode(Node):
    def __init__(self, path: str, options: PlaybackOptions | None = None, **kwargs):
        super().__init__("player", **kwargs)
        self.options = options or PlaybackOptions()
        self.options.validate()
        self.recording = Recording(path)
        self.publishers_by_channel = {}
        self._unacknowledged: dict[int, int] = {}  # channel id -> samples written since all were acknowledged
        self.skipped: dict[str, str] = {}
        self._announce_command_topics()
        self._announce_state_topics()
        for channel in self.recording.select(self.options):
            self._advertise(channel)
        self.stop_event = threading.Event()
        self.finished = threading.Event()
        self.published = 0
        self.clock = PlaybackClock(self.options.rate, self.stop_event,
                                   self.recording.start_of_playback(self.options))
        if self.options.clock_frequency_hz > 0:
            self._clock_publisher = self.create_publisher(Clock, "/clock", QoSProfile(depth=1))
            self.create_timer(1.0 / self.options.clock_frequency_hz, self._publish_clock)
        self._thread = threading.Thread(target=self._play, name="playback", daemon=True)

    def _announce_command_topics(self) -> None:
        commands = self.recording.command_topics()
        if commands and self.options.include_commands:
            self.get_logger().warning(
                f"playing command topics {commands}: a live node listening on them obeys them "
                "(an HV driver takes the heartbeat and the safe voltage)")
        elif commands:
            self.get_logger().info(
                f"not playing command topics {commands} (--include-commands plays them)")

    def _announce_state_topics(self) -> None:
        states = self.recording.state_topics()
        if not states or self.options.namespace:
            return
        if self.options.include_state:
            self.get_logger().warning(
                f"playing state topics {states} under their own names: a live client takes them for the live "
                "state (a replayed hv/state hides a dead HV driver)")
        else:
            self.get_logger().info(
                f"playing state topics {states} under {STATE_NAMESPACE} "
                "(--include-state plays them under their own names)")

    def _advertise(self, channel) -> None:
        type_name = self.recording.type_names.get(channel.id, "")
        try:
            msg_type = import_message_type(type_name, channel.topic)
        except UnknownMessageTypeError as error:
            if not self.options.skip_unknown:
                self.recording.close()
                raise
            self.skipped[channel.topic] = str(error)
            self.get_logger().warning(f"not playing {channel.topic}: {error}")
            return
        qos = playback_qos(parse_offered_qos(channel.metadata.get("offered_qos_profiles", ""), channel.topic))
        topic = self.options.published_name(channel.topic)
        self.publishers_by_channel[channel.id] = self.create_publisher(msg_type, topic, qos)

    def start(self) -> None:
        """Starts playback in a background thread; `finished` is set at the end."""
        self._thread.start()

    def stop(self) -> None:
        self.stop_event.set()
        if self._thread.is_alive():
            self._thread.join()

    def _play(self) -> None:
        channels = [c for c in self.recording.channels if c.id in self.publishers_by_channel]
        try:
            self.published = play(self.recording, channels, self.options, self.clock,
                                  self._publish)
        finally:
            self.finished.set()

    def _publish(self, channel, message) -> None:
        publisher = self.publishers_by_channel[channel.id]
        if publisher.qos_profile.history == HistoryPolicy.KEEP_LAST:
            self._wait_for_room(channel, publisher)
        publisher.publish(message.data)

    def _wait_for_room(self, channel, publisher) -> None:
        """A latched publisher keeps only its depth of samples (what a late joiner gets): a sample written into a
        full history pushes out the oldest, sent or not. Before that write, wait until its subscribers hold every
        sample, so that a fast replay's burst loses none (volatile topics keep all: playback_qos)."""
        if self._unacknowledged.get(channel.id, 0) >= publisher.qos_profile.depth:
            if not publisher.wait_for_all_acked(Duration(seconds=ACKNOWLEDGEMENT_TIMEOUT_S)):
                self.get_logger().warning(
                    f"{channel.topic}: not every subscriber acknowledged the samples written within "
                    f"{ACKNOWLEDGEMENT_TIMEOUT_S:g} s; a slow one may miss some of this burst")
            self._unacknowledged[channel.id] = 0
        self._unacknowledged[channel.id] = self._unacknowledged.get(channel.id, 0) + 1

    def _publish_clock(self) -> None:
        if not self._thread.is_alive():
            return  # /clock runs while messages are played, as in ros2 bag play
        seconds, nanoseconds = divmod(self.clock.now(), 1_000_000_000)
        self._clock_publisher.publish(Clock(clock=Time(sec=seconds, nanosec=nanoseconds)))

    def destroy_node(self):
        self.stop()
        self.recording.close()
        return super().destroy_node()


def run(path: str, options: PlaybackOptions, keep_alive: bool = False, ros_args=None) -> int:
    """Plays `path` to the end (or until SIGINT/SIGTERM); keep_alive keeps latched topics up."""
    init(ros_args)
    node = None
    try:
        node = PlayerNode(path, options)
        node.start()
        while rclpy.ok() and (keep_alive or not node.finished.is_set()):
            rclpy.spin_once(node, timeout_sec=0.1)
        print(f"published {node.published} messages", file=sys.stderr)
        return 0
    except UnknownMessageTypeError as error:
        rclpy.logging.get_logger("player").error(f"{error} (use --skip-unknown to play the rest)")
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
