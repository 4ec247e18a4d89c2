"""LED spectra: peak, FWHM, an emission model, measurement checks, relative power through the camera.

Public objects
--------------
- :class:`LedCharacterisation`, :func:`characterise_led`: peak, centroid, FWHM, the fitted
  emission model and its residual, warnings for saturated or noisy exports.
- :func:`emission_model_Ohno2005`: the asymmetric form of Ohno's LED model that is fitted.
- :func:`relative_power_through_camera`: the LEDs' true power ratios, measured by the camera on a
  white reference (the spectrometer gives shapes; the booth's real drive currents give ratios).

References
----------
Ohno Y. (2005) "Spectral design considerations for white LED color rendering", Opt. Eng. 44(11),
111302: ``S(λ) = [g(λ) + 2 g(λ)⁵] / 3`` with ``g = exp(−((λ − λ0)/Δλ)²)``. Here Δλ differs on
each side of the peak (phosphor tails and packaging make real LEDs skewed); the FWHM of the model
is ``HALF_WIDTH_FACTOR · (Δλ_left + Δλ_right)`` (``(g + 2g⁵)/3 = ½`` at ``|λ − λ0| ≈ 0.461 Δλ``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq, least_squares

from msflash.calibration.errors import CalibrationError
from msflash.calibration.spectrometer import SpectrometerMeasurement
from msflash.processing.led_wavelength import peak_nm as measured_peak_nm
from msflash.processing.spectra import Spectra, require_same_grid

SATURATION_RUN = 3
"""Consecutive samples at the maximum (within :data:`SATURATION_TOLERANCE`) that mark a clipped peak."""
SATURATION_TOLERANCE = 1e-6
"""Relative tolerance for "at the maximum"."""
MIN_SNR = 100.0
"""Peak over the out-of-band noise below which a measurement is called noisy."""
MAX_MODEL_RESIDUAL = 0.05
"""Relative RMS residual of the emission model above which the fit is reported as poor."""


def _half_width_factor() -> float:
    """``x`` with ``g + 2g⁵ = 1.5`` for ``g = exp(−x²)``: the half-maximum point in units of Δλ."""
    return brentq(lambda x: (math.exp(-x * x) + 2 * math.exp(-5 * x * x)) / 3 - 0.5, 0.01, 3.0)


HALF_WIDTH_FACTOR = _half_width_factor()
"""Half maximum of the Ohno model lies at ``|λ − λ0| = HALF_WIDTH_FACTOR · Δλ`` (≈ 0.461)."""


def emission_model_Ohno2005(
    wavelengths_nm: np.ndarray,
    amplitude: float,
    peak_nm: float,
    width_left_nm: float,
    width_right_nm: float,
) -> np.ndarray:
    """Ohno's (2005) LED emission model with a different width on each side of the peak.

    Examples
    --------
    >>> float(emission_model_Ohno2005(np.array([500.0]), 2.0, 500.0, 10.0, 20.0)[0])
    2.0
    """
    wavelengths_nm = np.asarray(wavelengths_nm, dtype=float)
    width = np.where(wavelengths_nm < peak_nm, width_left_nm, width_right_nm)
    g = np.exp(-(((wavelengths_nm - peak_nm) / width) ** 2))
    return amplitude * (g + 2 * g**5) / 3


@dataclass(frozen=True)
class LedCharacterisation:
    """What one LED measurement says."""

    name: str
    """The LED (file stem unless named)."""
    source: str
    """The measurement file."""
    peak_nm: float
    """Wavelength of the maximum (parabolic refinement around the top sample)."""
    centroid_nm: float
    """Power-weighted mean wavelength."""
    fwhm_nm: float
    """Full width at half maximum of the measured samples (linear interpolation at the crossings)."""
    model: dict
    """Fitted :func:`emission_model_Ohno2005` parameters: amplitude, peak_nm, width_left_nm, width_right_nm."""
    model_residual: float
    """RMS of measurement − model relative to the peak."""
    snr: float
    """Peak over the standard deviation of the out-of-band samples (inf when there are none)."""
    saturated: bool
    """The peak is flat-topped: the spectrometer clipped."""
    warnings: tuple[str, ...]
    """Human-readable warnings (saturated, noisy, poor fit, peak near the edge)."""


def _fwhm(wavelengths: np.ndarray, values: np.ndarray, top: int) -> tuple[float, float, float]:
    """FWHM and the two half-maximum crossings around sample ``top`` (edges if never crossed)."""
    half = values[top] / 2
    left = top
    while left > 0 and values[left] > half:
        left -= 1
    right = top
    while right < values.size - 1 and values[right] > half:
        right += 1

    def crossing(i: int, j: int) -> float:
        if values[i] == values[j]:
            return float(wavelengths[i])
        return float(wavelengths[i] + (half - values[i]) * (wavelengths[j] - wavelengths[i]) / (values[j] - values[i]))

    low = crossing(left, left + 1) if values[left] <= half else float(wavelengths[0])
    high = crossing(right - 1, right) if values[right] <= half else float(wavelengths[-1])
    return high - low, low, high


def characterise_led(measurement: SpectrometerMeasurement) -> LedCharacterisation:
    """Peak, FWHM, Ohno model fit and checks of one (dark-subtracted) LED measurement.

    Raises
    ------
    CalibrationError
        If the measurement has no clear peak (the maximum is not above twice the median).

    Examples
    --------
    >>> w = np.arange(400.0, 701.0, 1.0)
    >>> m = SpectrometerMeasurement(w, np.exp(-0.5 * ((w - 520) / 10) ** 2), "energy", "g", "g")
    >>> c = characterise_led(m)
    >>> round(c.peak_nm, 1), round(c.fwhm_nm, 1)
    (520.0, 23.6)
    """
    wavelengths, values = measurement.wavelengths_nm, measurement.values
    top = int(np.argmax(values))
    peak_value = float(values[top])
    where = measurement.source
    if not peak_value > 2 * max(float(np.median(values)), 0.0):
        raise CalibrationError(
            f"{where}: no emission peak (maximum {peak_value:g} is not above twice the median "
            f"{float(np.median(values)):g}); expected a narrowband LED measurement"
        )
    notes: list[str] = []
    # Peak: the one number msflash gives an LED's wavelength (parabola through the top sample and its neighbours).
    peak_nm = measured_peak_nm(wavelengths, values)
    if not 0 < top < values.size - 1:
        notes.append(
            f"{where}: the peak lies at the edge of the measured range ({peak_nm:g} nm); the LED may extend beyond it"
        )
    fwhm, low, high = _fwhm(wavelengths, values, top)
    positive = np.clip(values, 0, None)
    centroid = float(np.sum(wavelengths * positive) / np.sum(positive))
    at_max = _flat_top(values, peak_value, where, notes)
    band = max(fwhm, 5.0)
    snr = _peak_snr(wavelengths, values, peak_nm, peak_value, band, where, notes)
    # Ohno 2005 model, asymmetric, fitted on the samples above 2 % of the peak plus a margin.
    fit_mask = np.abs(wavelengths - peak_nm) <= 3 * band + 2 * (wavelengths[1] - wavelengths[0])
    usable = fit_mask & ~(at_max if at_max is not None else np.zeros(values.shape, dtype=bool))
    if np.count_nonzero(usable) < 5:
        usable = fit_mask
    widths = (max(peak_nm - low, 1.0), max(high - peak_nm, 1.0))
    model = _fit_emission_model(wavelengths, values, usable, peak_nm, peak_value, widths)
    model_values = emission_model_Ohno2005(wavelengths, *model)
    model_residual = float(np.sqrt(np.mean(((values - model_values) / peak_value)[fit_mask] ** 2)))
    if model_residual > MAX_MODEL_RESIDUAL:
        notes.append(
            f"{where}: the single-peak emission model fits poorly (RMS residual {model_residual:.3f} of "
            "the peak): a phosphor-converted or multi-die LED? The measured spectrum is used, not the model"
        )
    amplitude, fitted_peak, width_left, width_right = (float(v) for v in model)
    return LedCharacterisation(
        name=measurement.name,
        source=where,
        peak_nm=peak_nm,
        centroid_nm=centroid,
        fwhm_nm=fwhm,
        model={
            "amplitude": amplitude,
            "peak_nm": fitted_peak,
            "width_left_nm": width_left,
            "width_right_nm": width_right,
        },
        model_residual=model_residual,
        snr=snr,
        saturated=at_max is not None,
        warnings=tuple(notes),
    )


def _flat_top(values: np.ndarray, peak_value: float, where: str, notes: list[str]) -> np.ndarray | None:
    """The samples at the maximum when a run of them shows a saturated spectrometer (noted), else None."""
    at_max = values >= peak_value * (1 - SATURATION_TOLERANCE)
    run, longest = 0, 0
    for flag in at_max:
        run = run + 1 if flag else 0
        longest = max(longest, run)
    if longest < SATURATION_RUN:
        return None
    notes.append(
        f"{where}: {longest} samples at the maximum {peak_value:g} (flat top): the spectrometer "
        "saturated; re-measure with a shorter integration time"
    )
    return at_max


def _peak_snr(
    wavelengths: np.ndarray,
    values: np.ndarray,
    peak_nm: float,
    peak_value: float,
    band: float,
    where: str,
    notes: list[str],
) -> float:
    """Peak over the noise of the samples far from the emission band (inf without them); low is noted."""
    out_of_band = np.abs(wavelengths - peak_nm) > 4 * band
    if np.count_nonzero(out_of_band) < 5:
        return math.inf
    noise = float(np.std(values[out_of_band]))
    snr = peak_value / noise if noise > 0 else math.inf
    if snr < MIN_SNR:
        notes.append(
            f"{where}: noisy measurement (peak/noise {snr:.0f} < {MIN_SNR:.0f}); average more "
            "scans or lengthen the integration time"
        )
    return snr


def _fit_emission_model(
    wavelengths: np.ndarray,
    values: np.ndarray,
    usable: np.ndarray,
    peak_nm: float,
    peak_value: float,
    half_widths: tuple[float, float],
) -> np.ndarray:
    """The Ohno 2005 model's amplitude, peak and two half widths, least squares on the ``usable`` samples."""
    start = np.array([peak_value, peak_nm, half_widths[0] / HALF_WIDTH_FACTOR, half_widths[1] / HALF_WIDTH_FACTOR])

    def residual(p: np.ndarray) -> np.ndarray:
        return (emission_model_Ohno2005(wavelengths[usable], *p) - values[usable]) / peak_value

    span = wavelengths[-1] - wavelengths[0]
    fit = least_squares(
        residual,
        start,
        bounds=([0, wavelengths[0] - 50, 0.1, 0.1], [10 * peak_value, wavelengths[-1] + 50, span, span]),
    )
    return np.asarray(fit.x)


