"""Exposure planning: meter the ambient, then expose each LED frame for SNR below saturation.

Two steps, both on short host-paced previews that are never written to the sequence:

1. **Ambient auto-exposure.** Ambient previews (LEDs off) are taken until the *bright end* — the
   pixel value that only ``max_saturated_fraction`` of the pixels exceed (a pixel's value is its
   brightest channel) — sits at ``target_fraction`` of full scale (white − black) within
   ``tolerance``. Too bright (more than ``max_saturated_fraction`` saturated) divides the exposure
   by 4; otherwise the exposure is scaled by target ÷ bright end (at most ×16 per preview; the
   sensor is linear, so one unsaturated preview usually suffices). Clamped to the camera's range.
2. **LED exposures.** One preview of ambient + each LED, at ``led_preview_fraction`` of the
   ambient exposure (shorter, so that even a strong LED rarely saturates; a saturated preview is
   retaken 4× shorter), gives each pixel's rate with the LED on (DN/µs). Each LED frame then gets
   the longest exposure whose bright end of ambient + LED stays at ``headroom_fraction`` of full
   scale — the LED-only difference's SNR only grows with exposure — clamped to the camera's range.

**SNR** of an LED-only image (LED frame ÷ its exposure − ambient frame ÷ its exposure) is the
median over unsaturated pixels of signal ÷ noise:

- with a noise model (conversion gain ``electrons_per_dn`` and read noise, from the simulated
  sensor or the camera's profile): variance of a value ``S`` DN is ``S·g/e + (σ_r·g/e)²`` at gain
  ``g``, propagated through the difference (method ``"photon+read noise"``);
- otherwise from the difference image itself: the noise is read from the median of the diagonal
  Haar details of 2 × 2 cells of same-colour pixels, which cancel edges along the rows or columns
  (method ``"difference image"``; :func:`snr_from_difference`); predictions then scale the preview's
  SNR by √(exposure ratio).

The planned SNR is a prediction from the previews; :func:`measure_led_snr` measures it on the
frames actually captured.

**No LED signal is a warning, not a number.** An SNR that is not a finite positive number of
plausible size — NaN (no pixel to measure on), infinite or above :data:`MAX_PLAUSIBLE_SNR` (a
difference image without noise: identical or synthetic frames), zero or negative (the LED frame is
no brighter than the ambient) — is never printed or recorded as a figure: :func:`led_snr_problem`
says which, :func:`led_snr_warnings` names the LED, and JSON holds ``null`` in its place.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from msflash.acquisition.session import exposure_information as info
from msflash.processing.noise_level import CHI2_1_MEDIAN, haar_details

DEFAULT_EXPOSURE_RANGE_US = (1.0, 10_000_000.0)
"""Exposure limits assumed for a camera that does not report its own."""

MAX_PLAUSIBLE_SNR = 1e6
"""Above this a per-pixel LED SNR is no measurement: photon noise bounds a pixel's SNR by √(full well),
about 10³ for any sensor below 10¹² electrons, so a larger figure means the noise was not seen
(issue 29 saw 1.5e+15 on the GigE fake's test patterns)."""

MAX_INFORMATION_BLOCKS = 4096
"""The information criterion looks at most at this many blocks (evenly spaced) of a large frame."""

CRITERIA = ("bright_end", "information")
"""The exposure criteria :class:`ExposurePolicy` offers."""


@dataclass(frozen=True)
class ExposurePolicy:
    """What auto-exposure aims for."""

    max_saturated_fraction: float = 0.001
    """At most this fraction of pixels may saturate in any planned frame (0.1 %)."""
    target_fraction: float = 0.7
    """Ambient frame: the bright end sits at this fraction of full scale."""
    headroom_fraction: float = 0.9
    """LED and flash frames: the bright end of ambient + LEDs stays at or below this fraction."""
    tolerance: float = 0.1
    """Ambient metering stops when the bright end is within this relative distance of the target."""
    max_previews: int = 8
    """Ambient previews at most."""
    led_preview_fraction: float = 0.25
    """LED previews are taken at this fraction of the ambient exposure."""
    min_snr: float = 1.0
    """Planned LED SNR (median pixel) below this is reported as a warning. Per pixel, so modest: the
    estimate pools every pixel and bins 4×4 blocks (×4 SNR) first."""
    stride: int = 2
    """Metering looks at every ``stride``-th row and column (4× fewer pixels by default)."""
    criterion: str = "bright_end"
    """How exposures are chosen: ``"bright_end"`` (the ambient's bright end at ``target_fraction``, each
    LED frame's at ``headroom_fraction``; at most ``max_saturated_fraction`` saturated per frame) or
    ``"information"`` (starting from the bright-end plan, the ambient and LED exposures that maximise the
    information the unsaturated blocks carry about the LED-only signals; see
    :mod:`acquisition.session.exposure_information`). Not the default: it lowers the sim's mean spectrum RMSE
    by 12 % but raises it under the underwater ambient, and the blocks it gives up (up to
    ``max_lost_fraction``: the chart's white patches) are missing from the synthesised images too."""
    max_lost_fraction: float = 0.25
    """Information criterion: at most this fraction of the estimator's blocks may be lost to saturation
    in the union of the frames (a guard; the criterion itself weighs what a lost block costs)."""
    block_size: int = 4
    """The estimator's block (pixels per side, per CFA plane for a mosaic): a block saturated in any frame
    is dropped from every frame (``processing/statistics.py``)."""
    anti_flicker: str = "off"
    """``--anti-flicker``: ``50`` or ``60`` (the mains in Hz), ``auto`` or ``off``: exposures rounded to whole
    flicker periods where they allow (:mod:`acquisition.session.anti_flicker`)."""

    def __post_init__(self) -> None:
        if self.anti_flicker not in ("off", "50", "60", "auto"):
            raise ValueError(f"anti_flicker {self.anti_flicker!r}; expected off, 50, 60 or auto")
        if self.criterion not in CRITERIA:
            raise ValueError(f"criterion {self.criterion!r}; expected one of {', '.join(CRITERIA)}")
        if not 0 <= self.max_lost_fraction < 1:
            raise ValueError(f"max_lost_fraction {self.max_lost_fraction}; expected 0 ≤ f < 1")
        if self.block_size < 1:
            raise ValueError(f"block_size {self.block_size}; expected ≥ 1")
        if not 0 <= self.max_saturated_fraction < 0.5:
            raise ValueError(f"max_saturated_fraction {self.max_saturated_fraction}; expected 0 ≤ f < 0.5")
        if not 0 < self.target_fraction <= self.headroom_fraction <= 1:
            raise ValueError(
                f"target {self.target_fraction}, headroom {self.headroom_fraction}; expected 0 < target ≤ headroom ≤ 1"
            )


@dataclass(frozen=True)
class NoiseModel:
    """Sensor noise in the units of the pixel values."""

    electrons_per_dn: float
    """Conversion gain at gain 1 (electrons per DN)."""
    read_noise_e: float
    """Read noise, electrons."""

    def variance_dn(self, signal_dn: np.ndarray, gain: float = 1.0) -> np.ndarray:
        """Variance (DN²) of a value ``signal_dn`` above black: photon + read noise."""
        dn_per_e = gain / self.electrons_per_dn
        return np.maximum(signal_dn, 0.0) * dn_per_e + (self.read_noise_e * dn_per_e) ** 2


@dataclass(frozen=True)
class Levels:
    """One frame, metered."""

    exposure_us: float
    bright_end: float
    """The value only ``max_saturated_fraction`` of pixels exceed, as a fraction of full scale."""
    saturated_fraction: float
    """Fraction of pixels with a channel at or above the white level."""


@dataclass
class ExposurePlan:
    """Chosen exposures and what they are expected to give."""

    ambient_exposure_us: float
    led_exposures_us: tuple[float, ...]
    predicted_snr: tuple[float, ...]
    snr_method: str
    exposure_range_us: tuple[float, float]
    policy: ExposurePolicy
    previews: list[dict] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    mode: str = "auto"
    lost_block_fraction: float | None = None
    """Information criterion: the predicted fraction of the estimator's blocks saturated in some frame."""
    ambient_gain: float = 1.0
    """Analogue gain of the ambient frame (a replay's recorded gain; 1 otherwise)."""
    led_gains: tuple[float, ...] | None = None
    """Analogue gain of each LED frame (a replay's recorded gains), or None for ``ambient_gain``."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (for the sequence's ``extra`` and run.json)."""
        return {
            "mode": self.mode,
            "ambient_exposure_us": self.ambient_exposure_us,
            "led_exposures_us": list(self.led_exposures_us),
            "predicted_led_snr": [snr_or_none(v) for v in self.predicted_snr],
            "snr_method": self.snr_method,
            "exposure_range_us": list(self.exposure_range_us),
            "policy": asdict(self.policy),
            "previews": self.previews,
            "warnings": list(self.warnings),
            "lost_block_fraction": self.lost_block_fraction,
        }


# -- an LED's SNR: a figure, or a warning ---------------------------------------------------------


def led_snr_problem(snr: float) -> str | None:
    """Why an LED's SNR is no measurement (the LED shows no signal), or None when it is one.

    Examples
    --------
    >>> led_snr_problem(12.5) is None
    True
    >>> led_snr_problem(float("inf"))
    'no LED signal measurable: the LED-only image has no noise (identical or synthetic frames)'
    >>> led_snr_problem(-0.4)
    'no LED signal: its frame is no brighter than the ambient frame (SNR -0.4)'
    """
    if math.isnan(snr):
        return "no LED signal measured: too few unsaturated pixels in its frame and the ambient frame"
    if snr > MAX_PLAUSIBLE_SNR:
        return "no LED signal measurable: the LED-only image has no noise (identical or synthetic frames)"
    if snr <= 0:
        shown = f" (SNR {snr:.3g})" if snr > -MAX_PLAUSIBLE_SNR else ""
        return f"no LED signal: its frame is no brighter than the ambient frame{shown}"
    return None


def snr_or_none(snr: float) -> float | None:
    """``snr`` when it is a measurement (:func:`led_snr_problem`), else None (``null`` in JSON)."""
    return None if led_snr_problem(snr) is not None else float(snr)


def led_snr_warnings(names: Sequence[str], snrs: Sequence[float], what: str = "SNR") -> list[str]:
    """One warning per LED whose SNR is no measurement, naming the LED (``what``: planned or measured).

    Examples
    --------
    >>> led_snr_warnings(["led440", "led480"], [8.0, float("nan")], "measured SNR")
    ['LED led480: measured SNR: no LED signal measured: too few unsaturated pixels in its frame and the ambient frame']
    """
    return [
        f"LED {name}: {what}: {problem}"
        for name, snr in zip(names, snrs, strict=True)
        if (problem := led_snr_problem(snr)) is not None
    ]


def format_led_snr(names: Sequence[str], snrs: Sequence[float]) -> str:
    """The LEDs' SNR for a progress line: figures, and ``no signal`` where there is none.

    Examples
    --------
    >>> format_led_snr(["a", "b"], [3.14159, -4e14])
    'a 3.14, b no signal'
    """
    return ", ".join(
        f"{name} {snr:.3g}" if led_snr_problem(snr) is None else f"{name} no signal"
        for name, snr in zip(names, snrs, strict=True)
    )


# -- what a camera offers ----------------------------------------------------------------------


def camera_exposure_range(camera: Any) -> tuple[float, float]:
    """The camera's exposure range (µs), or :data:`DEFAULT_EXPOSURE_RANGE_US`."""
    found = getattr(camera, "exposure_range_us", None)
    if found:
        low, high = float(found[0]), float(found[1])
        if 0 <= low < high:
            return max(low, DEFAULT_EXPOSURE_RANGE_US[0]), high
    return DEFAULT_EXPOSURE_RANGE_US


def camera_noise_model(camera: Any) -> NoiseModel | None:
    """The sensor's noise model: a simulated sensor's, or the camera's ``noise_model`` (profile), or None."""
    sensor = getattr(camera, "sensor", None)
    if sensor is not None and hasattr(sensor, "electrons_per_dn"):
        return NoiseModel(float(sensor.electrons_per_dn), float(sensor.read_noise_e))
    model = getattr(camera, "noise_model", None)
    if isinstance(model, NoiseModel):
        return model
    if model is not None:
        return NoiseModel(float(model[0]), float(model[1]))
    return None


# -- metering ----------------------------------------------------------------------------------


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


def _sample(pixels: np.ndarray, stride: int) -> np.ndarray:
    """Every ``stride``-th pixel of a frame, as (h, w[, channels]) — for a one-plane frame whole 2×2 quads.

    Striding a raw mosaic by an even step would read a single CFA site (one colour: a blue LED
    metered on red sites looks dark), so a 2-D frame is sampled as 2×2 quads, each a 4-channel
    "pixel" (every colour of the mosaic; for a mono frame four neighbours), on every
    ``stride / 2``-th quad — the same number of values as before. ``stride`` 1 keeps the frame.
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
    # a transposed view (which numpy copies element by element, ~20× slower on the capture path).
    first = pixels[0:height:step, 0:width:step]
    quads = np.empty((*first.shape, 4), dtype=pixels.dtype)
    for site, (p, q) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        quads[:, :, site] = pixels[p:height:step, q:width:step]
    return quads


def _brightest(pixels: np.ndarray, stride: int) -> np.ndarray:
    return _brightest_channel(_sample(pixels, stride))


def _brightest_channel(values: np.ndarray) -> np.ndarray:
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
    brightest = _brightest(np.asarray(pixels), policy.stride)
    flat = brightest.reshape(-1)
    saturated = float(np.count_nonzero(flat >= white)) / flat.size
    q = 1.0 - policy.max_saturated_fraction
    value = linear_quantile(flat, q) if flat.size else 0.0
    return Levels(float(exposure_us), (value - black) / (white - black), saturated)


def _clamp(value: float, limits: tuple[float, float]) -> float:
    return float(min(max(value, limits[0]), limits[1]))


def auto_ambient_exposure(
    capture: Callable[[float], np.ndarray],
    start_us: float,
    black: float,
    white: float,
    limits: tuple[float, float],
    policy: ExposurePolicy,
) -> tuple[float, np.ndarray, float, list[Levels], list[str]]:
    """Meter ambient previews until the bright end sits at the target.

    ``capture(exposure_us)`` returns an ambient frame. Returns the chosen exposure, the last
    unsaturated preview and its exposure (for the LED rates), every preview metered, and warnings.
    """
    exposure = _clamp(start_us, limits)
    metered: list[Levels] = []
    notes: list[str] = []
    good: tuple[np.ndarray, float] | None = None
    for _ in range(policy.max_previews):
        pixels = capture(exposure)
        levels = meter(pixels, black, white, policy, exposure)
        metered.append(levels)
        if levels.saturated_fraction > policy.max_saturated_fraction:
            if exposure <= limits[0]:
                notes.append(
                    f"ambient too bright: {levels.saturated_fraction:.2%} of pixels saturate at the "
                    f"camera's shortest exposure {limits[0]:g} µs; reduce the light or the aperture"
                )
                good = (pixels, exposure)
                break
            exposure = _clamp(exposure / 4.0, limits)
            continue
        good = (pixels, exposure)
        factor = policy.target_fraction / levels.bright_end if levels.bright_end > 0 else 16.0
        if abs(factor - 1.0) <= policy.tolerance:
            break
        proposed = _clamp(exposure * min(max(factor, 1 / 16), 16.0), limits)
        if proposed == exposure:
            if factor > 1:
                notes.append(
                    f"ambient too dark: at the camera's longest exposure {limits[1]:g} µs the bright end "
                    f"is {levels.bright_end:.1%} of full scale (target {policy.target_fraction:.0%}); "
                    "add light, open the aperture or raise the gain"
                )
            break
        exposure = proposed
        if 1 / 16 < factor < 16.0 and levels.bright_end >= 0.02:
            break  # a well-measured unsaturated preview: the sensor is linear, the prediction lands on target
    else:
        notes.append(f"ambient metering did not settle in {policy.max_previews} previews")
    if good is None:
        good = (pixels, metered[-1].exposure_us)
    return exposure, good[0], good[1], metered, notes


def _rates(pixels: np.ndarray, exposure_us: float, black: float, stride: int) -> np.ndarray:
    rates = _sample(pixels, stride).astype(np.float64)
    rates -= (
        black  # in place: (sub − black) / exposure without two temporaries (the last frame's is on the latency path)
    )
    rates /= exposure_us
    return rates


def _valid(pixels: np.ndarray, white: float, stride: int) -> np.ndarray:
    return _brightest(pixels, stride) < white


def snr_with_model(
    ambient_rate: np.ndarray,
    led_rate: np.ndarray,
    ambient_us: float,
    led_us: float,
    noise: NoiseModel,
    valid: np.ndarray,
    gain: float = 1.0,
) -> float:
    """Median SNR of the LED-only rate image for frames at these exposures, from expected values."""
    signal = led_rate - ambient_rate
    variance = (
        noise.variance_dn(led_rate * led_us, gain) / led_us**2
        + noise.variance_dn(ambient_rate * ambient_us, gain) / ambient_us**2
    )
    snr = signal / np.sqrt(np.maximum(variance, 1e-30))
    mask = np.broadcast_to(valid[..., None], snr.shape) if snr.ndim == valid.ndim + 1 else valid
    values = snr[mask]
    return float(np.median(values)) if values.size else math.nan


def snr_from_difference(
    ambient: np.ndarray,
    led: np.ndarray,
    ambient_us: float,
    led_us: float,
    black: float,
    white: float,
    cfa: bool = False,
) -> float:
    """Median signal ÷ noise of the LED-only rate image, the noise from the image itself (no sensor model).

    The noise is read from the diagonal Haar detail of 2 × 2 cells of same-colour samples
    (:func:`processing.noise_level.haar_details`): ``median(HH²) = 0.455 · 4σ²`` for noise alone, and an
    edge along the rows or the columns cancels in it. Differences of neighbouring same-colour samples,
    before, held the scene wherever an edge fell between them — on a mosaic, whose same-colour samples
    are 2 pixels apart, a third of them on the sim chart, and the SNR came out half the sensor model's.
    """
    diff = (led.astype(np.float64) - black) / led_us - (ambient.astype(np.float64) - black) / ambient_us
    valid = _brightest(led, 1) < white
    valid &= _brightest(ambient, 1) < white
    mask = np.broadcast_to(valid[..., None], diff.shape) if diff.ndim == 3 else valid
    # Invalid samples as NaN: haar_details leaves out every cell holding one.
    _, diagonal, _, _ = haar_details(np.where(mask, diff, np.nan), 2 if cfa else 1, 0.0, math.inf)
    if diagonal.size < 16:
        return math.nan
    sigma = math.sqrt(float(np.median(np.square(diagonal))) / CHI2_1_MEDIAN / 4.0)
    signal = float(np.median(diff[mask]))
    return signal / sigma if sigma > 0 else math.inf


def plan_exposures(
    capture: Callable[[Sequence[float], float], np.ndarray],
    n_leds: int,
    black: float,
    white: float,
    limits: tuple[float, float],
    noise: NoiseModel | None,
    policy: ExposurePolicy = ExposurePolicy(),
    start_us: float = 10_000.0,
    cfa: bool = False,
    led_names: Sequence[str] | None = None,
) -> ExposurePlan:
    """Auto-exposure for an ambient + each-LED sequence.

    ``capture(levels, exposure_us)`` returns one preview frame with the LEDs at ``levels``;
    ``led_names`` name the LEDs in warnings (``1`` … ``n`` when None).
    """
    names = list(led_names) if led_names is not None else [str(i + 1) for i in range(n_leds)]
    dark = (0.0,) * n_leds
    ambient_us, ambient_px, ambient_px_us, metered, notes = auto_ambient_exposure(
        lambda e: capture(dark, e), start_us, black, white, limits, policy
    )
    previews = [{"leds": "off", **asdict(m)} for m in metered]
    full = white - black
    stride = policy.stride
    ambient_rate = _rates(ambient_px, ambient_px_us, black, stride)
    ambient_ok = _valid(ambient_px, white, stride)
    led_us: list[float] = []
    led_previews: list[tuple[np.ndarray, float]] = []
    for led in range(n_leds):
        levels = tuple(1.0 if i == led else 0.0 for i in range(n_leds))
        preview_us = _clamp(ambient_us * policy.led_preview_fraction, limits)
        for _ in range(4):
            pixels = capture(levels, preview_us)
            metered_led = meter(pixels, black, white, policy, preview_us)
            previews.append({"leds": f"led {led + 1}", **asdict(metered_led)})
            if metered_led.saturated_fraction <= policy.max_saturated_fraction or preview_us <= limits[0]:
                break
            preview_us = _clamp(preview_us / 4.0, limits)
        led_rate = _rates(pixels, preview_us, black, stride)
        combined = _brightest_channel(led_rate)
        bright_rate = linear_quantile(combined, 1.0 - policy.max_saturated_fraction)
        if bright_rate > 0:
            exposure = _clamp(policy.headroom_fraction * full / bright_rate, limits)
        else:
            exposure = limits[1]
            notes.append(f"LED {names[led]}: no signal in its preview")
        if metered_led.saturated_fraction > policy.max_saturated_fraction:
            exposure = limits[0]
            notes.append(
                f"LED {names[led]}: saturates {metered_led.saturated_fraction:.2%} of pixels at the shortest "
                f"exposure {limits[0]:g} µs; dim the LED"
            )
        led_us.append(exposure)
        led_previews.append((pixels, preview_us))
    lost: float | None = None
    if policy.criterion == "information" and n_leds:
        ambient_us, chosen, lost = _most_informative(
            ambient_px, ambient_px_us, led_previews, ambient_us, led_us, black, white, limits, noise, policy, cfa
        )
        led_us = list(chosen)
    snrs: list[float] = []
    for led, ((pixels, preview_us), exposure) in enumerate(zip(led_previews, led_us, strict=True)):
        if noise is not None:
            led_rate = _rates(pixels, preview_us, black, stride)
            valid = ambient_ok & _valid(pixels, white, stride)
            snr = snr_with_model(ambient_rate, led_rate, ambient_us, exposure, noise, valid)
        else:
            measured = snr_from_difference(ambient_px, pixels, ambient_px_us, preview_us, black, white, cfa)
            snr = measured * math.sqrt(exposure / preview_us) if math.isfinite(measured) else measured
        snrs.append(snr)
        if led_snr_problem(snr) is not None:
            notes.extend(led_snr_warnings([names[led]], [snr], "planned SNR"))
        elif not snr >= policy.min_snr:
            notes.append(
                f"LED {names[led]}: planned SNR {snr:.3g} below {policy.min_snr:g} — the LED is weak against "
                "the ambient; dim the ambient or move the booth closer"
            )
    return ExposurePlan(
        ambient_us,
        tuple(led_us),
        tuple(snrs),
        "photon+read noise" if noise is not None else "difference image",
        limits,
        policy,
        previews,
        notes,
        lost_block_fraction=lost,
    )


def _most_informative(
    ambient_px: np.ndarray,
    ambient_px_us: float,
    led_previews: Sequence[tuple[np.ndarray, float]],
    ambient_us: float,
    led_us: Sequence[float],
    black: float,
    white: float,
    limits: tuple[float, float],
    noise: NoiseModel | None,
    policy: ExposurePolicy,
    cfa: bool,
) -> tuple[float, tuple[float, ...], float]:
    """The information criterion on the previews, from the bright-end plan: ambient and LED exposures, lost fraction.

    Every pixel of the previews (a mosaic's too: each pixel's own channel), grouped by the
    estimator's blocks (``block_size`` per side, per CFA plane: 2·``block_size`` raw pixels).
    """
    block = policy.block_size * (2 if cfa else 1)
    limit_dn = policy.headroom_fraction * (white - black)

    def grouped(pixels: np.ndarray, exposure_us: float) -> tuple[np.ndarray, np.ndarray]:
        rate = info.group_blocks(_rates(pixels, exposure_us, black, 1), block)
        clipped = np.any(info.group_blocks(np.asarray(pixels) >= white, block), axis=1)
        if rate.shape[0] > MAX_INFORMATION_BLOCKS:  # an even sample of the blocks estimates the sums and fractions
            keep = np.linspace(0, rate.shape[0] - 1, MAX_INFORMATION_BLOCKS).astype(int)
            rate, clipped = rate[keep], clipped[keep]
        crossing = info.crossings(rate, clipped, exposure_us, limit_dn)
        return info.thin_members(rate, block, 2 if cfa else 1), crossing

    ambient, ambient_crossing = grouped(ambient_px, ambient_px_us)
    leds = [grouped(pixels, preview_us) for pixels, preview_us in led_previews]
    blocks = info.Blocks(ambient, tuple(r for r, _ in leds), ambient_crossing, tuple(c for _, c in leds))
    dn_per_e = 1.0 / noise.electrons_per_dn if noise is not None else 1.0
    read_dn = noise.read_noise_e * dn_per_e if noise is not None else 0.0
    return info.most_informative(blocks, ambient_us, led_us, limits, dn_per_e, read_dn, policy.max_lost_fraction)


def measure_led_snr(
    ambient: np.ndarray,
    ambient_us: float,
    led_frames: Sequence[np.ndarray],
    led_us: Sequence[float],
    black: float,
    white: float,
    noise: NoiseModel | None,
    cfa: bool = False,
    gain: float = 1.0,
    stride: int = 2,
) -> tuple[list[float], str]:
    """Per-LED SNR of the LED-only images of captured frames, and the method used."""
    values: list[float] = []
    if noise is None:
        for frame, exposure in zip(led_frames, led_us, strict=True):
            values.append(snr_from_difference(ambient, frame, ambient_us, exposure, black, white, cfa))
        return values, "difference image"
    ambient_rate = _rates(ambient, ambient_us, black, stride)
    ambient_ok = _valid(ambient, white, stride)
    for frame, exposure in zip(led_frames, led_us, strict=True):
        rate = _rates(frame, exposure, black, stride)
        valid = ambient_ok & _valid(frame, white, stride)
        values.append(snr_with_model(ambient_rate, rate, ambient_us, exposure, noise, valid, gain))
    return values, "photon+read noise"


def linear_quantile(values: np.ndarray, q: float, *, overwrite: bool = False) -> float:
    """``np.quantile(values, q)`` (linear method), bit for bit, from the two order statistics around it.

    The sample at position ``(n − 1)·q`` of the sorted values, interpolated between its two
    neighbours as numpy does (from the upper neighbour when the fraction is ≥ ½); NaN if any value
    is NaN. One ``np.partition`` instead of ``np.quantile``'s general machinery: half the time on
    the few thousand metered pixels. ``overwrite`` partitions ``values`` in place (the caller's
    scratch array) instead of a copy.

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

    def __init__(
        self, black: float, white: float, limits: tuple[float, float], policy: ExposurePolicy = ExposurePolicy()
    ) -> None:
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
        self._ambient_rate = _rates(pixels, exposure_us, self.black, self._stride)

    def add_led(self, pixels: np.ndarray, exposure_us: float) -> None:
        """Take the next LED frame (its LED-only rate: frame rate − ambient rate)."""
        if self._ambient_rate is None:
            raise ValueError("flash exposure: an LED frame before the ambient frame; expected the ambient first")
        led_only = _rates(pixels, exposure_us, self.black, self._stride)
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
        rate = linear_quantile(_brightest_channel(total), 1.0 - self.policy.max_saturated_fraction, overwrite=True)
        if not rate > 0:
            return _clamp(self._ambient_us, self.limits)
        return _clamp(self.policy.target_fraction * (self.white - self.black) / rate, self.limits)


def flash_exposure(
    ambient: np.ndarray,
    ambient_us: float,
    led_frames: Sequence[np.ndarray],
    led_us: Sequence[float],
    weights: Sequence[float] | np.ndarray,
    black: float,
    white: float,
    limits: tuple[float, float],
    policy: ExposurePolicy = ExposurePolicy(),
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


# -- flash energy under PWM dimming (host paced) ------------------------------------------------


class FlashEnergyWarning(UserWarning):
    """A frame's LED energy may differ from level × full: a PWM-dimmed booth and an exposure that is
    not a whole number of PWM periods (docs/flash-energy.md)."""


def pwm_energy_error(level: float, exposure_us: float, period_us: float) -> float:
    """The worst relative energy error of an LED PWM-dimmed at ``level`` over an exposure, over all phases.

    ``exposure = n·P + r``: the n whole periods give exactly ``level·n·P``; the remainder ``r``
    collects between ``max(0, r − (1 − level)·P)`` and ``min(r, level·P)`` depending on where it
    cuts the period. 0 for levels 0 and 1 and for whole periods.

    >>> round(pwm_energy_error(0.5, 1000.0, 4096.0), 3), pwm_energy_error(0.5, 8192.0, 4096.0)
    (1.0, 0.0)
    """
    if not 0.0 < level < 1.0 or not exposure_us > 0 or not period_us > 0:
        return 0.0
    remainder = math.fmod(exposure_us, period_us)
    high = level * period_us
    least, most = max(0.0, remainder - (period_us - high)), min(remainder, high)
    wanted = level * remainder
    return max(abs(least - wanted), abs(most - wanted)) / (level * exposure_us)


def whole_pwm_periods(
    exposure_us: float,
    levels: Sequence[float],
    pwm_hz: float,
    limits: tuple[float, float],
    policy: ExposurePolicy = ExposurePolicy(),
) -> tuple[float, str | None]:
    """A frame's exposure for a PWM-dimmed booth (host paced): whole PWM periods, or a warning.

    With every level 0 or 1 nothing changes. Otherwise the exposure becomes the nearest whole
    number of periods, never more than ``headroom_fraction / target_fraction`` of it (the flash
    exposure aims its bright end at the target: longer would saturate) and within the camera's
    ``limits``; when no whole number fits (an exposure shorter than a period), the exposure is kept
    and the warning gives the worst energy error over the fractional levels (:func:`pwm_energy_error`).

    Returns
    -------
    (exposure_us, warning or None)
    """
    fractional = [float(w) for w in levels if 0.0 < float(w) < 1.0]
    if not fractional or not pwm_hz > 0:
        return exposure_us, None
    period = 1e6 / pwm_hz
    longest = exposure_us * policy.headroom_fraction / policy.target_fraction
    candidates = [n * period for n in (math.floor(exposure_us / period), math.ceil(exposure_us / period)) if n >= 1]
    fitting = [c for c in candidates if c <= longest and limits[0] <= c <= limits[1]]
    if fitting:
        return min(fitting, key=lambda c: abs(c - exposure_us)), None
    error = max(pwm_energy_error(w, exposure_us, period) for w in fractional)
    return exposure_us, (
        f"flash exposure {exposure_us:.0f} µs: the booth dims by PWM at {pwm_hz:g} Hz (a {period:.0f} µs period) "
        f"when the host paces it, and no whole number of periods fits this exposure, so a frame's LED "
        f"energy may be off by up to {error:.0%} of its level; expected --sync booth or camera (the booth "
        "then pulses each LED for level × exposure) or a longer exposure"
    )
