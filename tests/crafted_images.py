"""Hostile image files for the image readers' bounds: a header that claims any size, without the pixels."""
import struct
import zlib


def png_header(width: int, height: int) -> bytes:
    """A PNG that is only its signature, its IHDR (1-bit grey) and IEND: the size Pillow reads first."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0)) + chunk(
        b"IEND", b"")
