"""The one rule for negative values in measured spectra: noise is clipped to 0, anything else refused.

Public objects
--------------
- :data:`PEAK_FRACTION`, :data:`NOISE_SIGMAS`: the two bounds of the rule.
- :func:`noise_sigma`: a spectrum's noise, estimated from its sample-to-sample differences.
- :class:`ClippedNegatives`: what was clipped in one spectrum (for the JSON and the notes).
- :func:`clip_negative_noise`: the rule, applied to every column of a table.
- :func:`blind_columns`: the columns left with no positive value (refused by the same readers).

Measured spectra carry small negative values: a spectrometer export with the dark subtracted
(by the instrument software or by ``--dark``) is noise about zero in the LED's tails, and half
of that noise is below zero. A spectral power (or responsivity) cannot be negative, so those
values are clipped to 0; but a value far below zero is no noise — a dark subtracted twice, a
baseline offset, a wrong column — and is refused. A negative value is noise when it is at least

    −max(PEAK_FRACTION × peak, NOISE_SIGMAS × σ)

with ``peak`` the column's largest value and ``σ`` its noise, measured in its tails from the
differences of neighbouring samples (:func:`noise_sigma`; differences, so that an offset — a dark
subtracted twice — is no noise). The fraction
of the peak alone would refuse dim LEDs (an export with peak/noise 30, which
``characterise_led`` warns about, has −4σ tails at −13 % of the peak); the noise bound alone
would refuse a smooth, correlated tail (a resampled or smoothed export, whose differences
understate its noise). Every reader of spectra the user measured applies this function — the
spectrometer reader, the calibration reader (:func:`calibration.files.load_calibration`), the
sequence reader and the rigs' spectral tables — and every writer of a calibration writes what it
returns, so what one command writes the others read.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from msflash.processing.errors import SpectralDataError

PEAK_FRACTION = 0.05
"""Negative values down to this fraction of the column's peak are noise."""
NOISE_SIGMAS = 5.0
"""Negative values down to this many noise σ (:func:`noise_sigma`) are noise: 5σ of Gaussian noise
is exceeded by 1 sample in ~3.5 million."""
_MAD_TO_SIGMA = 1.4826
"""Median absolute deviation to the σ of a Gaussian."""


NOISE_REGION = 0.10
"""The noise is measured where the values are below this fraction of the peak (the tails)."""
MIN_NOISE_PAIRS = 8
"""Fewer neighbouring pairs in the tails than this: no noise estimate (σ = 0, the peak bound alone)."""


def noise_sigma(values: np.ndarray) -> float:
    """The noise σ of a spectrum, from the differences of neighbouring samples in its tails.

    Only pairs of samples both below :data:`NOISE_REGION` of the peak count: there the signal is
    (nearly) zero, so the differences are noise, and a constant offset (a dark subtracted twice)
    cancels instead of passing for noise. The median ignores the odd large difference; for
    independent noise the difference of two samples has σ√2. With fewer than
    :data:`MIN_NOISE_PAIRS` such pairs the answer is 0.

    Examples
    --------
    >>> w = np.arange(400.0, 700.0, 0.5)
    >>> led = np.exp(-0.5 * ((w - 520) / 10) ** 2) + np.random.default_rng(0).normal(0.0, 0.01, w.size)
    >>> round(noise_sigma(led), 2)
    0.01
    """
    values = np.asarray(values, dtype=float)
    peak = max(float(values.max()), 0.0) if values.size else 0.0
    low = values < NOISE_REGION * peak
    pairs = low[:-1] & low[1:]
    if np.count_nonzero(pairs) < MIN_NOISE_PAIRS:
        return 0.0
    return float(_MAD_TO_SIGMA * np.median(np.abs(np.diff(values)[pairs])) / np.sqrt(2.0))


@dataclass(frozen=True)
class ClippedNegatives:
    """The negative noise clipped to 0 in one column."""

    column: str
    """The column (LED or channel) name."""
    count: int
    """How many values were clipped."""
    most_negative: float
    """The lowest of them."""
    at_nm: float
    """Its wavelength."""
    tolerance: float
    """The bound it was within (a positive number: values down to ``-tolerance`` are noise)."""

    def as_dict(self) -> dict:
        """JSON form."""
        return {
            "column": self.column,
            "count": self.count,
            "most_negative": self.most_negative,
            "at_nm": self.at_nm,
            "tolerance": self.tolerance,
        }

    def note(self, source: str) -> str:
        """One line for stderr."""
        return (
            f"{source}: column '{self.column}': {self.count} negative value(s) down to {self.most_negative:.3g} "
            f"(at {self.at_nm:g} nm) clipped to 0 as noise (within −{self.tolerance:.3g})"
        )


