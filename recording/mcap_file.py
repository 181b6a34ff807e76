"""MCAP files with the ROS 2 profile: writing, describing and recovering. No rclpy import.

Chunks are compressed and written out at least every `flush_period`, so a recorder killed
with SIGKILL loses at most the chunk in memory; `recover` turns such a file (no summary, no
footer, maybe a torn last record) into a complete one.
"""
import os
import struct
from dataclasses import dataclass, field

import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer

from planner.atomic_file import atomic_write

from .bounded_mcap import BoundedFile, open_bounded, scan
from .message_definitions import SCHEMA_ENCODING, full_definition
from .qos_profiles import parse_offered_qos

PROFILE = "ros2"
MESSAGE_ENCODING = "cdr"
LIBRARY = "softblock-recorder"
COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}
DEFAULT_CHUNK_SIZE = 256 * 1024
SEQUENCE_MODULUS = 1 << 32  # MCAP's message sequence field is a uint32
BAG_METADATA_VERSION = 9  # rosbag2_storage::BagMetadata of ROS 2 Jazzy
NO_MESSAGE_TIME = 2**63 - 1  # rosbag2's starting_time of a bag without messages


def create_new(path: str, overwrite: bool = False):
    """A new file at ``path`` open for binary writing, never written through a symlink.

    An existing ``path`` (a file, a link, anything) is refused with FileExistsError, as ``ros2 bag record``
    refuses an existing bag; with ``overwrite`` it is removed first (a link itself, not what it points to), so
    an old recording is replaced, never truncated in place."""
    if overwrite and os.path.lexists(path) and not os.path.isdir(path):
        os.unlink(path)
    try:
        descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    except FileExistsError:
        raise _exists(path, "--overwrite, parameter overwrite") from None
    return os.fdopen(descriptor, "wb")


def _exists(path: str, how: str) -> FileExistsError:
    return FileExistsError(f"{path} exists; choose another output, or overwrite it on purpose ({how})")


class RecordingWriter:
    """Writes one ROS 2 MCAP file: a schema per message type, a channel per topic. The file must not
    exist unless ``overwrite`` (see create_new)."""

    def __init__(self, path: str, compression: str = "zstd",
                 chunk_size: int = DEFAULT_CHUNK_SIZE, overwrite: bool = False):
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {sorted(COMPRESSIONS)}, "
                             f"not {compression!r}")
        if chunk_size <= 0:
            raise ValueError(f"chunk_size must be positive, not {chunk_size}")
        self.path = path
        self._stream = create_new(path, overwrite)
        self._writer = Writer(self._stream, chunk_size=chunk_size,
                              compression=COMPRESSIONS[compression])
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._schema_ids: dict[str, int] = {}
        self.message_counts: dict[str, int] = {}
        self._topics: dict[int, str] = {}
        self._topic_metadata: dict[str, dict] = {}  # topic -> rosbag2 TopicMetadata
        self._first_time, self._last_time = NO_MESSAGE_TIME, 0  # log times [ns]

    def add_topic(self, topic: str, type_name: str, offered_qos_profiles: str = "",
                  type_hash: str = "", definition: str | None = None) -> int:
        """Registers a topic; returns the channel id to pass to `write`.

        `definition` defaults to the full .msg text found through the ament index.
        """
        if type_name not in self._schema_ids:
            text = full_definition(type_name) if definition is None else definition
            self._schema_ids[type_name] = self._writer.register_schema(
                type_name, SCHEMA_ENCODING, text.encode())
        metadata = {"offered_qos_profiles": offered_qos_profiles, "topic_type_hash": type_hash}
        channel_id = self._writer.register_channel(topic, MESSAGE_ENCODING,
                                                   self._schema_ids[type_name], metadata)
        self._topics[channel_id] = topic
        self.message_counts[topic] = 0
        self._topic_metadata[topic] = {
            "name": topic, "type": type_name, "serialization_format": MESSAGE_ENCODING,
            "offered_qos_profiles": parse_offered_qos(offered_qos_profiles, topic),
            "type_description_hash": type_hash}
        return channel_id

    def write(self, channel_id: int, data: bytes, log_time: int, publish_time: int, sequence: int = 0) -> None:
        """Adds one serialized (CDR) message; times in nanoseconds; ``sequence`` is the publisher's own
        sample counter (DDS publication sequence number; 0 = unknown), kept to 32 bits as MCAP stores it."""
        self._writer.add_message(channel_id, log_time, bytes(data), publish_time, sequence % SEQUENCE_MODULUS)
        self.message_counts[self._topics[channel_id]] += 1
        self._first_time = min(self._first_time, log_time)
        self._last_time = max(self._last_time, log_time)

    def flush(self) -> None:
        """Writes the chunk in progress to disk: what a SIGKILL afterwards cannot lose."""
        self._writer.flush()

    @property
    def closed(self) -> bool:
        return self._stream.closed

    def bag_metadata(self) -> dict:
        """rosbag2's BagMetadata of this file, as `ros2 bag record` stores it at close (v9)."""
        count = sum(self.message_counts.values())
        duration = {"nanoseconds": max(self._last_time - self._first_time, 0)}
        starting_time = {"nanoseconds_since_epoch": self._first_time}
        name = os.path.basename(self.path)
        return {
            "version": BAG_METADATA_VERSION, "storage_identifier": "mcap", "duration": duration,
            "starting_time": starting_time, "message_count": count,
            "topics_with_message_count": [
                {"topic_metadata": metadata, "message_count": self.message_counts[topic]}
                for topic, metadata in self._topic_metadata.items()],
            # rosbag2's own file or message compression, not MCAP's chunk compression
            "compression_format": "", "compression_mode": "",
            "relative_file_paths": [name],
            "files": [{"path": name, "starting_time": starting_time, "duration": duration,
                       "message_count": count}],
            "custom_data": {},
            "ros_distro": os.environ.get("ROS_DISTRO") or "jazzy",  # PyPI wheels set no ROS_DISTRO
        }

    def close(self) -> None:
        """Writes rosbag2's metadata record, indexes, statistics and footer: a complete file."""
        if self.closed:
            return
        self._writer.add_metadata("rosbag2", {"serialized_metadata": yaml.safe_dump(
            self.bag_metadata(), sort_keys=False, default_flow_style=False)})
        self._writer.finish()
        self._stream.close()


