"""Opening an MCAP file from anywhere, bounded before the mcap library parses it. No rclpy import.

A record's length fields are trusted by the mcap readers: a chunk or an attachment claiming 2^40 bytes made
them allocate that much (MemoryError) or hand zstd an impossible size (ZstdError). So:
- only a regular file is opened (planner.regular_file: a FIFO would block, /dev/zero never ends);
- no read asks for more bytes than remain in the file (BoundedFile), whatever a length field says;
- every chunk's uncompressed size, as the chunk claims it and as its zstd/lz4 frame header claims it, is at
  most MAX_CHUNK_BYTES, and its records inflate to no more than the chunk claims (`_chunk_problem`: inflated
  piece by piece and counted, never held whole): a frame that declares no size can inflate 4 MB to 1 GiB. This
  is checked for the whole file before any message is read;
- the summary's chunk index, which the seeking reader follows instead of the file's order, points only at chunks
  that scan checked (`_index_problem`): an index entry pointing into an attachment found a chunk claiming 2^40
  bytes there;
- a schema or a message that is not what it claims, found while decoding (`undecodable`), is one ValueError.
"""
from __future__ import annotations

import contextlib
import io
import os
import struct
from typing import NamedTuple

import lz4.frame
import zstandard
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap_ros2._vendor.rosidl_adapter.parser import InvalidSpecification, InvalidValue
from mcap.writer import MCAP0_MAGIC

from planner.regular_file import open_regular

MAX_CHUNK_BYTES = 256 * 1024 * 1024  # [bytes] uncompressed; the recorder's chunks are at most 64 MiB
_RECORD_HEADER = struct.Struct("<BQ")  # opcode, content length
_CHUNK_START = struct.Struct("<QQQII")  # message start, end time, uncompressed size, its CRC, compression's length
_FRAME_HEADER = 18  # bytes: the longest zstd frame header; an lz4 frame header is at most 19
_UNKNOWN_SIZE = (0, zstandard.CONTENTSIZE_UNKNOWN, zstandard.CONTENTSIZE_ERROR)
_PIECE = 1 << 20  # [bytes] inflated at a time while a chunk is measured


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


def _inflated_size(compression: str, compressed: bytes, limit: int) -> int:
    """How many bytes ``compressed`` inflates to, counted up to just past ``limit`` (at most _PIECE more are held
    at a time); the first frame of lz4, as mcap reads it. ZstdError or RuntimeError (python-lz4) for data that
    does not decompress."""
    size = 0
    if compression == "zstd":
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(compressed)) as reader:
            while size <= limit and (piece := reader.read(_PIECE)):
                size += len(piece)
    elif compression == "lz4":
        decompressor = lz4.frame.LZ4FrameDecompressor()
        size = len(decompressor.decompress(compressed, max_length=_PIECE))
        while size <= limit and not decompressor.eof and not decompressor.needs_input:
            size += len(decompressor.decompress(b"", max_length=_PIECE))
    else:
        size = len(compressed)
    return size


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
    records = stream.tell()
    declared = _frame_size(compression, stream.read(_FRAME_HEADER)) if records_length else 0
    if declared is None:
        return f"{where} does not start with a {compression} frame"
    if max(claimed, declared) > MAX_CHUNK_BYTES:
        return f"{where} claims {max(claimed, declared)} bytes uncompressed, above the limit of {MAX_CHUNK_BYTES}"
    stream.seek(records)
    try:
        inflated = _inflated_size(compression, stream.read(records_length), claimed)
    except (zstandard.ZstdError, RuntimeError) as error:
        return f"{where} does not decompress ({type(error).__name__}: {' '.join(str(error).split())[:80]})"
    if inflated > claimed:
        return f"{where} inflates beyond the {claimed} bytes it declares"
    return ""


class Scan(NamedTuple):
    end: int              # the offset where the sound top-level records end
    problem: str          # why the record there is not sound; "" when the file is sound to its end
    chunks: dict[int, int]  # offset -> length (opcode and length field included) of each sound chunk record


def scan(stream: BoundedFile) -> Scan:
    """Walks the top-level records. A record is sound when it fits in the file and, for a chunk, its uncompressed
    size is bounded and its records inflate to no more than that (`_chunk_problem`). The stream's position is
    left at 0."""
    position = len(MCAP0_MAGIC)
    problem = ""
    chunks = {}
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
            chunks[position] = _RECORD_HEADER.size + length
        position = content + length
        if opcode == Opcode.FOOTER:
            break
    stream.seek(0)
    return Scan(position, problem, chunks)


# What the mcap reader raises on a summary section that is not one (on top of McapError).
_SUMMARY_ERRORS = (ValueError, EOFError, KeyError, IndexError, TypeError, struct.error, OverflowError)


def _index_problem(stream: BoundedFile, chunks: dict[int, int]) -> str:
    """Why the summary's chunk index must not be followed, or "": each entry must point at a chunk record that
    `scan` checked, with that record's length."""
    try:
        summary = make_reader(stream).get_summary()
    except (McapError, *_SUMMARY_ERRORS) as error:
        return f"the summary section cannot be read ({type(error).__name__}: {' '.join(str(error).split())[:80]})"
    finally:
        stream.seek(0)
    for entry in summary.chunk_indexes if summary else ():
        if chunks.get(entry.chunk_start_offset) != entry.chunk_length:
            return (f"the summary's chunk index names a chunk of {entry.chunk_length} bytes at byte "
                    f"{entry.chunk_start_offset}; the file has none there")
    return ""


def open_bounded(path: str) -> BoundedFile:
    """The file, checked by `scan` to its end and its summary's chunk index by `_index_problem`; McapError
    naming the record otherwise (e.g. a torn tail: run the recover subcommand)."""
    stream = BoundedFile(path)
    found = scan(stream)
    problem = found.problem or _index_problem(stream, found.chunks)
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
