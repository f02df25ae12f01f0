"""Image files made byte by byte for the frame reader's tests."""

import struct
import zlib


def png_header_only(path, width, height):
    """A PNG whose header claims ``width x height`` and which holds no pixel data."""

    def chunk(kind, body):
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))

    path.write_bytes(b"\x89PNG\r\n\x1a\n"
                     + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
                     + chunk(b"IEND", b""))
