"""The chunks of a PNG file, to check what the previews and plots msflash writes declare."""

from __future__ import annotations

import struct


def png_chunks(data: bytes) -> dict[str, bytes]:
    """The chunks of PNG bytes by type (the first of each type)."""
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        raise ValueError("PNG: missing signature; expected PNG data")
    chunks: dict[str, bytes] = {}
    position = 8
    while position + 8 <= len(data):
        (length,) = struct.unpack(">I", data[position : position + 4])
        kind = data[position + 4 : position + 8].decode("latin-1")
        chunks.setdefault(kind, data[position + 8 : position + 8 + length])
        position += 12 + length
    return chunks
