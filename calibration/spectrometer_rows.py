"""A spectrometer export's rows put in wavelength order, and the wavelengths of a one-column export.

What instruments write, and what is read (``docs/calibration.md``, *Row order, repeats and one column*):

- **Descending wavelengths.** Scanning instruments (UV-Vis spectrophotometers, monochromator scans) step from long
  to short wavelengths by default, and their exports list the samples in that order. Read: the rows reversed, each
  value kept with its wavelength (the line numbers too, for messages).
- **A row written twice.** A writer repeating a line (at a segment or page boundary, a file appended by hand) gives
  exact duplicate rows. Read: collapsed to one, silently — nothing is lost or changed.
- **One wavelength, several readings.** A high-resolution CCD whose pixel wavelengths are exported rounded (one
  decimal, or whole nanometres, by the program's or a spreadsheet's number format) gives adjacent rows with one
  printed wavelength and different values; a scanning instrument's grating or detector change gives two readings at
  the change-over wavelength. Both are readings of that wavelength: averaged (every column), with a warning naming
  the lines (:class:`calibration.errors.CalibrationWarning`).
- **Wavelengths that turn back** (rising, then falling, or a second scan appended) are refused, naming both lines:
  no order of the rows is the instrument's.
- **One column.** A value per line with the grid in the header — ``Start wavelength: 380`` and ``Step: 1`` (or the
  last wavelength: ``End: 780``), as some instruments and the older plain formats write it — is read on that grid;
  one column without them is refused, naming the file and what is expected.
"""

from __future__ import annotations

import re
import warnings

import numpy as np

from msflash.calibration.errors import CalibrationError, CalibrationWarning
from msflash.calibration.spectrometer_header import header_number

_KEY = re.compile(r"^\s*(?P<key>[A-Za-zλ][^:;=,\t]*?)\s*[:;=,\t]\s*(?P<value>[^:;=\t]*?)\s*(?:nm)?\s*$")
_START = re.compile(r"^(?:start|starting|first|begin)(?:wavelength|wl|lambda|λ)?$")
_STEP = re.compile(r"^(?:wavelength)?(?:step|interval|increment|spacing)(?:size|width)?$")
_END = re.compile(r"^(?:end|ending|stop|last|final)(?:wavelength|wl|lambda|λ)?$")


def in_wavelength_order(
    table: np.ndarray, lines: list[int], source: str
) -> tuple[np.ndarray, list[int], tuple[str, ...]]:
    """``table``'s rows (wavelength first) in ascending wavelength order, one row per wavelength; the line of each
    row, and what was done (see the module notes).

    Examples
    --------
    >>> table, lines, notes = in_wavelength_order(np.array([[420.0, 1], [410, 2], [410, 2], [400, 3]]), [5, 6, 7, 8], "x")
    >>> table.tolist(), lines, notes
    ([[400.0, 3.0], [410.0, 2.0], [420.0, 1.0]], [8, 6, 5], ('descending wavelengths: read in ascending order', 'line 7 repeats line 6: read once'))

    Raises
    ------
    CalibrationError
        Wavelengths that rise and fall, naming the two lines.
    """
    notes: list[str] = []
    steps = np.diff(table[:, 0])
    if steps.size and np.all(steps <= 0) and np.any(steps < 0):
        table, lines = table[::-1], lines[::-1]
        notes.append("descending wavelengths: read in ascending order")
        steps = -steps[::-1]
    if np.any(steps < 0):
        k = int(np.argmax(steps < 0))
        raise CalibrationError(
            f"{source}:{lines[k + 1]}: wavelength {table[k + 1, 0]:g} nm after {table[k, 0]:g} nm (line {lines[k]}); "
            "expected the wavelengths in one order, ascending or descending (two scans in one file?)"
        )
    if not np.any(steps == 0):
        return table, list(lines), tuple(notes)
    return _one_row_per_wavelength(table, list(lines), source, notes)


def _one_row_per_wavelength(
    table: np.ndarray, lines: list[int], source: str, notes: list[str]
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
        readings = ", ".join(f"{value:g} (line {lines[i]})" for i, value in zip(range(start, end), table[start:end, 1]))
        more = f"; {len(averaged) - 1} more wavelengths read more than once, averaged too" if len(averaged) > 1 else ""
        message = (
            f"{source}: {end - start} readings at {table[start, 0]:g} nm, {readings}: averaged{more} (wavelengths "
            "rounded in the export, or a scan's change-over point)"
        )
        notes.append(message)
        warnings.warn(message, CalibrationWarning, stacklevel=4)
    return np.array(rows), kept, tuple(notes)


def header_wavelengths(header_lines: list[tuple[int, str]], count: int, source: str, first_line: int) -> np.ndarray:
    """The wavelengths of a one-column export of ``count`` values, from its header's start and step (or end).

    >>> header_wavelengths([(1, "Start wavelength (nm): 380"), (2, "Step: 2,5")], 3, "x", 3).tolist()
    [380.0, 382.5, 385.0]

    Raises
    ------
    CalibrationError
        No start with a step or an end in the header: one line naming the file and what is expected.
    """
    found: dict[str, float] = {}
    for _, line in header_lines:
        match = _KEY.match(line.lstrip("#%;/ "))
        value = header_number(match.group("value")) if match else None
        if match is None or value is None:
            continue
        key = re.sub(r"\(.*?\)|\[.*?\]|[\s_-]", "", match.group("key").lower())
        for name, pattern in (("start", _START), ("step", _STEP), ("end", _END)):
            if pattern.match(key):
                found.setdefault(name, value)
    start, step, end = found.get("start"), found.get("step"), found.get("end")
    if step is None and start is not None and end is not None and count > 1:
        step = (end - start) / (count - 1)
    if start is None or step is None or not step > 0:
        raise CalibrationError(
            f"{source}:{first_line}: 1 column; expected at least 2 (wavelength_nm, value), or one value a line under "
            "a header giving the first wavelength and the step ('Start wavelength: 380' and 'Step: 1', or 'End: 780')"
        )
    return start + step * np.arange(count)