def require_complete(path: str) -> None:
    """McapError unless `path` (a regular file) ends with the footer magic that `RecordingWriter.close` writes."""
    with BoundedFile(path) as stream:
        stream.seek(0, os.SEEK_END)
        size = stream.tell()
        stream.seek(max(size - len(MCAP0_MAGIC), 0))
        complete = size > 2 * len(MCAP0_MAGIC) and stream.read() == MCAP0_MAGIC
    if not complete:
        raise McapError(f"{path} is not a finished MCAP file (its recorder was killed?); "
                        "run the recover subcommand on it first")


@dataclass
class RecoveryResult:
    success: bool
    message: str
    messages: int = 0
    topics: dict = field(default_factory=dict)


def _readable_records(stream: BoundedFile):
    """Records of `stream` in file order, stopping quietly at a truncated tail (or wherever its size says)."""
    records = StreamReader(stream, validate_crcs=True).records
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except (McapError, struct.error, ValueError, EOFError):
            return  # torn record at the end of a file whose writer died
        yield record


class _NotMcap(Exception):
    """The source does not start with an MCAP header: nothing is written."""


def recover(source: str, target: str, overwrite: bool = False) -> RecoveryResult:
    """Rewrites the readable prefix of `source` (e.g. a SIGKILL'd recording) as a valid `target`.

    `target` must not be `source` under any name (a link, another path): the files are compared,
    not the names. An existing `target` is refused (FileExistsError) unless `overwrite`, as
    `RecordingWriter` refuses one. The output goes to a temporary file renamed to `target` at the end,
    so `source` is read whole before anything named `target` changes; a link named `target` is
    replaced, never written through.
    """
    if os.path.exists(target) and os.path.samefile(source, target):
        raise ValueError(f"target {target} is the recording {source} itself; choose another output")
    if os.path.lexists(target) and not overwrite:
        raise _exists(target, "--overwrite")
    counts: dict[str, int] = {}
    with BoundedFile(source) as records:
        records.size, problem, _ = scan(records)  # reads end where the sound records do (recording.bounded_mcap)
        try:
            with atomic_write(target, "wb", replace=overwrite) as stream:
                _copy_readable(records, stream, counts)
        except _NotMcap:
            return RecoveryResult(False, f"{source} does not start with an MCAP header")
    stopped = f" (stopped at what follows: {problem})" if problem else ""
    return RecoveryResult(True, f"recovered {sum(counts.values())} messages into {target}{stopped}",
                          sum(counts.values()), counts)


def _copy_readable(source: BoundedFile, stream, counts: dict[str, int]) -> None:
    """Writes the readable records of `source` as a complete MCAP file; counts per topic."""
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    topics: dict[int, str] = {}
    writer = None
    for record in _readable_records(source):
        if isinstance(record, Header):
            writer = Writer(stream, chunk_size=DEFAULT_CHUNK_SIZE)
            writer.start(profile=record.profile, library=record.library)
        elif writer is None:
            break
        elif isinstance(record, Schema) and record.id not in schema_ids:
            schema_ids[record.id] = writer.register_schema(record.name, record.encoding,
                                                           record.data)
        elif isinstance(record, Channel) and record.id not in channel_ids:
            channel_ids[record.id] = writer.register_channel(
                record.topic, record.message_encoding, schema_ids.get(record.schema_id, 0),
                record.metadata)
            topics[record.id] = record.topic
            counts.setdefault(record.topic, 0)
        elif isinstance(record, Message) and record.channel_id in channel_ids:
            writer.add_message(channel_ids[record.channel_id], record.log_time,
                               record.data, record.publish_time, record.sequence)
            counts[topics[record.channel_id]] += 1
        elif isinstance(record, Metadata):
            writer.add_metadata(record.name, record.metadata)
        elif isinstance(record, Attachment):
            writer.add_attachment(record.create_time, record.log_time, record.name,
                                  record.media_type, record.data)
    if writer is None:
        raise _NotMcap
    writer.finish()


def describe(path: str) -> dict:
    """Profile, time span and per-topic type, count and durability of a complete file.

    Raises McapError for an unfinished file (writer killed): run `recover` on it.
    """
    require_complete(path)
    with open_bounded(path) as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        summary = reader.get_summary()
    if summary is None or summary.statistics is None:
        raise McapError(f"{path} has no summary section; run the recover subcommand on it")
    stats = summary.statistics
    topics = {}
    for channel_id, channel in sorted(summary.channels.items()):
        schema = summary.schemas.get(channel.schema_id)
        offered = parse_offered_qos(channel.metadata.get("offered_qos_profiles", ""), channel.topic)
        topics[channel.topic] = {
            "type": schema.name if schema else "",
            "count": stats.channel_message_counts.get(channel_id, 0),
            "durability": sorted({str(p.get("durability", "")) for p in offered}),
        }
    return {
        "path": path, "profile": header.profile, "library": header.library,
        "message_count": stats.message_count, "chunk_count": stats.chunk_count,
        "start_time": stats.message_start_time / 1e9,
        "duration": (stats.message_end_time - stats.message_start_time) / 1e9,
        "topics": topics,
    }
