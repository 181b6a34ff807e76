"""What to replay and when: topic selection and the recorded timing. No rclpy import.

Command topics (recording.topics) are left out unless `include_commands` is set, so a replay next to
a live stack never feeds its HV watchdog or moves its voltage ceiling by default. State topics (hv/state,
/diagnostics, ...) are played under STATE_NAMESPACE unless `include_state` is set (or every topic goes to a
`namespace`), so a live client never takes a recorded state for the live one (a dead driver stays visible).
"""
import re
import threading
import time
from dataclasses import dataclass

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel

from .bounded_mcap import open_bounded
from .mcap_file import require_complete
from .topics import is_command_topic, is_namespace, is_state_topic

STATE_NAMESPACE = "/replay"  # where a default replay puts the state topics


@dataclass
class PlaybackOptions:
    """Player settings. Regexes use `re.search` on the full topic name; empty matches all."""

    rate: float = 1.0            # playback speed factor (2.0 = twice as fast)
    loop: bool = False           # start over at the end until stopped
    include: str = ""            # regex: play only matching topics
    exclude: str = ""            # regex: never play matching topics
    start_offset_s: float = 0.0  # seconds into the recording to start from
    skip_unknown: bool = False   # play the other topics when a type cannot be imported
    clock_frequency_hz: float = 0.0  # Hz of /clock (rosgraph_msgs/Clock); 0 = no /clock
    delay_s: float = 0.0         # seconds between advertising the topics and the first message,
                                 # so subscribers can discover and match the publishers first
    include_commands: bool = False  # also play command topics (recording.topics)
    namespace: str = ""          # prefix of every topic, e.g. /replay; "": topics as recorded
    include_state: bool = False  # state topics under their own names too (else under STATE_NAMESPACE)

    def published_name(self, topic: str) -> str:
        """The name a recorded topic is played under."""
        if self.namespace:
            return self.namespace + topic
        if is_state_topic(topic) and not self.include_state:
            return STATE_NAMESPACE + topic
        return topic

    def validate(self) -> None:
        if not self.rate > 0:
            raise ValueError(f"rate must be positive, not {self.rate}")
        if self.start_offset_s < 0:
            raise ValueError(f"start_offset_s must be >= 0 s, not {self.start_offset_s}")
        if self.clock_frequency_hz < 0:
            raise ValueError(f"clock_frequency_hz must be >= 0 Hz, not {self.clock_frequency_hz}")
        if self.delay_s < 0:
            raise ValueError(f"delay_s must be >= 0 s, not {self.delay_s}")
        if self.namespace and not is_namespace(self.namespace):
            raise ValueError(f"namespace must look like /name or /a/b, not {self.namespace!r}")
        for name in ("include", "exclude"):
            try:
                re.compile(getattr(self, name))
            except re.error as error:
                raise ValueError(f"{name} is not a valid regex: {error}") from error


class Recording:
    """A finished MCAP file: its channels with their schema names, and a time-ordered reader."""

    def __init__(self, path: str):
        require_complete(path)
        self.path = path
        self._stream = open_bounded(path)
        self._reader = make_reader(self._stream)
        summary = self._reader.get_summary()
        if summary is None or summary.statistics is None:
            self._stream.close()
            raise McapError(f"{path} has no summary section; run the recover subcommand on it")
        self.channels: list[Channel] = list(summary.channels.values())
        self.type_names = {c.id: summary.schemas[c.schema_id].name
                           for c in self.channels if c.schema_id in summary.schemas}
        self.start_time = summary.statistics.message_start_time
        self.end_time = summary.statistics.message_end_time

    def select(self, options: PlaybackOptions) -> list[Channel]:
        """Channels whose topic passes the include/exclude regexes (command topics if asked for)."""
        include, exclude = re.compile(options.include), re.compile(options.exclude)
        return [c for c in self.channels
                if include.search(c.topic) and not (options.exclude and exclude.search(c.topic))
                and (options.include_commands or not is_command_topic(c.topic))]

    def command_topics(self) -> list[str]:
        """The recorded command topics (see recording.topics)."""
        return sorted(c.topic for c in self.channels if is_command_topic(c.topic))

    def state_topics(self) -> list[str]:
        """The recorded state topics (see recording.topics)."""
        return sorted(c.topic for c in self.channels if is_state_topic(c.topic))

    def start_of_playback(self, options: PlaybackOptions) -> int:
        """Recorded time (ns) playback starts at: the first message plus the start offset."""
        return self.start_time + round(options.start_offset_s * 1e9)

    def messages(self, channels: list[Channel], start: int):
        """(channel, message) in log-time order from recorded time `start` (ns) on."""
        topics = [c.topic for c in channels]
        for _, channel, message in self._reader.iter_messages(topics=topics, starting_at=start):
            yield channel, message

    def close(self) -> None:
        self._stream.close()


class PlaybackClock:
    """Maps wall time to recorded time at a rate factor; waits until a recorded time is due.

    Until `restart` (e.g. during the delay before the first message) it stands at `start` (ns), the
    recorded time playback begins at, as rosbag2's player holds /clock at the bag's start.
    """

    def __init__(self, rate: float, stop: threading.Event, start: int):
        self.rate = rate
        self.stop = stop
        self._origin_recorded = start
        self._origin_wall: float | None = None  # None: not running yet

    def restart(self, recorded_time: int) -> None:
        self._origin_recorded = recorded_time
        self._origin_wall = time.monotonic()

    def now(self) -> int:
        """The recorded time (ns) being played now."""
        if self._origin_wall is None:
            return self._origin_recorded
        return self._origin_recorded + round((time.monotonic() - self._origin_wall)
                                             * self.rate * 1e9)

    def wait_until(self, recorded_time: int) -> bool:
        """Sleeps until `recorded_time` is due; False when stopped meanwhile."""
        delay = (recorded_time - self._origin_recorded) / 1e9 / self.rate
        remaining = self._origin_wall + delay - time.monotonic()
        return not (remaining > 0 and self.stop.wait(remaining)) and not self.stop.is_set()


def play(recording: Recording, channels: list[Channel], options: PlaybackOptions,
         clock: PlaybackClock, publish) -> int:
    """Calls publish(channel, message) at the recorded timing; returns how many were published."""
    published = 0
    if clock.stop.wait(options.delay_s):
        return published
    while not clock.stop.is_set():
        clock.restart(recording.start_of_playback(options))
        for channel, message in recording.messages(channels, recording.start_of_playback(options)):
            if not clock.wait_until(message.log_time):
                return published
            publish(channel, message)
            published += 1
        if not options.loop:
            break
    return published
