"""A classic little-endian TIFF written byte by byte: one image IFD, its pixel strips and an EXIF sub-IFD.

Why not tifffile: its writer refuses the ``ExifIFD`` pointer tag ("not writing extratag 34665"), so
EXIF tags could only go into IFD0, where they do not belong (TIFF/EP and DNG put ``ExposureTime``,
``DateTimeOriginal`` and ``ISOSpeedRatings`` in the EXIF IFD; ``exiftool -validate`` warns
"Wrong IFD for 0x829a ExposureTime (should be ExifIFD not IFD0)"). The layout (TIFF 6.0 §2): the
8-byte header, IFD0 with its values longer than 4 bytes after it, the EXIF IFD with its values,
then the strips; every IFD and value starts on an even offset, entries are sorted by tag.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

BYTE, ASCII, SHORT, LONG, RATIONAL, UNDEFINED, SRATIONAL = 1, 2, 3, 4, 5, 7, 10
"""TIFF field types."""
EXIF_IFD_TAG = 34665
"""IFD0's pointer to the EXIF IFD."""
STRIP_BYTES = 1 << 16
"""About how many bytes each strip holds (TIFF 6.0 recommends about 8 KiB; readers take any size)."""
_DENOMINATOR_LIMIT = 1_000_000


@dataclass(frozen=True)
class Tag:
    """One IFD entry: its number, field type, value count and the value's bytes (little-endian)."""

    number: int
    type: int
    count: int
    data: bytes


def ascii_tag(number: int, text: str) -> Tag:
    """A NUL-terminated 7-bit ASCII string (anything else becomes ``?``)."""
    data = text.encode("ascii", "replace") + b"\0"
    return Tag(number, ASCII, len(data), data)


def short_tag(number: int, *values: int) -> Tag:
    """Unsigned 16-bit values."""
    return Tag(number, SHORT, len(values), struct.pack(f"<{len(values)}H", *values))


def long_tag(number: int, *values: int) -> Tag:
    """Unsigned 32-bit values."""
    return Tag(number, LONG, len(values), struct.pack(f"<{len(values)}I", *values))


def byte_tag(number: int, *values: int) -> Tag:
    """Unsigned 8-bit values."""
    return Tag(number, BYTE, len(values), bytes(values))


def undefined_tag(number: int, data: bytes) -> Tag:
    """Raw bytes (``ExifVersion``)."""
    return Tag(number, UNDEFINED, len(data), data)


def _fraction(value: float) -> Fraction:
    return Fraction(float(value)).limit_denominator(_DENOMINATOR_LIMIT)


def rational_tag(number: int, *values: float | tuple[int, int]) -> Tag:
    """Unsigned rationals: a float (the nearest fraction with a denominator ≤ 10⁶) or an exact (numerator, denominator).

    Raises
    ------
    ValueError
        A negative value or one past 32 bits.
    """
    pairs = [value if isinstance(value, tuple) else _pair(_fraction(value)) for value in values]
    if any(not (0 <= n < 2**32 and 0 < d < 2**32) for n, d in pairs):
        raise ValueError(f"tag {number}: {values} do not fit unsigned 32-bit rationals")
    return Tag(number, RATIONAL, len(pairs), b"".join(struct.pack("<2I", n, d) for n, d in pairs))


def srational_tag(number: int, *values: float) -> Tag:
    """Signed rationals, each the nearest fraction with a denominator ≤ 10⁶.

    Raises
    ------
    ValueError
        A value past signed 32 bits.
    """
    pairs = [_pair(_fraction(value)) for value in values]
    if any(not (-(2**31) <= n < 2**31 and 0 < d < 2**31) for n, d in pairs):
        raise ValueError(f"tag {number}: {values} do not fit signed 32-bit rationals")
    return Tag(number, SRATIONAL, len(pairs), b"".join(struct.pack("<2i", n, d) for n, d in pairs))


def _pair(fraction: Fraction) -> tuple[int, int]:
    return fraction.numerator, fraction.denominator


def _even(offset: int) -> int:
    return offset + (offset & 1)


