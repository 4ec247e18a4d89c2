"""Baseline TIFF files written byte by byte, for encodings OpenImageIO's writer does not produce.

OpenImageIO writes little-endian TIFFs only, stores half floats as 32-bit floats and uint32 as
another type; the reader must still be tested on what other tools write: big-endian files (older
scientific cameras, tifffile's ``byteorder='>'``), float16 samples, uint32 counts. The layout is
the TIFF 6.0 baseline: header, one IFD, out-of-line values, one uncompressed strip.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

_SHORT, _LONG = 3, 4
_SAMPLE_FORMATS = {"u": 1, "i": 2, "f": 3}


def write_baseline_tiff(path: Path, pixels: np.ndarray, *, big_endian: bool = False) -> Path:
    """Write ``pixels`` ((H, W) or (H, W, 3); any integer or float dtype) as one uncompressed TIFF strip."""
    order = ">" if big_endian else "<"
    pixels = np.ascontiguousarray(pixels)
    height, width = pixels.shape[:2]
    samples = 1 if pixels.ndim == 2 else pixels.shape[2]
    bits = pixels.dtype.itemsize * 8
    data = pixels.astype(pixels.dtype.newbyteorder(order)).tobytes()
    entries = [  # (tag, type, values), in ascending tag order as TIFF requires
        (256, _LONG, [width]),
        (257, _LONG, [height]),
        (258, _SHORT, [bits] * samples),
        (259, _SHORT, [1]),
        (262, _SHORT, [2 if samples == 3 else 1]),
        (273, _LONG, [0]),
        (277, _SHORT, [samples]),
        (278, _LONG, [height]),
        (279, _LONG, [len(data)]),
        (284, _SHORT, [1]),
        (339, _SHORT, [_SAMPLE_FORMATS[pixels.dtype.kind]] * samples),
    ]
    ifd_size = 2 + 12 * len(entries) + 4
    extra = bytearray()
    extra_start = 8 + ifd_size
    packed_entries = []
    for tag, kind, values in entries:
        code = "H" if kind == _SHORT else "I"
        payload = struct.pack(f"{order}{len(values)}{code}", *values)
        packed_entries.append((tag, kind, values, code, payload))
        if len(payload) > 4:
            extra += payload + b"\0" * (len(payload) % 2)
    strip_offset = extra_start + len(extra)
    ifd = bytearray(struct.pack(f"{order}H", len(entries)))
    offset = extra_start
    for tag, kind, values, _code, payload in packed_entries:
        if tag == 273:
            payload = struct.pack(f"{order}I", strip_offset)
        if len(payload) > 4:
            field = struct.pack(f"{order}I", offset)
            offset += len(payload) + len(payload) % 2
        else:
            field = payload.ljust(4, b"\0")
        ifd += struct.pack(f"{order}HHI", tag, kind, len(values)) + field
    ifd += struct.pack(f"{order}I", 0)
    header = (b"MM" if big_endian else b"II") + struct.pack(f"{order}HI", 42, 8)
    path.write_bytes(header + bytes(ifd) + bytes(extra) + data)
    return path
