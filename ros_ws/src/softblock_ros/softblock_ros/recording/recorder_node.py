"""Recorder node: subscribes (raw CDR) to the stack's topics and writes a ROS 2 MCAP file.

Topics are discovered periodically (all of them, or the `topics` list); each subscription asks
for what the publishers offer, so latched (transient_local) samples are captured.
"""
import re
import sys

from rclpy.node import Node
from rclpy.parameter import Parameter

from recording.mcap_file import COMPRESSIONS, RecordingWriter
from recording.message_definitions import DefinitionNotFoundError
from recording.topics import is_hidden

from ..parameters import Param, ParameterError, declare, with_defaults
from ..runner import run_node
from .message_types import UnknownMessageTypeError, import_message_type
from .qos_metadata import offered_qos_yaml, recording_qos

DEFAULT_EXCLUDE = r"^/parameter_events$"  # /rosout is recorded: the nodes' logs, HV faults among them
PARAMETERS = (
    Param("output", "recording.mcap", "MCAP file to write; an existing one is refused unless overwrite", kind=str),
    Param.of(RecordingWriter, "overwrite", "replace an existing output file (a link is replaced, never written "
             "through)"),
    Param("topics", [], "topics to record (relative names resolve in the node's namespace); empty: every "
          "discovered topic", kind=str, size=(0, 10_000)),
    Param("exclude", DEFAULT_EXCLUDE, "regex of topics not recorded in all-topics mode", kind=str),
    Param.of(RecordingWriter, "compression", "chunk compression", choices=tuple(COMPRESSIONS)),
    Param.of(RecordingWriter, "chunk_size", "bytes per chunk before writing", low=1, high=64 << 20),
    Param("flush_period_s", 1.0, "time between flushes: the most a SIGKILL can lose", "s", 0.01, 60.0),
    Param("discovery_period_s", 1.0, "time between topic discoveries", "s", 0.05, 60.0),
)


class RecorderNode(Node):
    def __init__(self, output: str | None = None, topics=(), **kwargs):
        """``output`` and ``topics`` replace the parameters' defaults (a parameter file still wins)."""
        super().__init__("recorder", **kwargs)
        given = {"output": output, "topics": list(topics)}
        value = declare(self, with_defaults(PARAMETERS, **{name: v for name, v in given.items() if v}))
        self.output, self.topics = value["output"], value["topics"]
        try:
            self.exclude = re.compile(value["exclude"])
        except re.error as error:
            raise ParameterError(f"parameter exclude={value['exclude']!r} refused: not a regular expression "
                                 f"({error})") from None
        compression, chunk_size = value["compression"], value["chunk_size"]
        flush_period, discovery_period = value["flush_period_s"], value["discovery_period_s"]
        self.wanted = {self.resolve_topic_name(topic) for topic in self.topics}
        if value["overwrite"]:
            self.get_logger().warning(f"overwrite is on: an existing {self.output} is replaced")
        self.writer = RecordingWriter(self.output, compression, chunk_size, value["overwrite"])
        self.skipped: dict[str, str] = {}
        self._recorded = {}
        self.create_timer(flush_period, self.writer.flush)
        self.create_timer(discovery_period, self.discover)
        self.discover()

    def _selected(self, topic: str) -> bool:
        if self.wanted:
            return topic in self.wanted
        return not is_hidden(topic) and not self.exclude.search(topic)

    def discover(self) -> None:
        """Subscribes to every selected topic that has publishers and is not recorded yet."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recorded or topic in self.skipped or not self._selected(topic):
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # the offered QoS is unknown until a publisher exists
            if len(types) != 1:
                self._skip(topic, f"it carries several types {types}")
                continue
            self._subscribe(topic, types[0], publishers)

    def _skip(self, topic: str, reason: str) -> None:
        self.skipped[topic] = reason
        self.get_logger().warning(f"not recording {topic}: {reason}")

    def _subscribe(self, topic: str, type_name: str, publishers) -> None:
        try:
            msg_type = import_message_type(type_name, topic)
            offered = [info.qos_profile for info in publishers]
            channel = self.writer.add_topic(topic, type_name, offered_qos_yaml(offered),
                                            str(publishers[0].topic_type_hash))
        except (UnknownMessageTypeError, DefinitionNotFoundError) as error:
            self._skip(topic, str(error))
            return
        qos = recording_qos(offered)
        self._recorded[topic] = self.create_subscription(
            msg_type, topic, lambda data, info: self.writer.write(
                channel, data, info["received_timestamp"], info["source_timestamp"],
                info.get("publication_sequence_number") or 0),
            qos, raw=True)
        self.get_logger().info(f"recording {topic} ({type_name}, {qos.durability.short_key})")

    @property
    def recorded_topics(self) -> list[str]:
        return sorted(self._recorded)

    def close_recording(self) -> None:
        """Finishes the file (idempotent) and reports what it holds."""
        if self.writer.closed:
            return
        self.writer.close()
        counts = self.writer.message_counts
        print(f"wrote {sum(counts.values())} messages on {len(counts)} topics to {self.output}",
              file=sys.stderr)

    def destroy_node(self):
        self.close_recording()
        return super().destroy_node()


def run(parameters: dict, ros_args=None) -> int:
    """Records until SIGINT/SIGTERM, then finishes the file.

    `parameters` (name -> value) win over a --params-file in `ros_args` and the defaults.
    """
    overrides = [Parameter(name, value=value) for name, value in parameters.items()]
    return run_node(lambda: RecorderNode(parameter_overrides=overrides), "recorder",
                    args=ros_args)
