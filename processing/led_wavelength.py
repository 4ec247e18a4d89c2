"""One number for each LED's wavelength: the measured peak of its spectral power, and the names made from it.

Public objects
--------------
- :func:`peak_nm`: the peak of one measured spectrum, nm, to :data:`PEAK_DECIMALS` decimals.
- :func:`led_peaks_nm`: each LED's peak, the one recorded with the spectra (``metadata["peak_nm"]``) or
  computed from them.
- :func:`with_peaks`: the spectra with their peaks recorded (where they are measured, before any resampling).
- :func:`led_name`: the name msflash gives an LED of a given peak (``led597``).

Every wavelength msflash prints or writes for an LED — OME ``ExcitationWavelength``, EXR
``msflash:led_peak_nm``, the DNG's and CSV's notes, the run report, the live page's ``peak_nm``,
the booth emulator's ``PEAKS``, the calibration's ``peaks_nm`` — is this number, and every LED
name msflash makes from a wavelength is :func:`led_name` of it (docs/decisions/led-wavelength.md).

Why the peak of the energy spectrum (not its centroid, its largest sample or the photon spectrum's peak), with
the measurements: docs/decisions/led-wavelength.md.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import Spectra

PEAK_DECIMALS = 1
"""The peak is given to 0.1 nm: finer than any LED's width or spectrometer's accuracy, coarse enough to
read as one number everywhere."""
PEAK_METADATA_KEY = "peak_nm"
"""The :attr:`Spectra.metadata` key holding ``{name: peak_nm}`` where the spectra were measured."""


def peak_nm(wavelengths_nm: np.ndarray, values: np.ndarray) -> float:
    """The peak wavelength of one spectral power distribution, nm, rounded to :data:`PEAK_DECIMALS`.

    The vertex of the parabola through the largest sample and its two neighbours, placed between
    their wavelengths (unevenly spaced samples, a spectrometer's, included); at an edge of the
    range the largest sample's wavelength, on a flat top (a saturated reading) its middle.

    Raises
    ------
    SpectralDataError
        If the spectrum has no positive value or the lengths differ.

    Examples
    --------
    >>> w = np.arange(400.0, 701.0, 5.0)
    >>> peak_nm(w, np.exp(-0.5 * ((w - 597.3) / 12) ** 2))
    597.3
    """
    wavelengths = np.asarray(wavelengths_nm, dtype=float)
    spectrum = np.asarray(values, dtype=float)
    if spectrum.shape != wavelengths.shape or spectrum.size == 0:
        raise SpectralDataError(
            f"peak wavelength: {spectrum.size} values for {wavelengths.size} wavelengths; expected one per wavelength"
        )
    top = int(np.argmax(spectrum))
    if not spectrum[top] > 0:
        raise SpectralDataError("peak wavelength: the spectrum has no positive value; expected a light's spectrum")
    end = top
    while end + 1 < spectrum.size and spectrum[end + 1] == spectrum[top]:
        end += 1
    position = (top + end) / 2
    if top == end and 0 < top < spectrum.size - 1:
        before, at, after = spectrum[top - 1], spectrum[top], spectrum[top + 1]
        curvature = before - 2 * at + after
        if curvature < 0:
            position += 0.5 * (before - after) / curvature
    return round(float(np.interp(position, np.arange(wavelengths.size), wavelengths)), PEAK_DECIMALS)


def led_peaks_nm(leds: Spectra) -> tuple[float, ...]:
    """Each LED's peak wavelength, nm, in the order of ``leds.names``.

    The peak recorded where the spectra were measured (``leds.metadata["peak_nm"]``, a mapping from
    name to nm that :func:`with_peaks` sets and that resampling, unit changes and subsets keep), else
    :func:`peak_nm` of the spectrum as it is, in energy.

    Examples
    --------
    >>> from msflash.processing import datasets
    >>> led_peaks_nm(datasets.paper_leds())[:3]
    (439.9, 478.1, 500.1)
    """
    recorded = leds.metadata.get(PEAK_METADATA_KEY)
    recorded = recorded if isinstance(recorded, Mapping) else {}
    energy = leds.to_unit("energy") if leds.kind == "spd" and leds.unit != "energy" else leds
    return tuple(
        round(float(recorded[name]), PEAK_DECIMALS)
        if name in recorded
        else peak_nm(energy.wavelengths_nm, energy.values[:, k])
        for k, name in enumerate(leds.names)
    )


def with_peaks(leds: Spectra) -> Spectra:
    """``leds`` with each LED's :func:`peak_nm` recorded in ``metadata["peak_nm"]`` (computed on their own sampling)."""
    peaks = dict(zip(leds.names, led_peaks_nm(leds.replace(metadata={})), strict=True))
    return leds.replace(metadata={**leds.metadata, PEAK_METADATA_KEY: peaks})


def led_name(peak: float) -> str:
    """The name msflash gives an LED whose peak is ``peak`` nm: ``led`` and the peak to the nanometre.

    >>> led_name(597.2), led_name(439.9)
    ('led597', 'led440')
    """
    return f"led{round(peak):d}"
