"""Packed GenICam pixel formats: their PFNC codes, sizes and a vectorised numpy decoder.

Two packings exist for 10- and 12-bit samples, and cameras offer one or the other:

- **PFNC "p"** (``Mono10p``, ``Mono12p``, ``BayerRG12p`` …, the GenICam Pixel Format Naming
  Convention 2.x): the samples form one little-endian bit stream, least significant bit first —
  sample ``i`` is bits ``i·b … i·b + b − 1`` of the stream, byte ``j`` holds stream bits
  ``8j … 8j + 7``. Mono12p packs 2 samples in 3 bytes, Mono10p 4 in 5.
- **GigE Vision "Packed"** (``Mono12Packed``, ``BayerGR12Packed`` …, ``Mono10Packed``, the
  GigE Vision 1.x formats): 2 samples in 3 bytes, the high bits of each sample in its own byte
  and the low bits of both in the middle byte. 12 bits: byte 0 = ``p0[11:4]``, byte 1 =
  ``p0[3:0] | p1[3:0] << 4``, byte 2 = ``p1[11:4]``. 10 bits: byte 0 = ``p0[9:2]``, byte 1 =
  ``p0[1:0] | p1[1:0] << 4`` (bits 2–3 and 6–7 unused), byte 2 = ``p1[9:2]``.

Rows are not padded in either packing, so a frame is decoded only when its width is a whole
number of packing groups (2 or 4 samples): then every row starts on a byte boundary and the
"one stream per frame" and "one stream per row" readings agree. Cameras constrain packed widths
the same way (their ``Width`` increment); a width that is not is refused, not guessed at.

Pure numpy: no ``gi`` here; :mod:`acquisition.devices.aravis.camera` calls :func:`unpack_pixels` for the
formats of :data:`PACKED_FORMATS`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from msflash.acquisition.errors import CameraError

Packing = Literal["pfnc", "gev"]


@dataclass(frozen=True)
class PackedLayout:
    """How one packed pixel format stores its samples."""

    pfnc: int
    """The format's code (PFNC / GigE Vision ``PixelFormat`` register value): bits 16–23 are the
    bits per sample on the wire."""
    bits: int
    """Significant bits per sample: the white level is ``2**bits - 1``."""
    packing: Packing
    """``pfnc``: LSB-first bit stream; ``gev``: GigE Vision 1.x Packed layout (module docstring)."""
    group_pixels: int
    """Samples in one packing group (a group starts on a byte boundary)."""
    group_bytes: int
    """Bytes of one packing group."""
    cfa: str | None = None
    """Mosaic layout for Bayer formats (``RGGB``, ``GRBG``, ``GBRG``, ``BGGR``)."""


BAYER_CFA = {"RG": "RGGB", "GR": "GRBG", "GB": "GBRG", "BG": "BGGR"}
"""The mosaic layout each GenICam ``Bayer<XY>…`` name stands for (its first row's first two colours)."""


def _packed_formats() -> dict[str, PackedLayout]:
    table = {
        "Mono10p": PackedLayout(0x010A0046, 10, "pfnc", 4, 5),
        "Mono12p": PackedLayout(0x010C0047, 12, "pfnc", 2, 3),
        "Mono10Packed": PackedLayout(0x010C0004, 10, "gev", 2, 3),
        "Mono12Packed": PackedLayout(0x010C0006, 12, "gev", 2, 3),
    }
    # PFNC codes, in the order GR, RG, GB, BG of each family.
    codes = {
        "10p": (0x010A0056, 0x010A0058, 0x010A0054, 0x010A0052),
        "12p": (0x010C0057, 0x010C0059, 0x010C0055, 0x010C0053),
        "10Packed": (0x010C0026, 0x010C0027, 0x010C0028, 0x010C0029),
        "12Packed": (0x010C002A, 0x010C002B, 0x010C002C, 0x010C002D),
    }
    for suffix, family in codes.items():
        bits = int(suffix[:2])
        packing: Packing = "pfnc" if suffix.endswith("p") else "gev"
        group = (4, 5) if (bits, packing) == (10, "pfnc") else (2, 3)
        for cfa, code in zip(("GR", "RG", "GB", "BG"), family):
            table[f"Bayer{cfa}{suffix}"] = PackedLayout(code, bits, packing, *group, cfa=BAYER_CFA[cfa])
    return table


PACKED_FORMATS: dict[str, PackedLayout] = _packed_formats()
"""Packed formats msflash decodes, by GenICam name: Mono10p, Mono12p, Bayer{GR,RG,GB,BG}{10,12}p
(PFNC), Mono10Packed, Mono12Packed, Bayer{GR,RG,GB,BG}{10,12}Packed (GigE Vision)."""


def _layout(pixel_format: str, width: int, height: int, where: str) -> PackedLayout:
    layout = PACKED_FORMATS.get(pixel_format)
    if layout is None:
        raise CameraError(
            f"{where}: pixel format {pixel_format!r} is not a packed format msflash decodes; "
            f"expected one of {', '.join(PACKED_FORMATS)}"
        )
    if width < 1 or height < 1:
        raise CameraError(f"{where}: frame size {width}x{height}; expected a positive width and height")
    if width % layout.group_pixels:
        raise CameraError(
            f"{where}: width {width} is not a multiple of {layout.group_pixels} for {pixel_format} "
            f"({layout.group_pixels} pixels in {layout.group_bytes} bytes, rows unpadded); expected a width "
            f"the packing divides — set Width in steps of {layout.group_pixels}"
        )
    return layout


def packed_size(pixel_format: str, width: int, height: int, where: str = "packed_size") -> int:
    """Bytes of one ``width`` × ``height`` frame of a packed format.

    Raises
    ------
    CameraError
        Not a format of :data:`PACKED_FORMATS`, or a width the packing group does not divide.

    Examples
    --------
    >>> packed_size("Mono12p", 4, 2), packed_size("Mono10p", 8, 1), packed_size("BayerRG12Packed", 2, 2)
    (12, 10, 6)
    """
    layout = _layout(pixel_format, width, height, where)
    return width * height // layout.group_pixels * layout.group_bytes


def _unpack_pfnc(groups: np.ndarray, layout: PackedLayout) -> np.ndarray:
    """(n, group_bytes) bytes → (n, group_pixels) samples of an LSB-first bit stream.

    Sample ``i`` starts at stream bit ``s = i·bits``: byte ``s // 8``, bit ``s % 8``. For 10 and
    12 bits it ends within the next byte, so two bytes read as a little-endian ``uint16``,
    shifted right by ``s % 8`` and masked, are the sample.
    """
    samples = np.empty((groups.shape[0], layout.group_pixels), dtype=np.uint16)
    mask = np.uint16((1 << layout.bits) - 1)
    for i in range(layout.group_pixels):
        byte, shift = divmod(i * layout.bits, 8)
        assert shift + layout.bits <= 16, "a sample spans at most two bytes"
        pair = groups[:, byte].astype(np.uint16)
        if shift + layout.bits > 8:
            pair |= groups[:, byte + 1].astype(np.uint16) << np.uint16(8)
        if shift:
            pair >>= np.uint16(shift)
        np.bitwise_and(pair, mask, out=samples[:, i])
    return samples


def _unpack_gev(groups: np.ndarray, layout: PackedLayout) -> np.ndarray:
    """(n, 3) bytes → (n, 2) samples of the GigE Vision Packed layout."""
    low_bits = layout.bits - 8
    low_mask = np.uint16((1 << low_bits) - 1)
    middle = groups[:, 1].astype(np.uint16)
    samples = np.empty((groups.shape[0], 2), dtype=np.uint16)
    for i, (byte, shift) in enumerate(((0, 0), (2, 4))):  # p0: byte 0 + middle bits 0…; p1: byte 2 + bits 4…
        sample = samples[:, i]
        sample[...] = groups[:, byte]
        sample <<= np.uint16(low_bits)
        sample |= (middle >> np.uint16(shift)) & low_mask
    return samples


def unpack_pixels(
    data: bytes | memoryview | np.ndarray, pixel_format: str, width: int, height: int, where: str = "unpack_pixels"
) -> np.ndarray:
    """Decode one frame of a packed format into an owned, read-only ``uint16`` array.

    ``data`` holds at least :func:`packed_size` bytes (trailing chunk data is ignored); ``width`` must be a
    multiple of the packing group (2 or 4 samples); ``where`` prefixes error messages.

    Returns
    -------
    numpy.ndarray
        (height, width) ``uint16`` raw values in ``0 … 2**bits - 1``, as the sensor delivered them.

    Raises
    ------
    CameraError
        Unknown format, a width the packing group does not divide, or a payload shorter than the frame.

    Examples
    --------
    >>> unpack_pixels(bytes([0x21, 0x43, 0x65]), "Mono12p", 2, 1).tolist()  # 0x321, 0x654
    [[801, 1620]]
    >>> unpack_pixels(bytes([0x32, 0x41, 0x65]), "Mono12Packed", 2, 1).tolist()
    [[801, 1620]]
    """
    layout = _layout(pixel_format, width, height, where)
    n_bytes = width * height // layout.group_pixels * layout.group_bytes
    raw = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1).view(np.uint8)
    if raw.size < n_bytes:
        raise CameraError(
            f"{where}: payload of {raw.size} bytes is too short for {width}x{height} "
            f"{pixel_format}; expected {n_bytes} bytes"
        )
    groups = raw[:n_bytes].reshape(-1, layout.group_bytes)
    unpack = _unpack_pfnc if layout.packing == "pfnc" else _unpack_gev
    pixels = unpack(groups, layout).reshape(height, width)
    pixels.flags.writeable = False
    return pixels