def tolerance(values: np.ndarray) -> float:
    """How far below zero a column's values may go and still be noise (see the module notes)."""
    values = np.asarray(values, dtype=float)
    peak = max(float(values.max()), 0.0) if values.size else 0.0
    return max(PEAK_FRACTION * peak, NOISE_SIGMAS * noise_sigma(values))


def clip_negative_noise(
    wavelengths_nm: np.ndarray,
    values: np.ndarray,
    names: Sequence[str],
    source: str,
    lines: Sequence[int] | None = None,
    place: Callable[[int, int], str] | None = None,
) -> tuple[np.ndarray, tuple[ClippedNegatives, ...]]:
    """``values`` with negative noise clipped to 0, and what was clipped per column.

    Parameters
    ----------
    wavelengths_nm
        Shape (n,).
    values
        Shape (n,) or (n, k): one column per spectrum.
    names
        The column names (k of them), for messages.
    source
        The file (or field) the values came from, for messages.
    lines
        The file line of each row, if known: the refusal then names ``source:line``.
    place
        Names a value from its (row, column) in the refusal; by default "column 'NAME' at W nm".

    Returns
    -------
    The clipped values (same shape) and one :class:`ClippedNegatives` per column that had any.

    Raises
    ------
    SpectralDataError
        Naming the source (and line), the column, the wavelength, the value and the bound, for the
        first value below ``-tolerance``.

    Examples
    --------
    >>> w = np.array([400.0, 410.0, 420.0, 430.0])
    >>> clipped, report = clip_negative_noise(w, np.array([-0.01, 1.0, 0.2, 0.0]), ["B"], "b.csv")
    >>> clipped.tolist(), report[0].count
    ([0.0, 1.0, 0.2, 0.0], 1)
    """
    array = np.asarray(values, dtype=float)
    table = array.reshape(array.shape[0], -1)
    if not np.any(table < 0):
        return array, ()
    clipped = table.copy()
    report: list[ClippedNegatives] = []
    for column in range(table.shape[1]):
        column_values = table[:, column]
        negative = column_values < 0
        if not np.any(negative):
            continue
        bound = tolerance(column_values)
        beyond = column_values < -bound
        name = names[column] if column < len(names) else str(column + 1)
        if np.any(beyond):
            row = int(np.argmax(beyond))
            where = f"{source}:{lines[row]}" if lines is not None else source
            peak = max(float(column_values.max()), 0.0)
            what = place(row, column) if place is not None else f"column '{name}' at {float(wavelengths_nm[row]):g} nm"
            raise SpectralDataError(
                f"{where}: {what} is {column_values[row]:.6g}; expected a non-negative value, or measurement noise "
                f"down to −{bound:.3g} (the larger of {PEAK_FRACTION:.0%} of the peak {peak:.3g} and {NOISE_SIGMAS:g} × "
                f"the noise {noise_sigma(column_values):.3g}) — was the dark subtracted twice, or the baseline offset?"
            )
        lowest = int(np.argmin(column_values))
        report.append(
            ClippedNegatives(
                name,
                int(np.count_nonzero(negative)),
                float(column_values[lowest]),
                float(wavelengths_nm[lowest]),
                bound,
            )
        )
        clipped[:, column] = np.maximum(column_values, 0.0)
    return clipped.reshape(array.shape), tuple(report)


def blind_columns(values: np.ndarray, names: Sequence[str]) -> list[str]:
    """The columns of ``values`` (wavelength × column) with no positive value: an LED that emits
    nothing, a camera channel that sees nothing on the grid.

    Every reader that applies :func:`clip_negative_noise` refuses them, naming the column: left in,
    an all-zero responsivity made the ambient estimate fail later blaming the LEDs ("the LED-only
    image … is empty; is it connected?").

    >>> blind_columns(np.array([[0.0, 1.0], [0.0, 2.0]]), ["R", "G"])
    ['R']
    """
    values = np.asarray(values, dtype=float).reshape(len(values), -1)
    return [name for name, column in zip(names, values.T, strict=True) if not np.any(column > 0)]
