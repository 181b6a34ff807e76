"""Opening an MCAP file from anywhere, bounded before the mcap library parses it. No rclpy import.

A record's length fields are trusted by the mcap readers: a chunk or an attachment claiming 2^40 bytes made
them allocate that much (MemoryError) or hand zstd an impossible size (ZstdError). So:
- only a regular file is opened (planner.regular_file: a FIFO would block, /dev/zero never ends);
- no read asks for more bytes than remain in the file (BoundedFile), whatever a length field says;
- every chunk's uncompressed size, as the chunk claims it and as its zstd/lz4 frame header claims it, is at
  most MAX_CHUNK_BYTES (`chunk_problem`), checked for the whole file before any message is read;
- a schema or a message that is not what it claims, found while decoding (`undecodable`), is one ValueError.
"""
from __future__ import annotations

import contextlib
import io
import os
import struct

import lz4.frame
import zstandard
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap_ros2._vendor.rosidl_adapter.parser import InvalidSpecification, InvalidValue
from mcap.writer import MCAP0_MAGIC

from planner.regular_file import open_regular

MAX_CHUNK_BYTES = 256 * 1024 * 1024  # [bytes] uncompressed; the recorder's chunks are at most 64 MiB
_RECORD_HEADER = struct.Struct("<BQ")  # opcode, content length
_CHUNK_START = struct.Struct("<QQQII")  # message start, end time, uncompressed size, its CRC, compression's length
_FRAME_HEADER = 18  # bytes: the longest zstd frame header; an lz4 frame header is at most 19
_UNKNOWN_SIZE = (0, zstandard.CONTENTSIZE_UNKNOWN, zstandard.CONTENTSIZE_ERROR)


class BoundedFile:
    """A read-only regular file whose reads never ask for more than the bytes left before ``size`` (the file's
    size unless set lower). Not an io.RawIOBase: the mcap readers would wrap that in a BufferedReader, whose
    reads allocate what they are asked for, and which closes the file when it is collected."""

    def __init__(self, path: str):
        self._file = os.fdopen(open_regular(path), "rb")
        self.name = path
        self.size = os.fstat(self._file.fileno()).st_size

    def read(self, size: int | None = -1) -> bytes:
        left = max(self.size - self._file.tell(), 0)
        return self._file.read(left if size is None or size < 0 else min(size, left))

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        if whence == io.SEEK_END:  # from the end this file is bounded to
            return self._file.seek(self.size + offset)
        return self._file.seek(offset, whence)

    def tell(self) -> int:
        return self._file.tell()

    def seekable(self) -> bool:
        return True

    def readable(self) -> bool:
        return True

    @property
    def closed(self) -> bool:
        return self._file.closed

    def close(self) -> None:
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _frame_size(compression: str, frame: bytes) -> int | None:
    """The content size a zstd or lz4 frame header declares (0: none declared); None when it is not one."""
    try:
        if compression == "zstd":
            size = zstandard.get_frame_parameters(frame).content_size
        elif compression == "lz4":
            size = lz4.frame.get_frame_info(frame)["content_size"]
        else:
            return 0
    except (zstandard.ZstdError, RuntimeError):  # python-lz4 raises RuntimeError
        return None
    return 0 if size in _UNKNOWN_SIZE else size


def _chunk_problem(stream: BoundedFile, offset: int, length: int) -> str:
    """Why the chunk record whose content starts at ``offset`` must not be read, or ""."""
    where = f"chunk at byte {offset - _RECORD_HEADER.size}"
    stream.seek(offset)
    start = stream.read(_CHUNK_START.size)
    if len(start) < _CHUNK_START.size:
        return f"{where} is cut short"
    _, _, claimed, _, name_length = _CHUNK_START.unpack(start)
    if name_length > length:
        return f"{where} names a compression of {name_length} bytes"
    compression = stream.read(name_length).decode(errors="replace")
    (records_length,) = struct.unpack("<Q", stream.read(8).rjust(8, b"\0"))
    declared = _frame_size(compression, stream.read(_FRAME_HEADER)) if records_length else 0
    if declared is None:
        return f"{where} does not start with a {compression} frame"
    if max(claimed, declared) > MAX_CHUNK_BYTES:
        return f"{where} claims {max(claimed, declared)} bytes uncompressed, above the limit of {MAX_CHUNK_BYTES}"
    return ""


def scan(stream: BoundedFile) -> tuple[int, str]:
    """Walks the top-level records: (the offset where the sound ones end, why the next one is not sound, or ""
    when the file is sound to its end). A record is sound when it fits in the file and, for a chunk, its
    uncompressed size is bounded. The stream's position is left at 0."""
    position = len(MCAP0_MAGIC)
    problem = ""
    while position < stream.size:
        stream.seek(position)
        header = stream.read(_RECORD_HEADER.size)
        if len(header) < _RECORD_HEADER.size:
            problem = f"a record at byte {position} is cut off by the end of the file"
            break
        opcode, length = _RECORD_HEADER.unpack(header)
        content = position + _RECORD_HEADER.size
        if length > stream.size - content:
            problem = f"a record at byte {position} claims {length} bytes, more than the file holds"
            break
        if opcode == Opcode.CHUNK:
            problem = _chunk_problem(stream, content, length)
            if problem:
                break
        position = content + length
        if opcode == Opcode.FOOTER:
            break
    stream.seek(0)
    return position, problem


def open_bounded(path: str) -> BoundedFile:
    """The file, checked by `scan` to its end; McapError naming the record otherwise (e.g. a torn tail:
    run the recover subcommand)."""
    stream = BoundedFile(path)
    _, problem = scan(stream)
    if problem:
        stream.close()
        raise McapError(f"{path}: {problem}")
    return stream


# What mcap-ros2 and the code reading its messages raise on a schema text or a CDR payload that is not what the
# file says (a damaged or foreign file): its parser's errors, short or garbled buffers, missing fields.
DECODE_ERRORS = (InvalidSpecification, InvalidValue, NameError, AttributeError, IndexError, KeyError, TypeError,
                 struct.error, OverflowError, UnicodeDecodeError, RuntimeError, zstandard.ZstdError)


@contextlib.contextmanager
def undecodable(path: str):
    """Turns a decoding failure inside the block into one ValueError line naming the file. The schema parser's
    own print to stderr ("Error with: ...") is held back: the line says it."""
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            yield
    except DECODE_ERRORS as error:
        problem = "".join(c if c.isprintable() else "?" for c in " ".join(str(error).split()))[:120]
        raise ValueError(f"{path}: a schema or message cannot be decoded as it claims "
                         f"({type(error).__name__}: {problem})") from None