def relative_power_through_camera(
    led_spectra: Spectra,
    white_responses: np.ndarray,
    camera_responsivities: Spectra,
    white_reflectance: Spectra | None = None,
) -> np.ndarray:
    """Each LED's power scale, relative to the strongest, from the camera's view of a white reference.

    A spectrometer measures each LED's *shape* well, but its ratios between LEDs depend on where
    the probe sat; the camera, looking at a white reference under each LED alone, sees the ratios
    that matter for the flash. With ``m_k`` the white's linear RGB under LED ``k`` (per unit drive
    and exposure) and ``a_k = Cᵀ diag(r) s_k`` the response the measured shape predicts, the power
    is the least-squares scale ``p_k = a_kᵀ m_k / a_kᵀ a_k``.

    Parameters
    ----------
    led_spectra
        Measured shapes, (n_wavelengths, k), any scale.
    white_responses
        Linear camera responses of the white under each LED alone, (k, n_channels).
    camera_responsivities
        The camera's responsivities in the same unit and on the same grid.

    Returns
    -------
    np.ndarray
        (k,) power factors, the largest 1, for the columns of ``led_spectra``.

    Raises
    ------
    CalibrationError
        On shape mismatches, or an LED the camera does not see.
    """
    require_same_grid(led_spectra, camera_responsivities)
    responses = np.asarray(white_responses, dtype=float)
    k = led_spectra.count
    if responses.shape != (k, camera_responsivities.count):
        raise CalibrationError(
            f"relative LED power: white responses have shape {responses.shape}; expected ({k}, "
            f"{camera_responsivities.count}) — one camera response per LED"
        )
    if not np.all(np.isfinite(responses)):
        raise CalibrationError("relative LED power: white responses are not finite; expected linear camera values")
    shapes = led_spectra.to_unit(camera_responsivities.unit).values
    if white_reflectance is not None:
        require_same_grid(led_spectra, white_reflectance)
        shapes = shapes * white_reflectance.values[:, :1]
    predicted = (camera_responsivities.values.T @ shapes).T  # (k, channels)
    powers = np.empty(k)
    for i in range(k):
        norm = float(predicted[i] @ predicted[i])
        if norm <= 0 or float(responses[i].sum()) <= 0:
            raise CalibrationError(
                f"relative LED power: LED '{led_spectra.names[i]}' gives no camera response; expected a lit white "
                "reference inside the camera's spectral range"
            )
        powers[i] = float(predicted[i] @ responses[i]) / norm
    return powers / powers.max()
