"""A user's spectral rows put in wavelength order: the one set of row rules for every spectral file msflash reads.

Both readers of a user's spectral file apply these rules: the table reader
(:func:`processing.datasets.load_spectra_csv`: ``--target``, ``--led-spectra``, the sim's files, chart and white
reflectances) and the spectrometer-export reader (:func:`calibration.spectrometer.read_spectrometer_file`).
What writers do, and what is read (``docs/calibration.md``, *Row order, repeats and one column*):

- **Descending wavelengths.** Scanning instruments (UV-Vis spectrophotometers, monochromator scans) step from long
  to short wavelengths, and an Excel sort "largest to smallest" does the same to a table. Read: the rows reversed,
  each value kept with its wavelength (the line numbers too, for messages).
- **A row written twice.** A writer repeating a line (at a segment or page boundary, a file appended by hand) gives
  exact duplicate rows. Read: collapsed to one, silently — nothing is lost or changed.
- **One wavelength, several readings.** A high-resolution CCD whose pixel wavelengths are exported rounded (one
  decimal, or whole nanometres, by the program's or a spreadsheet's number format) gives adjacent rows with one
  printed wavelength and different values; a scanning instrument's grating or detector change gives two readings at
  the change-over wavelength. Both are readings of that wavelength: averaged (every column), with a warning naming
  the file and lines (:class:`processing.errors.SpectralDataWarning`, or the reader's own category).
- **Wavelengths that turn back** (rising, then falling, or a second scan appended) are refused, naming the file and
  both lines: no order of the rows is the writer's.
- **Wavelengths that are not nanometres** (micrometres 0.38–0.78, ångström 3800–7800, wavenumbers) are refused,
  naming the file and the line: the rows must lie within :data:`NANOMETRE_RANGE` (UV to short-wave infrared, what a
  spectrometer or spectrophotometer measures).

An ascending table with one row per wavelength is returned as it is (the same array): the shipped tables read to
the same numbers, bit for bit.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from msflash.processing.errors import SpectralDataError, SpectralDataWarning

NANOMETRE_RANGE = (100.0, 3000.0)
"""Wavelengths of a user's spectral file, in nm: anything outside is another unit (µm, ångström), never a sample."""


def in_wavelength_order(
    table: np.ndarray,
    lines: Sequence[int],
    source: str,
    warning: type[Warning] = SpectralDataWarning,
    stacklevel: int = 2,
) -> tuple[np.ndarray, list[int], tuple[str, ...]]:
    """``table``'s rows (wavelength first) in ascending wavelength order, one row per wavelength; the line of each
    row, and what was done (see the module notes).

    Parameters
    ----------
    lines
        The file line of each row, for messages.
    source
        The file, as messages name it.
    warning
        The category of the warning given when readings of one wavelength are averaged.
    stacklevel
        Of that warning, counted from the caller of this function (1: the caller).

    Examples
    --------
    >>> table, lines, notes = in_wavelength_order(np.array([[420.0, 1], [410, 2], [410, 2], [400, 3]]), [5, 6, 7, 8], "x")
    >>> table.tolist(), lines, notes
    ([[400.0, 3.0], [410.0, 2.0], [420.0, 1.0]], [8, 6, 5], ('descending wavelengths: read in ascending order', 'line 7 repeats line 6: read once'))

    Raises
    ------
    SpectralDataError
        Wavelengths that rise and fall, naming the file and the two lines; wavelengths outside
        :data:`NANOMETRE_RANGE`, naming the file and the line of the first one outside.
    """
    _require_nanometres(table[:, 0], lines, source)
    notes: list[str] = []
    lines = list(lines)
    steps = np.diff(table[:, 0])
    if steps.size and np.all(steps <= 0) and np.any(steps < 0):
        table, lines = table[::-1], lines[::-1]
        notes.append("descending wavelengths: read in ascending order")
        steps = -steps[::-1]
    if np.any(steps < 0):
        k = int(np.argmax(steps < 0))
        raise SpectralDataError(
            f"{source}:{lines[k + 1]}: wavelength {table[k + 1, 0]:g} nm after {table[k, 0]:g} nm (line {lines[k]}); "
            "expected the wavelengths in one order, ascending or descending (two scans in one file?)"
        )
    if not np.any(steps == 0):
        return table, lines, tuple(notes)
    return _one_row_per_wavelength(table, lines, source, notes, warning, stacklevel + 2)


def _require_nanometres(wavelengths: np.ndarray, lines: Sequence[int], source: str) -> None:
    """Refuse wavelengths outside :data:`NANOMETRE_RANGE`, naming the line of the first one outside."""
    low, high = NANOMETRE_RANGE
    outside = np.flatnonzero((wavelengths < low) | (wavelengths > high))
    if outside.size:
        first = int(outside[0])
        raise SpectralDataError(
            f"{source}:{lines[first]}: wavelength {wavelengths[first]:g}; the rows span {np.min(wavelengths):g}–"
            f"{np.max(wavelengths):g}; expected nanometres ({low:g}–{high:g})"
        )


def _one_row_per_wavelength(
    table: np.ndarray, lines: list[int], source: str, notes: list[str], warning: type[Warning], stacklevel: int
) -> tuple[np.ndarray, list[int], tuple[str, ...]]:
    """Rows sharing a wavelength (adjacent, the table in order) as one: repeats collapsed, readings averaged."""
    starts = np.flatnonzero(np.r_[True, np.diff(table[:, 0]) != 0])
    ends = np.r_[starts[1:], len(table)]
    rows, kept, averaged = [], [], []
    for start, end in zip(starts, ends, strict=True):
        group = table[start:end]
        rows.append(group.mean(axis=0))
        first, *again = sorted(lines[start:end])  # in the file's order, whichever way the rows were turned
        kept.append(first)
        if not again:
            continue
        if np.all(group == group[0]):
            notes.append(f"line {', '.join(map(str, again))} repeats line {first}: read once")
        else:
            averaged.append((start, end))
    if averaged:
        start, end = averaged[0]
        in_file_order = sorted(range(start, end), key=lambda i: lines[i])
        readings = ", ".join(f"{table[i, 1]:g} (line {lines[i]})" for i in in_file_order)
        more = f"; {len(averaged) - 1} more wavelengths read more than once, averaged too" if len(averaged) > 1 else ""
        message = (
            f"{source}: {end - start} readings at {table[start, 0]:g} nm, {readings}: averaged{more} (wavelengths "
            "rounded in the export, or a scan's change-over point)"
        )
        notes.append(message)
        warnings.warn(message, warning, stacklevel=stacklevel)
    return np.array(rows), kept, tuple(notes)
