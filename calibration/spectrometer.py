"""Reading spectrometer exports: two-column text (CSV, tab, semicolon or space separated).

Public objects
--------------
- :class:`SpectrometerMeasurement`: the raw samples of one export, on the instrument's own grid.
- :func:`parse_spectrometer_text`, :func:`read_spectrometer_file`: the parser and its file form.
- :func:`measurement_to_spectra`: the samples as :class:`~processing.spectra.Spectra` on a grid.
  A dark export is taken off by :func:`calibration.spectrometer_dark.remove_baseline`.

Accepted layout (``docs/calibration.md``, *Reading the numbers*)
----------------------------------------------------------------
Comment lines start with ``#``, ``%``, ``//`` or ``;``. Non-numeric lines *before* the data are a
header; the last of them names the columns if it has as many cells as the data. After the data
starts, every line must be numeric, except an end marker (``>>>>>End Spectral Data<<<<<``).
Descending wavelengths, repeated rows and one-column exports with the grid in the header are read
(:mod:`calibration.spectrometer_rows`). Decimal commas are read where they are unambiguous: cells separated by semicolons or tabs, each a
number once its one comma is a point (``380,5;0,25``); elsewhere ``1,5`` is two cells. UTF-8,
UTF-16 (with its byte-order mark) and Latin-1 files are read. Non-uniform instrument grids go
through :meth:`Spectra.from_samples` (box-car bins), then :meth:`Spectra.resample`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from msflash.calibration.errors import CalibrationError
from msflash.calibration.spectrometer_header import AcquisitionSettings, acquisition_settings
from msflash.calibration.spectrometer_rows import header_wavelengths, in_wavelength_order
from msflash.processing.errors import SpectralDataError
from msflash.processing.negative_values import ClippedNegatives, clip_negative_noise
from msflash.processing.spectra import (
    MAX_TABLE_MAGNITUDE,
    MIN_TABLE_PEAK,
    Spectra,
    SpectralUnit,
    WavelengthGrid,
    tiny_columns,
)
from msflash.processing.user_files import TEXT_EXPORT_MAX_BYTES, printable, read_user_bytes, shown_path
from msflash.processing.user_numbers import number_or_non_finite

_COMMENT_PREFIXES = ("#", "%", "//", ";")
_END_MARKERS = ("end", ">>>>>end")
_SEPARATORS = re.compile(r"[,\t; ]+")
_DECIMAL_COMMA_SEPARATORS = re.compile(r"[\t;]+")
_DECIMAL_COMMA_NUMBER = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$|^[+-]?\d+(?:[eE][+-]?\d+)?$", re.ASCII)
_AVANTES_COLUMNS = ("wave", "sample", "dark", "reference")
"""The first columns of an AvaSoft text export: wavelength, raw counts, the stored dark, the reference."""


@dataclass(frozen=True)
class SpectrometerMeasurement:
    """The samples of one spectrometer export."""

    wavelengths_nm: np.ndarray
    """Sampled wavelengths, strictly increasing, shape (n,)."""
    values: np.ndarray
    """Spectral power at each wavelength, shape (n,)."""
    unit: SpectralUnit
    """``energy`` (radiance/irradiance, W…) or ``photons`` (quanta)."""
    source: str
    """The file (or text) it came from, for messages."""
    name: str
    """A short name (the file stem unless given)."""
    header: tuple[str, ...] = ()
    """The header lines, as read."""
    metadata: dict = field(default_factory=dict, compare=False)
    """Extras: the value column's header, the line of each sample (``lines``), an in-file dark
    column (``dark_values``, AvaSoft's *Dark*), what was done to the baseline (``baseline``)."""
    settings: AcquisitionSettings = field(default_factory=AcquisitionSettings, compare=False)
    """Instrument, integration time, averaging and value unit as the header states them
    (:mod:`calibration.spectrometer_header`)."""

    @property
    def uniform(self) -> bool:
        """Whether the samples are on a uniform grid (within 0.1 % of the step)."""
        steps = np.diff(self.wavelengths_nm)
        return bool(steps.size and np.max(np.abs(steps - steps.mean())) <= 1e-3 * steps.mean())


def _cells(line: str) -> list[str]:
    """The cells of a line; decimal commas become points where the separators make them unambiguous
    (cells split by semicolons, tabs or blanks, each a number once its one comma is a point)."""
    if "," in line:
        for separators in (_DECIMAL_COMMA_SEPARATORS, re.compile(r"\s+")):
            if not separators.search(line.strip()):
                continue
            cells = [cell.strip() for cell in separators.split(line.strip()) if cell.strip() != ""]
            if (
                len(cells) >= 2
                and any("," in cell for cell in cells)
                and all(_DECIMAL_COMMA_NUMBER.match(c) for c in cells)
            ):
                return [cell.replace(",", ".") for cell in cells]
    return [cell for cell in _SEPARATORS.split(line.strip()) if cell != ""]


def _header_cells(line: str) -> list[str]:
    """Column names of a header line ("Wavelength (nm)\tIrradiance", "Wave   ;Sample   ;Dark")."""
    if re.search(r"[,\t;]", line):
        return [c.strip() for c in re.split(r"[,\t;]", line) if c.strip()]
    return _cells(line)


def _avantes_columns(header: list[str]) -> tuple[list[str], list[str]] | None:
    """AvaSoft's column names and units (``Wave;Sample;Dark;Reference…`` then ``[nm];[counts]…``)."""
    for index, line in enumerate(header):
        names = _header_cells(line)
        if [n.lower() for n in names[: len(_AVANTES_COLUMNS)]] == list(_AVANTES_COLUMNS):
            units = _header_cells(header[index + 1]) if index + 1 < len(header) else []
            return names, units if all(u.startswith("[") for u in units) else []
    return None


def _numbers(cells: list[str]) -> list[float] | None:
    """The cells as numbers (the one reading of a user's number, :func:`processing.user_numbers.plain_number`), or
    None when one is no number: a header line before the data, an end marker, or a refused data line."""
    try:
        return [number_or_non_finite(cell) for cell in cells]  # inf, nan: refused below naming the column
    except ValueError:
        return None


def parse_spectrometer_text(
    text: str,
    source: str = "<text>",
    unit: SpectralUnit = "energy",
    column: int | None = None,
    name: str | None = None,
) -> SpectrometerMeasurement:
    """Parse a spectrometer export (see the module notes for the layout).

    Parameters
    ----------
    unit
        ``energy`` or ``photons``: what the value column holds.
    column
        The value column (1-based after the wavelength column: 1 is the second column). Needed
        when the data have more than two columns.
    name
        Name of the measurement (default: derived from ``source``).

    Raises
    ------
    CalibrationError
        Naming the file and line: no data, a non-numeric or ragged data line, wrong column
        count, NaN/infinite values, wavelengths that rise and fall (descending ones are reversed, rows sharing a
        wavelength collapsed or averaged: :mod:`calibration.spectrometer_rows`), a value below the negative-noise
        bound (:mod:`processing.negative_values`), no signal.

    Examples
    --------
    >>> m = parse_spectrometer_text("# PR-715\\nnm,W\\n400,0.1\\n404,0.5\\n408,0.2\\n")
    >>> m.wavelengths_nm.tolist(), m.values.tolist()
    ([400.0, 404.0, 408.0], [0.1, 0.5, 0.2])
    """
    if unit not in ("energy", "photons"):
        raise CalibrationError(f"{source}: unit '{unit}'; expected energy or photons")
    data = _read_rows(text, source, column)
    table, data.lines, order_notes = in_wavelength_order(np.asarray(data.rows, dtype=float), data.lines, source)
    wavelengths = table[:, 0]
    value_column = data.column if data.column is not None else 1
    readings = table[:, value_column]
    _check_readings(readings, source)
    column_name, column_units, metadata = _value_column(data, table, value_column)
    if order_notes:
        metadata["order"] = order_notes
    settings = acquisition_settings(data.header_lines, source, column_units)
    _check_negatives(wavelengths, readings, column_name or "value", source, data.lines)
    return SpectrometerMeasurement(
        wavelengths,
        readings,
        unit,
        source,
        name or Path(source).stem,
        tuple(data.header),
        metadata,
        settings,
    )


@dataclass
class _Rows:
    """A spectrometer export's lines sorted: header and comments, numeric data rows and their line numbers."""

    column: int | None
    header: list[str] = field(default_factory=list)
    header_lines: list[tuple[int, str]] = field(default_factory=list)
    """Header and comment lines, for the acquisition settings."""
    rows: list[list[float]] = field(default_factory=list)
    lines: list[int] = field(default_factory=list)
    width: int | None = None
    avantes: tuple[list[str], list[str]] | None = None


def _read_rows(text: str, source: str, column: int | None) -> _Rows:
    """The header lines before the data, the data rows (same width, finite), up to an end marker."""
    data = _Rows(column)
    ended = False
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip().lstrip("\ufeff")
        if not line:
            continue
        if line.startswith(_COMMENT_PREFIXES):
            if not data.rows:
                data.header_lines.append((number, line))
            continue
        if ended:
            continue
        cells = _cells(line)
        values = _numbers(cells)
        if values is None:
            if not data.rows:
                data.header.append(line)
                data.header_lines.append((number, line))
                continue
            if line.lower().startswith(_END_MARKERS):
                ended = True
                continue
            raise CalibrationError(
                f"{source}:{number}: '{line[:50]}' is not numeric; expected 'wavelength, value' numbers on every data line"
            )
        if data.width is None:
            _first_data_line(data, len(values), line, f"{source}:{number}")
        elif len(values) != data.width:
            raise CalibrationError(
                f"{source}:{number}: {len(values)} columns; expected {data.width} as on the first data line"
            )
        bad = [i for i, v in enumerate(values) if not math.isfinite(v) or abs(v) > MAX_TABLE_MAGNITUDE]
        if bad:
            field_name = "wavelength" if bad[0] == 0 else f"column {bad[0] + 1}"
            raise CalibrationError(
                f"{source}:{number}: {field_name} is '{printable(cells[bad[0]][:40])}'; expected a finite number of "
                f"magnitude at most {MAX_TABLE_MAGNITUDE:g}"
            )
        data.rows.append(values)
        data.lines.append(number)
    if len(data.rows) < 3:
        first = f":{data.lines[0]}" if data.lines else ""  # the line of a lone data row, for the user to look at
        raise CalibrationError(
            f"{source}{first}: {len(data.rows)} data line{'' if len(data.rows) == 1 else 's'}; expected at least 3 "
            "lines of 'wavelength_nm, value'"
        )
    if data.width == 1:  # one value a line: the grid from the header, or refused naming what is expected
        wavelengths = header_wavelengths(data.header_lines, len(data.rows), source, data.lines[0])
        data.rows = [[float(wavelength), *row] for wavelength, row in zip(wavelengths, data.rows, strict=True)]
        data.width = 2
    return data


def _first_data_line(data: _Rows, width: int, line: str, where: str) -> None:
    """Fix the data's width and value column from the first data line (AvaSoft: its Sample column)."""
    data.width = width
    data.avantes = _avantes_columns(data.header)
    if width < 2:
        return  # one value a line: read on the header's grid (spectrometer_rows.header_wavelengths), or refused
    if width > 2 and data.column is None and data.avantes is not None:
        data.column = 1  # AvaSoft: the Sample column (raw counts); its Dark column is the stored dark
    if width > 2 and data.column is None:
        # "380,5,0,25": decimal commas between comma separators cannot be told apart from cells.
        hint = (
            "; if the numbers have decimal commas, export with ';' or tab separators"
            if not re.search(r"[\t; ]", line)
            else ""
        )
        raise CalibrationError(
            f"{where}: {width} columns; expected 2 (wavelength_nm, value), or choose the "
            f"value column (column=N / --column N){hint}"
        )
    if data.column is not None and not 1 <= data.column < width:
        raise CalibrationError(
            f"{where}: value column {data.column} requested but the data have {width} columns; expected 1…{width - 1}"
        )


def _check_readings(readings: np.ndarray, source: str) -> None:
    """A positive reading of a sensible magnitude (the wavelengths were put in increasing order, in nanometres, by
    :func:`in_wavelength_order`)."""
    peak = float(np.max(readings))
    if peak <= 0:
        raise CalibrationError(f"{source}: no positive value in the value column; expected a measured emission")
    if tiny_columns(readings[:, None]):
        raise CalibrationError(
            f"{source}: the value column peaks at {peak:.3g}; expected values of magnitude at least "
            f"{MIN_TABLE_PEAK:g} (a file scaled by mistake?)"
        )


def _value_column(data: _Rows, table: np.ndarray, value_column: int) -> tuple[str, tuple[str, ...], dict]:
    """The value column's name and units from the header, and the measurement's metadata (AvaSoft's dark)."""
    column_name, column_units = "", cast(tuple[str, ...], ())
    metadata: dict = {"lines": tuple(data.lines)}
    if data.avantes is not None:
        names, units = data.avantes
        column_name = names[value_column] if value_column < len(names) else ""
        column_units = tuple(units[value_column : value_column + 1])
        dark_column = 2
        width = data.width
        if value_column == 1 and width is not None and width > dark_column and np.any(table[:, dark_column] != 0):
            metadata["dark_values"] = table[:, dark_column].copy()  # AvaSoft stored a dark with the sample
    elif data.header and not data.header[-1].startswith(">>>>>"):  # OceanView's begin marker names no column
        # "Wavelength (nm)\tIrradiance": names may hold spaces when another separator is used.
        header_cells = _header_cells(data.header[-1])
        if data.width is not None and len(header_cells) >= data.width:
            column_name = header_cells[value_column]
            if re.fullmatch(r"\W*(?:raw\s+)?counts?\W*|.*[\[(]counts?[\])].*", column_name, re.IGNORECASE):
                column_units = ("[counts]",)  # a plain file naming its column "counts": raw counts
    metadata["column"] = column_name
    return column_name, column_units, metadata


def _check_negatives(
    wavelengths_nm: np.ndarray,
    values: np.ndarray,
    column: str,
    source: str,
    lines: tuple[int, ...] | list[int] | None = None,
) -> tuple[np.ndarray, tuple[ClippedNegatives, ...]]:
    """The values with negative noise clipped (:mod:`processing.negative_values`); beyond it, a CalibrationError."""
    try:
        return clip_negative_noise(wavelengths_nm, values, [column], source, lines)
    except SpectralDataError as err:
        raise CalibrationError(str(err)) from None


def read_spectrometer_file(
    path: str | Path,
    unit: SpectralUnit = "energy",
    column: int | None = None,
    name: str | None = None,
) -> SpectrometerMeasurement:
    """Read a spectrometer export from a file (UTF-8 or Latin-1 text; see :func:`parse_spectrometer_text`)."""
    path = Path(path)
    shown = shown_path(path)  # any bytes in the name: one printable line, in messages and as the source
    data = read_user_bytes(path, "a spectrometer text file", TEXT_EXPORT_MAX_BYTES, CalibrationError)
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):  # UTF-16 with its byte-order mark (Windows "Unicode")
        try:
            text = data.decode("utf-16")
        except UnicodeDecodeError as err:
            raise CalibrationError(
                f"{shown}: not valid UTF-16 text ({err.reason} at byte {err.start}); expected a text export"
            ) from err
        return parse_spectrometer_text(text, shown, unit, column, name)
    if b"\x00" in data[:4096]:
        raise CalibrationError(f"{shown}: binary data; expected a text export (CSV or tab/space separated)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("latin-1")  # instrument software often writes µ or ° in Latin-1
    return parse_spectrometer_text(text, shown, unit, column, name)


def clip_measurement_negatives(measurement: SpectrometerMeasurement, what: str) -> SpectrometerMeasurement:
    """``measurement`` unchanged once its negative values are checked to be noise (``what`` names it).

    Raises
    ------
    CalibrationError
        A value below the negative-noise bound (:mod:`processing.negative_values`).
    """
    _check_negatives(
        measurement.wavelengths_nm, measurement.values, measurement.metadata.get("column") or "value", what
    )
    return measurement


def measurement_to_spectra(
    measurements: list[SpectrometerMeasurement] | SpectrometerMeasurement,
    grid: WavelengthGrid,
    unit: SpectralUnit | None = None,
) -> Spectra:
    """Measurements as one ``Spectra`` (one column each) on ``grid``, zero outside their range.

    Negative noise is clipped to 0 on each instrument grid before resampling (the one rule,
    :func:`processing.negative_values.clip_negative_noise`; a value beyond it is refused), so the
    result is ≥ 0; what was clipped is in ``metadata["clipped_negatives"]`` (one dict per LED that had any) and
    ``metadata["clipped_notes"]`` (one line each, for stderr).

    Parameters
    ----------
    unit
        The unit of the result (default: the first measurement's).
    """
    if isinstance(measurements, SpectrometerMeasurement):
        measurements = [measurements]
    if not measurements:
        raise CalibrationError("LED spectra: no measurement given; expected at least one spectrometer file")
    unit = unit or measurements[0].unit
    columns = []
    clipped: list[dict] = []
    notes: list[str] = []
    for measurement in measurements:
        values, report = _check_negatives(
            measurement.wavelengths_nm, measurement.values, measurement.name, measurement.source
        )
        clipped.extend({**item.as_dict(), "column": measurement.name, "source": measurement.source} for item in report)
        notes.extend(item.note(measurement.source) for item in report)
        try:
            native = Spectra.from_samples(
                measurement.wavelengths_nm,
                values,
                (measurement.name,),
                kind="spd",
                unit=measurement.unit,
                source=measurement.source,
            )
            column = native.to_unit(unit).resample(grid, outside="zero").values[:, 0]
        except SpectralDataError as err:
            raise CalibrationError(f"{measurement.source}: {err}") from err
        if not np.any(column > 0):
            # Resampled with zeros outside the measured range: an export that misses the grid (an IR
            # LED, a misread unit) would become an LED with no emission, silently dropped downstream.
            peak = float(measurement.wavelengths_nm[int(np.argmax(measurement.values))])
            raise CalibrationError(
                f"{measurement.source}: no emission on {grid} (measured {measurement.wavelengths_nm[0]:g}–"
                f"{measurement.wavelengths_nm[-1]:g} nm, peak at {peak:g} nm); expected an LED emitting within the grid"
            )
        columns.append(column)
    return Spectra(
        grid,
        np.column_stack(columns),
        tuple(m.name for m in measurements),
        kind="spd",
        unit=unit,
        source=", ".join(m.source for m in measurements),
        metadata={"clipped_negatives": clipped, "clipped_notes": notes},
    )
