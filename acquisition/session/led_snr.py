"""An LED's SNR: the sensor's noise, the LED-only image's SNR, and no signal as a warning.

**SNR** of an LED-only image (LED frame ÷ its exposure − ambient frame ÷ its exposure) is the
median over unsaturated pixels of signal ÷ noise:

- with a noise model (conversion gain ``electrons_per_dn`` and read noise, from the simulated
  sensor or the camera's profile): variance of a value ``S`` DN is ``S·g/e + (σ_r·g/e)²`` at gain
  ``g``, propagated through the difference (method ``"photon+read noise"``);
- otherwise from the difference image itself: the noise is read from the median of the diagonal
  Haar details of 2 × 2 cells of same-colour pixels, which cancel edges along the rows or columns
  (method ``"difference image"``; :func:`snr_from_difference`); predictions then scale the preview's
  SNR by √(exposure ratio).

Exposure planning predicts it from the previews; :func:`measure_led_snr` measures it on the frames
actually captured.

**No LED signal is a warning, not a number.** An SNR that is not a finite positive number of
plausible size — NaN (no pixel to measure on), infinite or above :data:`MAX_PLAUSIBLE_SNR` (a
difference image without noise: identical or synthetic frames), zero or negative (the LED frame is
no brighter than the ambient) — is never printed or recorded as a figure: :func:`led_snr_problem`
says which, :func:`led_snr_warnings` names the LED, and JSON holds ``null`` in its place.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from msflash.acquisition.session.metering import brightest, rates, unsaturated
from msflash.processing.noise_level import CHI2_1_MEDIAN, haar_details

MAX_PLAUSIBLE_SNR = 1e6
"""Above this a per-pixel LED SNR is no measurement: photon noise bounds a pixel's SNR by √(full well),
about 10³ for any sensor below 10¹² electrons, so a larger figure means the noise was not seen."""


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


def snr_with_model(
    ambient_rate: np.ndarray,
    led_rate: np.ndarray,
    ambient_us: float,
    led_us: float,
    noise: NoiseModel,
    valid: np.ndarray,
    gain: float = 1.0,
    led_gain: float | None = None,
) -> float:
    """Median SNR of the LED-only rate image for frames at these exposures, from expected values.

    Rates are DN per µs at each frame's own gain: ``gain`` the ambient frame's, ``led_gain`` the LED frame's (default
    the same); the LED frame's rate is compared at the ambient's gain.
    """
    scale = 1.0 if led_gain is None else gain / led_gain
    led_gain = gain if led_gain is None else led_gain
    signal = led_rate * scale - ambient_rate
    variance = (
        noise.variance_dn(led_rate * led_us, led_gain) / led_us**2 * scale**2
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
    edge along the rows or the columns cancels in it.
    """
    diff = (led.astype(np.float64) - black) / led_us - (ambient.astype(np.float64) - black) / ambient_us
    valid = brightest(led, 1) < white
    valid &= brightest(ambient, 1) < white
    mask = np.broadcast_to(valid[..., None], diff.shape) if diff.ndim == 3 else valid
    # Invalid samples as NaN: haar_details leaves out every cell holding one.
    _, diagonal, _, _ = haar_details(np.where(mask, diff, np.nan), 2 if cfa else 1, 0.0, math.inf)
    if diagonal.size < 16:
        return math.nan
    sigma = math.sqrt(float(np.median(np.square(diagonal))) / CHI2_1_MEDIAN / 4.0)
    signal = float(np.median(diff[mask]))
    return signal / sigma if sigma > 0 else math.inf


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
    led_gains: Sequence[float] | None = None,
) -> tuple[list[float], str]:
    """Per-LED SNR of the LED-only images of captured frames, and the method used.

    ``gain`` is the ambient frame's gain, ``led_gains`` each LED frame's (default all ``gain``): a frame's values
    are divided by its exposure × gain before the ambient's are taken from them. (Divided by the exposure alone,
    an LED frame at gain 1 after an ambient at gain 1.5 — the independent Bayer sample's — read darker than the
    ambient: "no LED signal" for three LEDs that had one.)
    """
    gains = [gain] * len(led_frames) if led_gains is None else list(led_gains)
    values: list[float] = []
    if noise is None:
        for frame, exposure, led_gain in zip(led_frames, led_us, gains, strict=True):
            # The LED frame's exposure in the ambient's gain units (itself when the gains agree, bit for bit).
            equivalent_us = exposure if led_gain == gain else exposure * led_gain / gain
            values.append(snr_from_difference(ambient, frame, ambient_us, equivalent_us, black, white, cfa))
        return values, "difference image"
    ambient_rate = rates(ambient, ambient_us, black, stride)
    ambient_ok = unsaturated(ambient, white, stride)
    for frame, exposure, led_gain in zip(led_frames, led_us, gains, strict=True):
        rate = rates(frame, exposure, black, stride)
        valid = ambient_ok & unsaturated(frame, white, stride)
        values.append(
            snr_with_model(
                ambient_rate, rate, ambient_us, exposure, noise, valid, gain, None if led_gain == gain else led_gain
            )
        )
    return values, "photon+read noise"
