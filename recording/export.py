"""A recording as CSV, one file per topic, for analysis elsewhere (a spreadsheet, MATLAB, pandas). No rclpy.

Each row is one message: ``time_s`` (log time in seconds from the recording's first message), ``log_time_ns``
(the exact log time since the epoch) and the message's fields flattened to dotted columns
(``channels.0.measured_voltage``). The stack's messages carry SI units (V, A, m, rad, s); a time or a duration
(``sec``, ``nanosec``) becomes one column in seconds. An array of more than MAX_ARRAY_COLUMNS numbers (an
image's pixels) becomes its length (``data.length``). Columns are those of the first message, then any new
ones in the order they appear; a message without a column leaves its cell empty.
"""
from __future__ import annotations

import csv
from collections import defaultdict
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from planner.atomic_file import atomic_write

from .bounded_mcap import open_bounded, undecodable
from .mcap_file import require_complete

MAX_ARRAY_COLUMNS = 64
TIME_COLUMNS = ("time_s", "log_time_ns")


def _fields(message) -> list[str]:
    return [name for name in getattr(message, "__slots__", ()) if not name.startswith("_")]


def _is_time(message) -> bool:
    return _fields(message) in (["sec", "nanosec"], ["sec", "nsec"])


def flatten(message, prefix: str = "") -> dict:
    """Column -> value of one decoded message (see the module docstring)."""
    if _is_time(message):
        seconds, fraction = (getattr(message, name) for name in _fields(message))
        return {prefix.rstrip("."): seconds + fraction * 1e-9}
    row = {}
    for name in _fields(message):
        value, column = getattr(message, name), prefix + name
        if isinstance(value, (bytes, bytearray)) or (isinstance(value, (list, tuple)) and len(value) > MAX_ARRAY_COLUMNS
                                                      and not _fields(value[0])):
            row[f"{column}.length"] = len(value)
        elif isinstance(value, (list, tuple)):
            for index, item in enumerate(value):
                row.update(flatten(item, f"{column}.{index}.") if _fields(item) else {f"{column}.{index}": item})
        elif _fields(value):
            row.update(flatten(value, column + "."))
        else:
            row[column] = value
    return row


def csv_name(topic: str) -> str:
    """The file name of a topic's CSV: ``/robot1/hv/state`` -> ``robot1.hv.state.csv``."""
    return topic.strip("/").replace("/", ".") + ".csv"


def export_csv(path: str, directory: str | Path) -> dict[str, int]:
    """Writes ``<directory>/<topic>.csv`` for every topic of the recording; returns topic -> rows written.
    Each file is written whole and renamed into place (planner.atomic_file), replacing an older export."""
    require_complete(path)
    rows: dict[str, list[dict]] = defaultdict(list)
    with open_bounded(path) as stream, undecodable(path):
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        start = reader.get_summary().statistics.message_start_time
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            rows[channel.topic].append({"time_s": (message.log_time - start) / 1e9, "log_time_ns": message.log_time,
                                        **flatten(decoded)})
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    for topic, topic_rows in rows.items():
        columns = list(dict.fromkeys(column for row in topic_rows for column in row))
        with atomic_write(directory / csv_name(topic), "w", newline="") as out:
            writer = csv.DictWriter(out, columns)
            writer.writeheader()
            writer.writerows(topic_rows)
    return {topic: len(topic_rows) for topic, topic_rows in rows.items()}
