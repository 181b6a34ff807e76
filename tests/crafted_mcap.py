"""Hostile MCAP files for the recording readers' bounds (recording.bounded_mcap), crafted record by record: chunks
whose records inflate beyond what they declare, and a summary whose chunk index points into an attachment."""
import io
import struct

import lz4.frame
import zstandard
from mcap.opcode import Opcode
from mcap.writer import MCAP0_MAGIC, Writer

BLOCK = 64 << 20  # [bytes] of zeros compressed at a time (never the whole inflated size in memory)
TERABYTE = 1 << 40


def record(opcode: int, content: bytes) -> bytes:
    return bytes([opcode]) + struct.pack("<Q", len(content)) + content


def _text(data: bytes) -> bytes:
    return struct.pack("<I", len(data)) + data


def inflating_frame(compression: str, size: int) -> bytes:
    """A zstd or lz4 frame of ``size`` zero bytes whose header declares no content size."""
    if compression == "lz4":
        compressor = lz4.frame.LZ4FrameCompressor()
        parts = [compressor.begin(source_size=0)]
    else:
        compressor, parts = zstandard.ZstdCompressor(write_content_size=False).compressobj(), []
    for start in range(0, size, BLOCK):
        parts.append(compressor.compress(bytes(min(BLOCK, size - start))))
    return b"".join([*parts, compressor.flush()])


def chunk(compression: str, records: bytes, claimed: int) -> bytes:
    """A chunk record of compressed ``records`` that claims ``claimed`` bytes uncompressed."""
    return record(Opcode.CHUNK, struct.pack("<QQQI", 0, 0, claimed, 0) + _text(compression.encode())
                  + struct.pack("<Q", len(records)) + records)


def file_with(*records: bytes) -> bytes:
    """A file of a header, ``records``, a data end and a footer without a summary."""
    return (MCAP0_MAGIC + record(Opcode.HEADER, _text(b"ros2") + _text(b"crafted")) + b"".join(records)
            + record(Opcode.DATA_END, struct.pack("<I", 0)) + record(Opcode.FOOTER, struct.pack("<QQI", 0, 0, 0))
            + MCAP0_MAGIC)


FAKE = b"FAKECHUNK!"


def chunk_index_into_attachment(topic: str, schema_name: str, schema_text: str, messages: list[bytes],
                                offset: int | None = None) -> bytes:
    """A finished file of ``messages`` on ``topic`` whose summary's chunk index entries point at ``offset``, by
    default at a chunk inside an attachment that claims a terabyte (its zstd frame declares no size)."""
    frame = zstandard.ZstdCompressor(write_content_size=False).compress(bytes(64))
    buffer = io.BytesIO()
    writer = Writer(buffer)
    writer.start("ros2", "crafted")
    schema = writer.register_schema(schema_name, "ros2msg", schema_text.encode())
    channel = writer.register_channel(topic, "cdr", schema, {"offered_qos_profiles": ""})
    writer.add_attachment(create_time=0, log_time=0, name="x", media_type="application/octet-stream",
                          data=FAKE + chunk("zstd", frame, TERABYTE))
    for index, message in enumerate(messages):
        writer.add_message(channel, 1000 + index, message, 1000 + index)
    writer.finish()
    data = bytearray(buffer.getvalue())
    target = data.index(FAKE) + len(FAKE) if offset is None else offset
    position = len(MCAP0_MAGIC)
    while position < len(data) - len(MCAP0_MAGIC):
        opcode, length = data[position], struct.unpack_from("<Q", data, position + 1)[0]
        if opcode == Opcode.CHUNK_INDEX:  # message start and end time, then the chunk's offset
            struct.pack_into("<Q", data, position + 9 + 16, target)
        if opcode == Opcode.FOOTER:
            break
        position += 9 + length
    return bytes(data)
