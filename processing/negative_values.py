"""The one rule for negative values in measured spectra: noise is clipped to 0, anything else refused.

Public objects
--------------
- :data:`PEAK_FRACTION`, :data:`NOISE_SIGMAS`, :func:`noise_sigmas`: the two bounds of the rule.
- :func:`noise_pairs`: a spectrum's noise, estimated from its sample-to-sample differences.
- :class:`ClippedNegatives`: what was clipped in one spectrum (for the JSON and the notes).
- :func:`clip_negative_noise`: the rule, applied to every column of a table.
- :func:`blind_columns`: the columns left with no positive value (refused by the same readers).

A negative value in a measured spectrum is noise, clipped to 0, when it is at least

    −max(PEAK_FRACTION × peak, k × σ)

with ``peak`` the column's largest value, ``σ`` its noise measured in its tails from the differences
of neighbouring samples (:func:`noise_pairs`) and ``k`` ≥ :data:`NOISE_SIGMAS` from the noise model
(:func:`noise_sigmas`); anything lower is refused. Every reader of spectra the user measured applies
:func:`clip_negative_noise` and every writer of a calibration writes what it returns. Why both bounds
and why differences: ``docs/calibration.md`` ("Negative values").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from msflash.processing.errors import SpectralDataError

PEAK_FRACTION = 0.05
"""Negative values down to this fraction of the column's peak are noise."""
NOISE_SIGMAS = 5.0
"""Negative values down to at least this many noise σ (:func:`noise_pairs`) are noise: 5σ of
Gaussian noise is exceeded by 1 sample in ~3.5 million; :func:`noise_sigmas` widens it for long
columns and for σ measured on few pairs."""
FALSE_REFUSAL = 1e-6
"""The chance that a column of pure Gaussian noise (σ known) has a value beyond the noise bound."""
SIGMA_SPREAD = 1.2
"""Standard deviation of :func:`noise_pairs`' σ / true σ, times √pairs (``docs/measurements.md``)."""
SIGMA_SPREADS = 3.0
"""How many of those spreads the noise bound allows for σ measured too low."""
REGION_SIGMAS = 4.0
"""The noise region reaches at least this many σ above zero (the noise's whole distribution)."""
_MAD_TO_SIGMA = 1.4826
"""Median absolute deviation to the σ of a Gaussian."""


NOISE_REGION = 0.10
"""The noise is measured where the values are below this fraction of the peak (the tails)."""
MIN_NOISE_PAIRS = 8
"""Fewer neighbouring pairs in the tails than this: no noise estimate (σ = 0, the peak bound alone)."""


def _tail_pairs(values: np.ndarray, below: float) -> np.ndarray:
    low = values < below
    return low[:-1] & low[1:]


def noise_pairs(values: np.ndarray) -> tuple[float, int]:
    """The noise σ of a spectrum and how many neighbouring pairs it was measured on.

    Pairs of samples both below :data:`NOISE_REGION` of the peak count: there the signal is
    (nearly) zero, so the differences are noise, and a constant offset (a dark subtracted twice)
    cancels instead of passing for noise. The median ignores the odd large difference; for
    independent noise the difference of two samples has σ√2. When that region cuts into the noise
    itself (its bound below :data:`REGION_SIGMAS` σ, a dim export), it is widened to
    :data:`REGION_SIGMAS` σ and σ measured again.
    With fewer than :data:`MIN_NOISE_PAIRS` pairs the answer is (0, pairs).

    Examples
    --------
    >>> w = np.arange(400.0, 700.0, 0.5)
    >>> led = np.exp(-0.5 * ((w - 520) / 10) ** 2) + np.random.default_rng(0).normal(0.0, 0.01, w.size)
    >>> round(noise_pairs(led)[0], 2)
    0.01
    """
    values = np.asarray(values, dtype=float)
    peak = max(float(values.max()), 0.0) if values.size else 0.0
    below = NOISE_REGION * peak
    for _ in range(2):
        pairs = _tail_pairs(values, below)
        count = int(np.count_nonzero(pairs))
        if count < MIN_NOISE_PAIRS:
            return 0.0, count
        sigma = float(_MAD_TO_SIGMA * np.median(np.abs(np.diff(values)[pairs])) / np.sqrt(2.0))
        if below >= REGION_SIGMAS * sigma:
            break
        below = REGION_SIGMAS * sigma
    return sigma, count


def noise_sigmas(n_samples: int, n_pairs: int) -> float:
    """How many σ below zero a column's noise may reach: :data:`NOISE_SIGMAS` or more.

    Two allowances, both from the noise model (independent Gaussian noise, σ measured on
    ``n_pairs`` neighbouring pairs):

    - **many samples**: the bound one of ``n_samples`` pure-noise values crosses with probability
      :data:`FALSE_REFUSAL` — ``Φ⁻¹(1 − FALSE_REFUSAL / n_samples)``;
    - **σ measured, not known**: the estimate's spread is :data:`SIGMA_SPREAD` / √pairs of σ; the
      bound is widened by :data:`SIGMA_SPREADS` such spreads, as a σ measured that much too low
      would narrow it.

    Examples
    --------
    >>> round(noise_sigmas(300, 300), 2), round(noise_sigmas(3500, 3400), 2)
    (7.0, 6.58)
    """
    from scipy.special import ndtri

    sigmas = max(NOISE_SIGMAS, float(-ndtri(FALSE_REFUSAL / max(int(n_samples), 1))))
    return float(sigmas * (1.0 + SIGMA_SPREADS * SIGMA_SPREAD / np.sqrt(max(int(n_pairs), 1))))


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
    sigma, pairs = noise_pairs(values)
    return max(PEAK_FRACTION * peak, noise_sigmas(values.size, pairs) * sigma)


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
    values
        Shape (n,) or (n, k): one column per spectrum.
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
            sigma, pairs = noise_pairs(column_values)
            raise SpectralDataError(
                f"{where}: {what} is {column_values[row]:.6g}; expected a non-negative value, or measurement noise "
                f"down to −{bound:.3g} (the larger of {PEAK_FRACTION:.0%} of the peak {peak:.3g} and "
                f"{noise_sigmas(column_values.size, pairs):.2f} × the noise {sigma:.3g}) — was the dark subtracted "
                "twice, or the baseline offset?"
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

    Every reader that applies :func:`clip_negative_noise` refuses them, naming the column.

    >>> blind_columns(np.array([[0.0, 1.0], [0.0, 2.0]]), ["R", "G"])
    ['R']
    """
    values = np.asarray(values, dtype=float).reshape(len(values), -1)
    return [name for name, column in zip(names, values.T, strict=True) if not np.any(column > 0)]
