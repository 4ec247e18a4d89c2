"""PNG files a viewer shows as sRGB: the ``sRGB`` chunk (with ``gAMA``/``cHRM`` for old readers), previews enlarged.

Every PNG msflash writes (previews and plots) goes through :func:`srgb_png_bytes`, so a
colour-managed viewer or browser knows the pixels are sRGB rather than guessing. The chunks are
the PNG specification's (§11.3.3.5, and its recommended fallback ``gAMA`` 45455 and sRGB's
``cHRM``); no ICC profile is embedded (the specification says ``iCCP`` and ``sRGB`` should not
both be present).

Previews of small frames (the sim rig's chart is 112 × 106 pixels) are enlarged by an integer
factor, nearest neighbour, until the long side reaches :data:`PREVIEW_LONG_SIDE_PX`: every
camera pixel becomes a square block, no interpolated colour is invented, and the image is large
enough to look at on a screen.
"""

from __future__ import annotations

import io
import math
import struct
from collections.abc import Mapping
from pathlib import Path

import numpy as np

PREVIEW_LONG_SIDE_PX = 1024
"""Smallest long side of a written preview (pixels); smaller images are enlarged by an integer factor."""
PNG_COMPRESS_LEVEL = 1
"""zlib level of written PNGs: the fastest (blocks of equal pixels compress well at any level;
docs/measurements-acquisition.md)."""
SRGB_RENDERING_INTENT = 0
"""The ``sRGB`` chunk's rendering intent: 0, perceptual."""
SRGB_GAMMA = 45455
"""The ``gAMA`` value the PNG specification gives for sRGB (1/2.2 × 100000)."""
SRGB_CHROMATICITIES = (31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000)
"""The ``cHRM`` values of sRGB: white, red, green, blue x, y × 100000 (D65 and the Rec. 709 primaries)."""


def enlargement(shape: tuple[int, ...], long_side_px: int = PREVIEW_LONG_SIDE_PX) -> int:
    """The integer factor that brings the long side of ``shape`` (H, W, …) to at least ``long_side_px``.

    Examples
    --------
    >>> enlargement((106, 112, 3)), enlargement((2000, 3000, 3)), enlargement((0, 0, 3))
    (10, 1, 1)
    """
    longest = max(int(shape[0]), int(shape[1]))
    return max(1, math.ceil(long_side_px / longest)) if longest > 0 else 1


def enlarged(rgb8: np.ndarray, long_side_px: int = PREVIEW_LONG_SIDE_PX) -> np.ndarray:
    """``rgb8`` with every pixel repeated ``enlargement`` times in both directions (nearest neighbour)."""
    factor = enlargement(rgb8.shape, long_side_px)
    if factor == 1:
        return rgb8
    return np.repeat(np.repeat(rgb8, factor, axis=0), factor, axis=1)


def srgb_png_bytes(rgb8: np.ndarray, text: Mapping[str, str] | None = None) -> bytes:
    """An (H, W, 3) or (H, W, 4) uint8 sRGB image as PNG bytes with the sRGB chunks and optional text chunks."""
    from PIL import Image, PngImagePlugin

    pixels = np.ascontiguousarray(rgb8)
    if pixels.dtype != np.uint8 or pixels.ndim != 3 or pixels.shape[2] not in (3, 4):
        raise ValueError(f"PNG: image of dtype {pixels.dtype} and shape {pixels.shape}; expected uint8 (H, W, 3|4)")
    info = PngImagePlugin.PngInfo()
    info.add(b"sRGB", bytes([SRGB_RENDERING_INTENT]))
    info.add(b"gAMA", struct.pack(">I", SRGB_GAMMA))
    info.add(b"cHRM", struct.pack(">8I", *SRGB_CHROMATICITIES))
    for key, value in (text or {}).items():
        info.add_text(key, value)
    buffer = io.BytesIO()
    Image.fromarray(pixels, "RGB" if pixels.shape[2] == 3 else "RGBA").save(
        buffer, format="PNG", pnginfo=info, compress_level=PNG_COMPRESS_LEVEL
    )
    return buffer.getvalue()


def write_srgb_png(path: Path, rgb8: np.ndarray, text: Mapping[str, str] | None = None) -> Path:
    """Write :func:`srgb_png_bytes` of ``rgb8`` to ``path``; return the path."""
    path = Path(path)
    path.write_bytes(srgb_png_bytes(rgb8, text))
    return path
