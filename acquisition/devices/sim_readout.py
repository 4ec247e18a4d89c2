"""The simulated camera's readout: binning, region of interest and pixel format applied to each rendered frame,
with the limits a real camera puts on them.

The world is rendered at the sensor's full size; the readout then bins it, cuts the ROI out and packs the
values into the pixel format, as a camera's FPGA does after the ADC. The twin is as strict as a machine-vision
camera (``ImageLimits`` of :mod:`acquisition.devices.image_format`):

- ``Width`` in steps of :data:`WIDTH_INCREMENT`, ``Height``, ``OffsetX`` and ``OffsetY`` in steps of 2 (a
  mosaic's CFA phase survives any ROI it allows);
- ``BinningHorizontal``/``BinningVertical`` 1 … :data:`MAX_BINNING`; a mosaic is binned colour by colour
  (the mean of like-coloured pixels, so the CFA and the white level stay), an RGB frame pixel by pixel; a
  binning change resets the ROI to the whole binned sensor, as cameras clamp ``Width``;
- ``PixelFormat``: the sensor's layout at 8 bits (the top 8 of the ADC's) or at its own depth
  (``BayerRG8``/``BayerRG12`` for the ``sim`` rig's 12-bit RGGB sensor, ``RGB8``/``RGB12`` for an RGB one,
  ``Mono8``/``Mono12`` for a monochrome one, whose (H, W) frames carry one value a pixel); no other CFA. Formats
  wider than the sensor (the aravis-fake's ``BayerRG16``) carry its values unscaled.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from msflash.acquisition.devices.aravis.camera_features import FeatureInfo
from msflash.acquisition.devices.aravis.pixel_formats import BAYER_CFA
from msflash.acquisition.devices.aravis.pixel_layouts import PIXEL_FORMATS, pixel_layout
from msflash.acquisition.devices.image_format import (
    ImageFormat,
    ImageFormatRequest,
    ImageLimits,
    checked_request,
)

GENICAM_BAYER = {cfa: f"Bayer{code}" for code, cfa in BAYER_CFA.items()}
"""The GenICam name's stem of each mosaic layout (``RGGB`` → ``BayerRG``)."""
WIDTH_INCREMENT = 8
"""The twin's ``Width`` step (machine-vision sensors read out in blocks of 4–16 columns)."""
ROW_INCREMENT = 2
"""The step of ``Height``, ``OffsetX`` and ``OffsetY`` (a 2×2 CFA cell)."""
MAX_BINNING = 2
"""The largest binning factor the twin offers on each axis."""


