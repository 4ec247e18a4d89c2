"""A spectrometer export's rows put in wavelength order, and the wavelengths of a one-column export.

What instruments write, and what is read (``docs/calibration.md``, *Row order, repeats and one column*); the
row rules are :mod:`processing.spectral_rows`, which every reader of a user's spectral file applies:

- **Descending wavelengths** reversed, **a row written twice** read once, **one wavelength with several readings**
  averaged with a warning naming the lines (here :class:`calibration.errors.CalibrationWarning`), **wavelengths that
  turn back** refused naming both lines: :mod:`processing.spectral_rows` says why each is what instruments write.
- **One column.** A value per line with the grid in the header — ``Start wavelength: 380`` and ``Step: 1`` (or the
  last wavelength: ``End: 780``), as some instruments and the older plain formats write it — is read on that grid;
  one column without them is refused, naming the file and what is expected.
"""

from __future__ import annotations

import re

import numpy as np

from msflash.calibration.errors import CalibrationError, CalibrationWarning
from msflash.calibration.spectrometer_header import header_number
from msflash.processing import spectral_rows
from msflash.processing.errors import SpectralDataError

_KEY = re.compile(r"^\s*(?P<key>[A-Za-zλ][^:;=,\t]*?)\s*[:;=,\t]\s*(?P<value>[^:;=\t]*?)\s*(?:nm)?\s*$")
_START = re.compile(r"^(?:start|starting|first|begin)(?:wavelength|wl|lambda|λ)?$")
_STEP = re.compile(r"^(?:wavelength)?(?:step|interval|increment|spacing)(?:size|width)?$")
_END = re.compile(r"^(?:end|ending|stop|last|final)(?:wavelength|wl|lambda|λ)?$")


def in_wavelength_order(
    table: np.ndarray, lines: list[int], source: str
) -> tuple[np.ndarray, list[int], tuple[str, ...]]:
    """``table``'s rows (wavelength first) in ascending wavelength order, one row per wavelength; the line of each
    row, and what was done: the one set of row rules (:func:`processing.spectral_rows.in_wavelength_order`), which
    the spectral table reader applies too, with the calibration package's error and warning (examples there).

    Raises
    ------
    CalibrationError
        Wavelengths that rise and fall, naming the two lines.
    """
    try:  # the averaged-readings warning points at the export's reader (read_spectrometer_file)
        return spectral_rows.in_wavelength_order(table, lines, source, CalibrationWarning, stacklevel=3)
    except SpectralDataError as err:
        raise CalibrationError(str(err)) from None


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