def _ifd_size(tags: SequenceOf[Tag]) -> int:
    """Bytes of an IFD: count, entries, next-IFD offset, then its values longer than 4 bytes (each even)."""
    return 2 + 12 * len(tags) + 4 + sum(_even(len(tag.data)) for tag in tags if len(tag.data) > 4)


def _ifd_bytes(offset: int, tags: SequenceOf[Tag]) -> bytes:
    """The IFD at ``offset``, its long values right after it; entries sorted by tag (TIFF 6.0)."""
    ordered = sorted(tags, key=lambda tag: tag.number)
    numbers = [tag.number for tag in ordered]
    if len(set(numbers)) != len(numbers):
        raise ValueError(f"TIFF IFD: tags {numbers} repeat; expected each tag once")
    values_at = offset + 2 + 12 * len(ordered) + 4
    entries, values = [struct.pack("<H", len(ordered))], []
    for tag in ordered:
        if len(tag.data) <= 4:
            field = tag.data.ljust(4, b"\0")
        else:
            field = struct.pack("<I", values_at)
            values.append(tag.data.ljust(_even(len(tag.data)), b"\0"))
            values_at += _even(len(tag.data))
        entries.append(struct.pack("<HHI", tag.number, tag.type, tag.count) + field)
    entries.append(struct.pack("<I", 0))  # no next IFD
    return b"".join(entries + values)


def write_tiff(path: str | os.PathLike, pixels: np.ndarray, ifd0: SequenceOf[Tag], exif: SequenceOf[Tag]) -> Path:
    """Write one uncompressed 16-bit single-sample image with ``ifd0``'s tags and an EXIF IFD of ``exif``'s.

    ``pixels`` are (H, W) uint16; the layout's tags (``ImageWidth`` … ``StripByteCounts``, ``ExifIFD``) are added
    here, not given in ``ifd0``.

    Raises
    ------
    ValueError
        Pixels that are not (H, W) uint16, a file past 4 GiB or a tag given twice.
    """
    data = np.ascontiguousarray(pixels)
    if data.ndim != 2 or data.dtype != np.uint16 or data.size == 0:
        raise ValueError(f"{path}: pixels of shape {data.shape} and type {data.dtype}; expected (H, W) uint16")
    height, width = data.shape
    row_bytes = width * 2
    rows_per_strip = max(1, min(height, STRIP_BYTES // row_bytes))
    strips = [data[row : row + rows_per_strip].astype("<u2").tobytes() for row in range(0, height, rows_per_strip)]
    layout = [
        long_tag(256, width),
        long_tag(257, height),
        short_tag(258, 16),
        short_tag(259, 1),
        short_tag(277, 1),
        short_tag(284, 1),
        long_tag(278, rows_per_strip),
        long_tag(279, *(len(strip) for strip in strips)),
    ]
    placeholder = [long_tag(273, *([0] * len(strips))), long_tag(EXIF_IFD_TAG, 0)]
    ifd0_offset = 8
    exif_offset = _even(ifd0_offset + _ifd_size([*ifd0, *layout, *placeholder]))
    data_offset = _even(exif_offset + _ifd_size(exif))
    offsets, at = [], data_offset
    for strip in strips:
        offsets.append(at)
        at += _even(len(strip))
    if at >= 2**32:
        raise ValueError(f"{path}: {at} bytes; expected a classic TIFF under 4 GiB")
    pointers = [long_tag(273, *offsets), long_tag(EXIF_IFD_TAG, exif_offset)]
    head = struct.pack("<2sHI", b"II", 42, ifd0_offset)
    first = _ifd_bytes(ifd0_offset, [*ifd0, *layout, *pointers])
    second = _ifd_bytes(exif_offset, exif)
    path = Path(path)
    with open(path, "wb") as handle:
        handle.write(head + first.ljust(exif_offset - ifd0_offset, b"\0"))
        handle.write(second.ljust(data_offset - exif_offset, b"\0"))
        for strip in strips:
            handle.write(strip.ljust(_even(len(strip)), b"\0"))
    return path
