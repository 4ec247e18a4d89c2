"""What a pixel format means and what a buffer's bytes hold: pixel layouts, decoding (a copy) or a view
(zero copy), frame-id gaps.

:data:`PIXEL_FORMATS` is the one table of what a GenICam pixel format means — its mosaic layout, bit depth and
whether frames are mono, a raw mosaic or RGB (:attr:`PixelLayout.kind`). Every path that sets or reads a
camera's format asks it (:func:`pixel_layout`, :func:`camera_pixel_layout`): the camera's
``CameraInfo``, the rigs at open, a live format change; a format it lacks is refused in one line naming the
camera and the format, never recorded as something it is not.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from msflash.acquisition.devices.aravis.pixel_formats import BAYER_CFA, PACKED_FORMATS, unpack_pixels
from msflash.acquisition.errors import CameraError, CameraSettingError

if TYPE_CHECKING:
    from msflash.acquisition.devices.camera import CameraInfo

log = logging.getLogger(__name__)

FrameKind = Literal["mono", "mosaic", "rgb"]
"""What a frame of a pixel format is: one value a pixel (``mono``), a raw CFA mosaic, or three channels."""

GV_FRAME_ID_WRAP = 1 << 16
"""GigE Vision 1.x block ids are 16 bits and skip 0 when they wrap (65535 is followed by 1)."""


@dataclass(frozen=True)
class PixelLayout:
    """How a GenICam pixel format is laid out in a payload."""

    dtype: str
    """numpy dtype of one sample (little endian, as PFNC specifies for GigE Vision and USB3)."""
    channels: int
    """1 for mono and raw mosaics, 3 for RGB."""
    bits: int
    """Significant bits per sample: the white level is ``2**bits - 1``."""
    cfa: str | None = None
    """Mosaic layout for Bayer formats."""
    bgr: bool = False
    """Channels are stored B, G, R (reversed to R, G, B on decoding)."""
    packed: bool = False
    """Samples are bit-packed (:mod:`acquisition.devices.aravis.pixel_formats` decodes them to ``uint16``)."""

    @property
    def kind(self) -> FrameKind:
        """``mosaic`` for a Bayer format (:attr:`cfa` its layout), ``rgb`` for three channels, else ``mono``."""
        if self.cfa is not None:
            return "mosaic"
        return "rgb" if self.channels == 3 else "mono"


def _pixel_formats() -> dict[str, PixelLayout]:
    table = {
        "Mono8": PixelLayout("u1", 1, 8),
        "Mono10": PixelLayout("<u2", 1, 10),
        "Mono12": PixelLayout("<u2", 1, 12),
        "Mono14": PixelLayout("<u2", 1, 14),
        "Mono16": PixelLayout("<u2", 1, 16),
        "RGB8": PixelLayout("u1", 3, 8),
        "BGR8": PixelLayout("u1", 3, 8, bgr=True),
        "RGB10": PixelLayout("<u2", 3, 10),
        "RGB12": PixelLayout("<u2", 3, 12),
        "RGB16": PixelLayout("<u2", 3, 16),
    }
    for cfa, pattern in BAYER_CFA.items():
        table[f"Bayer{cfa}8"] = PixelLayout("u1", 1, 8, pattern)
        for bits in (10, 12, 14, 16):
            table[f"Bayer{cfa}{bits}"] = PixelLayout("<u2", 1, bits, pattern)
    for name, packed in PACKED_FORMATS.items():
        table[name] = PixelLayout("<u2", 1, packed.bits, packed.cfa, packed=True)
    return table


PIXEL_FORMATS: dict[str, PixelLayout] = _pixel_formats()
"""Pixel formats msflash decodes: unpacked ones, and the packed 10/12-bit formats of
:data:`acquisition.devices.aravis.pixel_formats.PACKED_FORMATS` (decoded to ``uint16``)."""


def pixel_layout(pixel_format: str, camera: str, hint: str = "") -> PixelLayout:
    """What ``pixel_format`` means (layout, bit depth, :attr:`PixelLayout.kind`), from :data:`PIXEL_FORMATS`;
    ``hint`` ends the refusal's message.

    Raises
    ------
    CameraSettingError
        A format msflash does not decode: one line naming ``camera`` and the format.

    Examples
    --------
    >>> layout = pixel_layout("BayerGR8", "camera X")
    >>> layout.kind, layout.cfa, layout.bits
    ('mosaic', 'GRBG', 8)
    >>> pixel_layout("Mono12p", "camera X").kind, pixel_layout("RGB8", "camera X").kind
    ('mono', 'rgb')
    """
    layout = PIXEL_FORMATS.get(pixel_format)
    if layout is None:
        raise CameraSettingError(
            f"{camera}: pixel format {pixel_format!r} is not one msflash decodes; expected one of "
            f"{', '.join(PIXEL_FORMATS)}{hint}"
        )
    return layout


def camera_pixel_layout(info: CameraInfo) -> PixelLayout:
    """What the pixel format a camera reports in ``info`` means; the rigs ask it at open and after a change.

    Raises
    ------
    CameraSettingError
        A format msflash does not decode, naming the camera (model and serial) and the format.
    """
    camera = f"camera {info.vendor} {info.model} (serial {info.serial})"
    return pixel_layout(info.pixel_format, camera, " (set one with --pixel-format or --feature PixelFormat=…)")


def _frame_shape(
    pixel_format: str, width: int, height: int, n_bytes: int, where: str
) -> tuple[PixelLayout, int, tuple[int, ...]]:
    """The layout of ``pixel_format``, the sample count of one image and the frame's shape.

    Raises :class:`CameraError` for an unknown format (:func:`pixel_layout`) or a payload of ``n_bytes`` too short.
    """
    layout = pixel_layout(pixel_format, where)
    n = width * height * layout.channels
    itemsize = np.dtype(layout.dtype).itemsize
    if n_bytes < n * itemsize:
        raise CameraError(
            f"{where}: payload of {n_bytes} bytes is too short for {width}x{height} "
            f"{pixel_format}; expected {n * itemsize} bytes"
        )
    shape = (height, width) if layout.channels == 1 else (height, width, layout.channels)
    return layout, n, shape


def decode_pixels(
    data: bytes | memoryview, pixel_format: str, width: int, height: int, where: str = "decode_pixels"
) -> np.ndarray:
    """Turn an image payload (at least ``width * height * channels * itemsize`` bytes) into an owned,
    read-only array of raw linear values; ``where`` prefixes error messages.

    Returns
    -------
    numpy.ndarray
        (height, width) for mono and mosaics, (height, width, 3) in R, G, B order for colour;
        ``uint8`` or ``uint16`` values as the sensor delivered them.

    Raises
    ------
    CameraError
        Unknown pixel format or a payload shorter than the image.
    """
    if pixel_format in PACKED_FORMATS:
        return unpack_pixels(data, pixel_format, width, height, where=where)
    layout, n, shape = _frame_shape(pixel_format, width, height, len(data), where)
    flat = np.frombuffer(data, dtype=layout.dtype, count=n)
    native = np.dtype(layout.dtype).newbyteorder("=")
    # An array over immutable ``bytes`` (what PyGObject's Buffer.get_data returns, already a copy
    # of the Aravis buffer) is safe to keep without another 2.6 MB copy per frame.
    owned = isinstance(data, bytes) and flat.dtype == native
    pixels = flat.reshape(shape) if owned else flat.reshape(shape).astype(native, copy=True)
    if layout.bgr:
        pixels = np.ascontiguousarray(pixels[..., ::-1])
    pixels.flags.writeable = False
    return pixels


def is_zero_copy_format(pixel_format: str) -> bool:
    """Whether a payload of ``pixel_format`` already is its frame, so :func:`view_pixels` applies.

    True for the formats of :data:`PIXEL_FORMATS` stored in this host's byte order and in R, G, B
    order (mono, Bayer, RGB8, RGB16); False for BGR8 (reordered), packed and unknown formats.

    Examples
    --------
    >>> is_zero_copy_format("Mono16"), is_zero_copy_format("BayerRG8"), is_zero_copy_format("BGR8")
    (True, True, False)
    >>> is_zero_copy_format("Mono12p")
    False
    """
    layout = PIXEL_FORMATS.get(pixel_format)
    return layout is not None and not layout.bgr and not layout.packed and np.dtype(layout.dtype).isnative


def view_pixels(
    payload: np.ndarray, pixel_format: str, width: int, height: int, where: str = "view_pixels"
) -> np.ndarray:
    """The frame inside ``payload`` (a byte array), as a read-only view: no copy.

    The result has the shape and dtype :func:`decode_pixels` gives and keeps ``payload`` alive.

    Raises
    ------
    CameraError
        A format :func:`is_zero_copy_format` refuses, or a payload shorter than the image.
    """
    if not is_zero_copy_format(pixel_format):
        raise CameraError(
            f"{where}: pixel format {pixel_format!r} needs decoding; expected one is_zero_copy_format accepts"
        )
    layout, n, shape = _frame_shape(pixel_format, width, height, payload.nbytes, where)
    dtype = np.dtype(layout.dtype)
    pixels = payload[: n * dtype.itemsize].view(dtype).reshape(shape)
    pixels.flags.writeable = False
    return pixels


def frame_id_gap(previous: int, current: int, wrap: int | None = GV_FRAME_ID_WRAP, skip_zero: bool = True) -> int:
    """Number of frame ids missing between two consecutive frames ``previous`` and ``current``.

    Parameters
    ----------
    wrap
        Modulus of the counter (``1 << 16`` for GigE Vision 1.x block ids), or ``None`` for a
        counter that does not wrap.
    skip_zero
        The counter skips 0 when it wraps (GigE Vision block ids run 1..65535).

    Returns
    -------
    int
        0 when ``current`` follows ``previous``; the number of skipped ids otherwise. A counter
        that went backwards without wrapping (a restarted camera) counts as ``-1``.

    Examples
    --------
    >>> frame_id_gap(65534, 65535), frame_id_gap(65535, 1), frame_id_gap(10, 13)
    (0, 0, 2)
    """
    if wrap is None:
        return current - previous - 1 if current > previous else -1
    step = (current - previous) % wrap
    if skip_zero and current < previous and step > 0:
        step -= 1  # id 0 is never sent after a wrap
    return step - 1 if step > 0 else -1
