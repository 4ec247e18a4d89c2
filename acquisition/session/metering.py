"""Metering: how bright a frame is, read on a sample of its pixels.

A pixel's value is its brightest channel; a raw mosaic is read in whole 2 × 2 quads (every colour
of the mosaic), a channel image pixel by pixel, on every ``stride``-th row and column. The *bright
end* of a frame is the value only ``max_saturated_fraction`` of its pixels exceed (as a fraction of
full scale, white − black); its *rates* are (value − black) ÷ exposure, DN/µs. Exposure planning
(:mod:`acquisition.session.exposure`), the LED SNR (:mod:`acquisition.session.led_snr`) and the flash
exposure read frames through here.

**The flash frame's exposure** is predicted from the ambient and LED frames already taken
(:class:`FlashExposure`): the model is linear (the sensor is), the flash frame's rate at a pixel is
the ambient rate plus Σₖ wₖ·(LEDₖ rate − ambient rate) for flash weights ``w``, so no preview is
needed; its bright end is put at the policy's ``target_fraction`` of full scale.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from msflash.acquisition.session.exposure import ExposurePolicy


@dataclass(frozen=True)
class Levels:
    """One frame, metered."""

    exposure_us: float
    bright_end: float
    """The value only ``max_saturated_fraction`` of pixels exceed, as a fraction of full scale."""
    saturated_fraction: float
    """Fraction of pixels with a channel at or above the white level."""


def metering_view(pixels: np.ndarray, mosaic: bool) -> np.ndarray:
    """A frame as the metering functions here should read it.

    They take an (H, W) frame for a raw mosaic and read it in whole 2×2 quads (every colour of
    the mosaic). A mono camera's (H, W) frame (``mosaic`` False) becomes an (H, W, 1) view, read
    pixel by pixel like any channel image: its bright end is that of its pixels, not of the
    brightest of four neighbours, and a quarter of the values are read. Other frames are returned
    as they are.

    Examples
    --------
    >>> frame = np.zeros((4, 6), dtype=np.uint16)
    >>> metering_view(frame, mosaic=False).shape, metering_view(frame, mosaic=True).shape
    ((4, 6, 1), (4, 6))
    """
    return pixels[:, :, None] if pixels.ndim == 2 and not mosaic else pixels


def sampled(pixels: np.ndarray, stride: int) -> np.ndarray:
    """Every ``stride``-th pixel of a frame, as (h, w[, channels]) — for a one-plane frame whole 2×2 quads.

    Striding a raw mosaic by an even step would read a single CFA site (one colour: a blue LED
    metered on red sites looks dark), so a 2-D frame is sampled as 2×2 quads, each a 4-channel
    "pixel" (every colour of the mosaic; for a mono frame four neighbours), on every
    ``stride / 2``-th quad. ``stride`` 1 keeps the frame.
    """
    if stride <= 1:
        return pixels
    if pixels.ndim == 3:
        return pixels[::stride, ::stride]
    height, width = (pixels.shape[0] // 2) * 2, (pixels.shape[1] // 2) * 2
    if height == 0 or width == 0:
        return pixels[::stride, ::stride]
    step = 2 * max(1, stride // 2)
    # Site (p, q) of every sampled quad is one strided slice: four slice copies, not a reshape of
    # a transposed view (which numpy copies element by element, far slower: docs/measurements.md).
    first = pixels[0:height:step, 0:width:step]
    quads = np.empty((*first.shape, 4), dtype=pixels.dtype)
    for site, (p, q) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        quads[:, :, site] = pixels[p:height:step, q:width:step]
    return quads


def brightest(pixels: np.ndarray, stride: int) -> np.ndarray:
    return brightest_channel(sampled(pixels, stride))


def brightest_channel(values: np.ndarray) -> np.ndarray:
    """The per-pixel maximum over the channels of (h, w, c) values (a new array); (h, w) values as they are.

    A running ``np.maximum`` over the channel planes: numpy's ``max`` over a short last axis is
    several times slower, and this runs for the flash exposure on the capture's latency path.
    """
    if values.ndim != 3:
        return values
    brightest = values[:, :, 0].copy()
    for channel in range(1, values.shape[2]):
        np.maximum(brightest, values[:, :, channel], out=brightest)
    return brightest


def meter(pixels: np.ndarray, black: float, white: float, policy: ExposurePolicy, exposure_us: float = 0.0) -> Levels:
    """Bright end and saturated fraction of one frame."""
    flat = brightest(np.asarray(pixels), policy.stride).reshape(-1)
    saturated = float(np.count_nonzero(flat >= white)) / flat.size
    q = 1.0 - policy.max_saturated_fraction
    value = linear_quantile(flat, q) if flat.size else 0.0
    return Levels(float(exposure_us), (value - black) / (white - black), saturated)


def clamp(value: float, limits: tuple[float, float]) -> float:
    return float(min(max(value, limits[0]), limits[1]))


def rates(pixels: np.ndarray, exposure_us: float, black: float, stride: int) -> np.ndarray:
    rates = sampled(pixels, stride).astype(np.float64)
    rates -= (
        black  # in place: (sub − black) / exposure without two temporaries (the last frame's is on the latency path)
    )
    rates /= exposure_us
    return rates


def unsaturated(pixels: np.ndarray, white: float, stride: int) -> np.ndarray:
    return brightest(pixels, stride) < white


def linear_quantile(values: np.ndarray, q: float, *, overwrite: bool = False) -> float:
    """``np.quantile(values, q)`` (linear method), bit for bit, from the two order statistics around it.

    The sample at position ``(n − 1)·q`` of the sorted values, interpolated between its two
    neighbours as numpy does (from the upper neighbour when the fraction is ≥ ½); NaN if any value
    is NaN; one ``np.partition``. ``overwrite`` partitions ``values`` in place (the caller's scratch array).

    >>> linear_quantile(np.array([3.0, 1.0, 4.0, 1.0, 5.0]), 0.9)  # sorted 1 1 3 4 5: 0.6 of the way from 4 to 5
    4.6
    """
    flat = values.reshape(-1)
    n = flat.size
    if n == 0:
        raise ValueError("linear_quantile: no values; expected at least one")
    if not 0.0 <= q <= 1.0:
        raise ValueError(f"linear_quantile: q {q}; expected 0 ≤ q ≤ 1")
    position = (n - 1) * q
    below = min(int(math.floor(position)), n - 1)
    above = min(below + 1, n - 1)
    ordered = flat if overwrite else flat.copy()
    ordered.partition(sorted({below, above, n - 1}))
    if flat.dtype.kind == "f" and math.isnan(ordered[n - 1]):
        return math.nan  # NaN sorts last, as in np.quantile
    low, high = float(ordered[below]), float(ordered[above])
    gamma = position - below
    diff = high - low
    return high - diff * (1.0 - gamma) if gamma >= 0.5 else low + diff * gamma


class FlashExposure:
    """The flash frame's exposure, predicted from the ambient and LED frames as they arrive.

    The model is linear: the flash frame's rate (DN/µs) at a pixel is the ambient rate plus
    Σₖ wₖ·(LEDₖ rate − ambient rate) for flash weights ``w``. :meth:`add_ambient` and
    :meth:`add_led` take each frame's rates and LED-only rates (on every ``2·policy.stride``-th row
    and column) when it arrives, between frames; :meth:`predict` then costs only the weighted sum,
    the brightest channel and the bright end: the exposure that puts the bright end (only
    ``max_saturated_fraction`` of pixels brighter) at ``target_fraction`` of full scale, clamped
    to ``limits``.
    """

    def __init__(self, black: float, white: float, limits: tuple[float, float], policy: ExposurePolicy) -> None:
        self.black = float(black)
        self.white = float(white)
        self.limits = limits
        self.policy = policy
        self._stride = policy.stride * 2
        self._ambient_us: float | None = None
        self._ambient_rate: np.ndarray | None = None
        self._led_only: list[np.ndarray] = []

    def add_ambient(self, pixels: np.ndarray, exposure_us: float) -> None:
        """Take the ambient frame (LEDs off); it must come before the LED frames."""
        if self._ambient_rate is not None:
            raise ValueError("flash exposure: a second ambient frame; expected one ambient frame per capture")
        self._ambient_us = float(exposure_us)
        self._ambient_rate = rates(pixels, exposure_us, self.black, self._stride)

    def add_led(self, pixels: np.ndarray, exposure_us: float) -> None:
        """Take the next LED frame (its LED-only rate: frame rate − ambient rate)."""
        if self._ambient_rate is None:
            raise ValueError("flash exposure: an LED frame before the ambient frame; expected the ambient first")
        led_only = rates(pixels, exposure_us, self.black, self._stride)
        led_only -= self._ambient_rate
        self._led_only.append(led_only)

    def predict(self, weights: Sequence[float] | np.ndarray) -> float:
        """The flash exposure (µs) for LED weights ``weights`` (one per LED frame added)."""
        if self._ambient_rate is None or self._ambient_us is None:
            raise ValueError("flash exposure: no ambient frame; expected the ambient and LED frames first")
        total = self._ambient_rate.copy()
        for led_only, weight in zip(self._led_only, weights, strict=True):
            if weight > 0:
                total += weight * led_only
        rate = linear_quantile(brightest_channel(total), 1.0 - self.policy.max_saturated_fraction, overwrite=True)
        if not rate > 0:
            return clamp(self._ambient_us, self.limits)
        return clamp(self.policy.target_fraction * (self.white - self.black) / rate, self.limits)


def flash_exposure(
    ambient: np.ndarray,
    ambient_us: float,
    led_frames: Sequence[np.ndarray],
    led_us: Sequence[float],
    weights: Sequence[float] | np.ndarray,
    black: float,
    white: float,
    limits: tuple[float, float],
    policy: ExposurePolicy,
) -> float:
    """Exposure for the flash frame: ambient + Σ wₖ·LEDₖ with its bright end at the target fraction.

    Predicted from the captured frames (the model is linear), so no preview is needed. The
    one-shot form of :class:`FlashExposure` (which takes the frames as they arrive).
    """
    predictor = FlashExposure(black, white, limits, policy)
    predictor.add_ambient(ambient, ambient_us)
    for frame, exposure in zip(led_frames, led_us, strict=True):
        predictor.add_led(frame, exposure)
    return predictor.predict(weights)