@dataclass(frozen=True)
class SimReadout:
    """How a rendered frame is read out: the sensor it comes from and the format in force."""

    sensor_shape: tuple[int, int]
    """(height, width) of the rendered frame."""
    cfa: str | None
    bits: int
    """The sensor's ADC depth."""
    binning: tuple[int, int] = (1, 1)
    roi: tuple[int, int, int, int] | None = None
    """None: the whole (binned) sensor."""
    pixel_format: str = ""
    """"" : the sensor's own format (:meth:`native_format`)."""
    mono: bool = False
    """A monochrome sensor (no CFA): the rendered frame's channels are alike and one is read out, (H, W)."""

    @property
    def native_format(self) -> str:
        """The sensor's layout at its own depth (its container's when GenICam has no name for it: the formats
        are :data:`~acquisition.devices.aravis.pixel_layouts.PIXEL_FORMATS`')."""
        own = f"{self._layout}{self.bits}"
        return own if own in PIXEL_FORMATS else f"{self._layout}{8 if self.bits <= 8 else 16}"

    @property
    def _layout(self) -> str:
        if self.mono:
            return "Mono"
        return "RGB" if self.cfa is None else GENICAM_BAYER[self.cfa]

    @property
    def offered_formats(self) -> tuple[str, ...]:
        """``PixelFormat``'s entries: the sensor's layout at 8 bits and at its own depth."""
        return tuple(dict.fromkeys((f"{self._layout}8", self.native_format)))

    @property
    def format(self) -> ImageFormat:
        """The format in force."""
        width, height = self.binned_size
        roi = self.roi or (0, 0, width, height)
        return ImageFormat(roi, self.binning, self.pixel_format or self.native_format)

    @property
    def binned_size(self) -> tuple[int, int]:
        """(width, height) of the sensor after binning (whole CFA cells for a mosaic)."""
        height, width = self.sensor_shape
        cell = 2 if self.cfa is not None else 1
        bh, bv = self.binning
        return width // cell // bh * cell, height // cell // bv * cell

    @property
    def out_bits(self) -> int:
        """The depth of the values delivered: 8 for an 8-bit format, else the sensor's own."""
        return 8 if pixel_layout(self.format.pixel_format, "simulated camera").bits == 8 else self.bits

    def levels(self, black: float, white: float) -> tuple[float, float]:
        """The sensor's black and white levels in the delivered values."""
        shift = 2.0 ** (self.bits - self.out_bits)
        return black / shift, min(white / shift, 2.0**self.out_bits - 1)

    def limits(self, camera: str) -> ImageLimits:
        """What the twin allows now, as GenICam features."""
        width, height = self.binned_size
        x, y, w, h = self.format.roi

        def integer(name: str, value: int, low: int, high: int, step: int) -> FeatureInfo:
            return FeatureInfo(name, "integer", "RW", value, low, high, step)

        features = {
            "BinningHorizontal": integer("BinningHorizontal", self.binning[0], 1, MAX_BINNING, 1),
            "BinningVertical": integer("BinningVertical", self.binning[1], 1, MAX_BINNING, 1),
            "PixelFormat": FeatureInfo(
                "PixelFormat", "enumeration", "RW", self.format.pixel_format, entries=self.offered_formats
            ),
            "OffsetX": integer("OffsetX", x, 0, width - WIDTH_INCREMENT, ROW_INCREMENT),
            "OffsetY": integer("OffsetY", y, 0, height - ROW_INCREMENT, ROW_INCREMENT),
            "Width": integer("Width", w, WIDTH_INCREMENT, width // WIDTH_INCREMENT * WIDTH_INCREMENT, WIDTH_INCREMENT),
            "Height": integer("Height", h, ROW_INCREMENT, height, ROW_INCREMENT),
        }
        return ImageLimits(camera, features, (width, height))

    def applied(self, request: ImageFormatRequest, camera: str) -> SimReadout:
        """This readout with ``request`` in force, refused as a camera would refuse it."""
        checked_request(self.limits(camera), request, self.offered_formats)
        readout = self
        if request.binning is not None and tuple(request.binning) != self.binning:
            readout = replace(readout, binning=tuple(request.binning), roi=None)  # type: ignore[arg-type]
        if request.pixel_format is not None:
            readout = replace(readout, pixel_format=request.pixel_format)
        if request.roi is not None:
            readout.limits(camera).check_roi(request.roi)
            readout = replace(readout, roi=tuple(request.roi))  # type: ignore[arg-type]
        return readout

    def read(self, pixels: np.ndarray) -> np.ndarray:
        """A rendered frame (``sensor_shape``) read out: binned, cut to the ROI, packed into the format (a mono
        sensor's one channel of it)."""
        frame = np.asarray(pixels)
        if self.mono and frame.ndim == 3:
            frame = frame[:, :, 0]
        if self.binning != (1, 1):
            frame = _binned(frame, self.binning, self.cfa is not None).astype(frame.dtype)
        x, y, w, h = self.format.roi
        frame = frame[y : y + h, x : x + w]
        if self.out_bits != self.bits:
            frame = (frame >> (self.bits - self.out_bits)).astype(np.uint8)
        return np.ascontiguousarray(frame)


def _binned(frame: np.ndarray, binning: tuple[int, int], mosaic: bool) -> np.ndarray:
    """The mean of ``binning`` (h, v) blocks; a mosaic's like-coloured pixels (its four CFA planes) separately."""
    bh, bv = binning
    if not mosaic:
        height, width = frame.shape[0] // bv * bv, frame.shape[1] // bh * bh
        cut = frame[:height, :width].astype(np.float64)
        shape = (height // bv, bv, width // bh, bh) + frame.shape[2:]
        return np.round(cut.reshape(shape).mean(axis=(1, 3)))
    height, width = frame.shape[0] // (2 * bv) * 2, frame.shape[1] // (2 * bh) * 2
    out = np.empty((height, width), dtype=np.float64)
    for row in (0, 1):
        for column in (0, 1):
            plane = frame[row::2, column::2][: height // 2 * bv, : width // 2 * bh].astype(np.float64)
            out[row::2, column::2] = plane.reshape(height // 2, bv, width // 2, bh).mean(axis=(1, 3))
    return np.round(out)
