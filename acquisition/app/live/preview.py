"""The live preview: a raw frame → a 640-pixel-wide sRGB JPEG, a histogram and a saturation overlay.

The frame is debayered (2×2 superpixels, :func:`processing.render.demosaic_superpixel`) and mapped to
sRGB with the camera → XYZ matrix fitted on a chart, as the run's previews are
(:mod:`acquisition.app.report`), but with a fixed white: the sensor's full scale is display white, so the
image brightens and darkens with the exposure as a camera viewer's does (the report's previews scale each
image to its own 99.5th percentile). Saturated pixels (a channel within :data:`SATURATION_MARGIN` of the
white level) are painted :data:`OVERLAY_RGB` when the overlay is on. Frames wider than twice the preview
are decimated before the colour step, so the cost follows the preview's size, not the sensor's.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
from PIL import Image

from msflash.acquisition.devices.camera import CameraInfo
from msflash.processing import datasets
from msflash.processing.render import camera_to_srgb_linear, camera_to_xyz_matrix, demosaic_superpixel, encode_srgb
from msflash.processing.spectra import Spectra

PREVIEW_WIDTH = 640
"""Width of the live preview in pixels (the frame is scaled to it, up or down)."""

HISTOGRAM_BINS = 64
"""Bins of the live histogram, over the sensor's range from black to white level."""

SATURATION_MARGIN = 0.002
"""A channel at or above ``white − margin·(white − black)`` counts as saturated."""

OVERLAY_RGB = (255, 0, 255)
"""The saturation overlay's colour (magenta: no chart patch is that colour at full scale)."""

JPEG_QUALITY = 85

ENCODE_STEPS = 4095
"""Linear display values are looked up in a table of this many steps (+1) of the sRGB curve."""


@dataclass(frozen=True)
class Preview:
    """One rendered live frame."""

    jpeg: bytes
    width: int
    height: int
    histogram: tuple[tuple[int, ...], ...]
    """Counts per channel (R, G, B), :data:`HISTOGRAM_BINS` bins from black to white level."""
    saturated_fraction: float
    """The fraction of (debayered) pixels with a saturated channel."""


class PreviewRenderer:
    """Renders a camera's raw frames as live previews (the colour matrix is fitted once).

    Parameters
    ----------
    responsivities
        The camera's spectral responsivities, for the colour matrix; None shows the camera's RGB as sRGB.
    """

    def __init__(self, info: CameraInfo, responsivities: Spectra | None, width: int = PREVIEW_WIDTH) -> None:
        self.cfa = info.cfa
        self.black = float(info.black_level)
        self.white = float(info.white_level)
        self.width = int(width)
        to_xyz = None
        if responsivities is not None:
            grid = responsivities.grid
            chart = datasets.macbeth().resample(grid, outside="edge")
            to_xyz = camera_to_xyz_matrix(
                responsivities.to_unit("photons"), chart, datasets.illuminant("D65", grid).to_unit("photons")
            )
        # Linear maps: the images of the unit vectors give the 3×3 camera → linear sRGB matrix and the Y row.
        srgb_of_basis, y_of_basis = camera_to_srgb_linear(np.eye(3), to_xyz)
        white_y = float(np.sum(y_of_basis)) or 1.0
        # Full scale → display white folded into the matrix; the sRGB curve as a table of ENCODE_STEPS + 1
        # entries made by processing.render.encode_srgb itself (a frame costs a lookup, not the curve).
        self._to_srgb = (np.asarray(srgb_of_basis, dtype=np.float64).T / white_y * ENCODE_STEPS).astype(np.float32)
        self._encode = np.round(encode_srgb(np.linspace(0.0, 1.0, ENCODE_STEPS + 1), 1.0) * 255).astype(np.uint8)

    def camera_rgb(self, pixels: np.ndarray) -> np.ndarray:
        """(H, W, 3) camera RGB in [0, 1] of full scale, debayered and decimated towards the preview's width."""
        raw = np.asarray(pixels)
        if raw.ndim == 2 and self.cfa is not None:
            step = max(1, raw.shape[1] // (4 * self.width)) * 2  # keep the CFA phase: an even stride
            if step > 2:
                raw = raw[: raw.shape[0] // step * step, : raw.shape[1] // step * step]
                raw = raw.reshape(raw.shape[0] // step, step, raw.shape[1] // step, step)[:, :2, :, :2]
                raw = raw.reshape(raw.shape[0] * 2, raw.shape[2] * 2)
            rgb = demosaic_superpixel(raw.astype(np.float32), self.cfa)
        else:
            if raw.ndim == 2:
                raw = raw[:, :, None].repeat(3, axis=2)
            step = max(1, raw.shape[1] // (2 * self.width))
            rgb = raw[::step, ::step].astype(np.float32)
        return (rgb - self.black) / max(self.white - self.black, 1.0)

    def render(self, pixels: np.ndarray, overlay: bool = True) -> Preview:
        """The preview of one raw frame; ``overlay`` paints the saturated pixels."""
        rgb = self.camera_rgb(pixels)
        saturated = np.any(rgb >= 1.0 - SATURATION_MARGIN, axis=2)
        return self.render_rgb(rgb, saturated if overlay else None, float(np.mean(saturated)))

    def render_rgb(
        self,
        rgb: np.ndarray,
        paint: np.ndarray | None = None,
        saturated: float | None = None,
        scale: float = 1.0,
        histogram: bool = True,
    ) -> Preview:
        """The preview of (H, W, 3) camera RGB, ``rgb · scale`` in [0, 1] of display white; ``paint`` marks
        pixels in :data:`OVERLAY_RGB`; ``saturated`` is the fraction reported (default: ``paint``'s); without
        ``histogram`` its counts are all zero (a view that shows none: the flash preview)."""
        # Small integer types and in-place clips: at video rate the passes over the pixels are the cost.
        counts: tuple[tuple[int, ...], ...] = ((0,) * HISTOGRAM_BINS,) * 3
        if histogram:
            scaled = np.multiply(rgb, HISTOGRAM_BINS * scale, dtype=np.float32)
            bins = np.clip(scaled, 0, HISTOGRAM_BINS - 1, out=scaled).astype(np.uint8)
            counts = tuple(
                tuple(int(n) for n in np.bincount(bins[:, :, c].ravel(), minlength=HISTOGRAM_BINS)) for c in range(3)
            )
        rgb8 = self.srgb8(rgb, scale)
        if paint is not None:
            rgb8[paint] = OVERLAY_RGB
        if saturated is None:
            saturated = float(np.mean(paint)) if paint is not None else 0.0
        height = max(1, round(rgb8.shape[0] * self.width / rgb8.shape[1]))
        resample = Image.Resampling.NEAREST if self.width >= rgb8.shape[1] else Image.Resampling.BOX
        image = Image.fromarray(rgb8).resize((self.width, height), resample)
        buffer = io.BytesIO()
        image.save(buffer, "JPEG", quality=JPEG_QUALITY)
        return Preview(buffer.getvalue(), self.width, height, counts, saturated)

    def srgb8(self, rgb: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """(H, W, 3) camera RGB, ``rgb · scale`` in [0, 1] → 8-bit sRGB (the preview's colour step, no resize)."""
        matrix = self._to_srgb.T if scale == 1.0 else (self._to_srgb.T * np.float32(scale)).astype(np.float32)
        linear = np.asarray(rgb, dtype=np.float32) @ matrix
        return self._encode[np.clip(linear, 0, ENCODE_STEPS, out=linear).astype(np.uint16)]
