"""A light a user measured, from a spectral table or a spectrometer export (``--target FILE``, ``--led-spectra``).

Public objects
--------------
- :func:`read_measured_light`: ``--target FILE``: a table, or an export of one light.
- :func:`read_led_export_files`: ``--led-spectra``: exports of the booth's LEDs, one per channel, as
  ``msflash calibrate leds`` reads them.

A user who measured the light to match, or the booth's LEDs, with a spectrometer hands msflash what the instrument's
program wrote — the same file ``msflash calibrate leds`` reads — or a table made from it. Both are read here, by the
two readers of a user's spectral file, which follow one set of row rules (:mod:`processing.spectral_rows`:
descending rows reversed, a repeated row read once, readings of one wavelength averaged with a warning naming the
lines, wavelengths that turn back or are not nanometres refused naming the lines):

- A file that starts as a table (after ``#`` comments, a ``wavelength_nm,<name>,…`` header) is one, read by
  :func:`processing.datasets.load_spectra_csv` (energy units); its errors are the table's.
- Any other text is read as a spectrometer export by :func:`calibration.spectrometer.read_spectrometer_file` (every
  layout it reads: OceanView, SpectraSuite, AvaSoft, SpectraWiz, Thorlabs, plain two columns, one column under a
  header giving the grid; decimal commas, UTF-16, Latin-1): one spectrum named after the file, on the export's own
  grid (:meth:`Spectra.from_samples`: an uneven CCD grid becomes 1-nm box-car means), in energy units. The dark an
  AvaSoft export stores beside its sample is taken off (:func:`calibration.spectrometer_dark.remove_baseline`); no
  other baseline is guessed — a broadband light has no out-of-band tail to measure one on. Values the export says
  are raw counts (the Ocean programs, AvaSoft's ``[counts]``, SpectraWiz ``SCOPE``, Thorlabs ``intensity``) still
  hold the spectrometer's own response: read, with a :class:`~processing.errors.SpectralDataWarning` saying so.
- A file that is neither is refused in one line naming the file and what each reader expected.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

from msflash.calibration.errors import CalibrationError
from msflash.calibration.led_exports import ExportOptions, read_led_exports, resolved_export
from msflash.calibration.spectrometer import read_spectrometer_file
from msflash.calibration.spectrometer_dark import remove_baseline
from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError, SpectralDataWarning
from msflash.processing.spectra import Spectra, WavelengthGrid
from msflash.processing.user_files import shown_path

Report = Callable[[str], None]


def _quiet(line: str) -> None:
    """A report that says nothing."""


def read_measured_light(path: str | Path, report: Report = _quiet) -> Spectra:
    """The spectra of a light file: a table's columns, or an export's one spectrum (see the module notes).

    Parameters
    ----------
    report
        Receives a note of what was done to an export (its stored dark taken off).

    Returns
    -------
    Spectra
        ``kind="spd"``, energy units, on the file's own grid; ``metadata["read_as"]`` says which reader read it
        (``"table"``, or ``"spectrometer export (OceanView)"`` …) and ``metadata["lines"]`` the file line of each
        sample where the samples are the file's rows.

    Raises
    ------
    SpectralDataError
        One line naming the file (and line): what the table reader refuses in a file that starts as a table, what
        the export reader refuses in one that does not, or, for a file that is neither, both.
    """
    where = shown_path(path)
    try:
        table = datasets.load_spectra_csv(path, kind="spd", unit="energy")
    except datasets.NotATableError as not_table:
        return _read_export(path, where, not_table, report)
    return table.replace(metadata={**table.metadata, "read_as": "table"})


def _read_export(path: str | Path, where: str, not_table: SpectralDataError, report: Report) -> Spectra:
    """The file read as a spectrometer export (it is no table: ``not_table`` says why)."""
    try:
        measurement = read_spectrometer_file(path, "energy", name=Path(path).stem)
        measurement = resolved_export(measurement, ExportOptions())
        if measurement.metadata.get("dark_values") is not None:  # AvaSoft's Dark column, stored with the sample
            measurement = remove_baseline(measurement, report=report)
        spectra = Spectra.from_samples(
            measurement.wavelengths_nm, measurement.values, (measurement.name,), "spd", measurement.unit, where
        ).to_unit("energy")
    except (CalibrationError, SpectralDataError) as err:
        raise SpectralDataError(_neither(where, not_table, err)) from None
    settings = measurement.settings
    if settings.value_unit == "counts":
        warnings.warn(
            f"{where}: the export's values are raw spectrometer counts ({settings.instrument}): the spectrometer's "
            "own response is still in them, so the light's shape is off by it; expected an irradiance export "
            "(energy units), or a table wavelength_nm,value made from one",
            SpectralDataWarning,
            stacklevel=3,
        )
    metadata = {
        **spectra.metadata,
        "read_as": f"spectrometer export ({settings.instrument})",
        "path": where,
        "acquisition": settings.as_dict(),
        "order": measurement.metadata.get("order", ()),
    }
    if spectra.grid.size == measurement.wavelengths_nm.size:  # uniform: the samples are the export's rows
        metadata["lines"] = tuple(measurement.metadata.get("lines", ()))
    return spectra.replace(metadata=metadata)


def _neither(where: str, not_table: Exception, as_export: Exception) -> str:
    """The export reader's refusal; when it found no data rows at all, what the table reader expected too."""
    export_reason = str(as_export)
    if re.match(rf"{re.escape(where)}:\d+: ", export_reason):  # it read data rows and refused one: an export
        return export_reason
    table_reason = str(not_table).removeprefix(f"{where}:").lstrip(" ")
    if table_reason[:1].isdigit():
        table_reason = f"line {table_reason}"
    return (
        f"{where}: neither a spectral table nor a spectrometer export: as a table, {table_reason}; as an export, "
        f"{export_reason.removeprefix(f'{where}:').lstrip(' ')}"
    )


def read_led_export_files(paths: Sequence[str | Path], grid: WavelengthGrid, report: Report = _quiet) -> Spectra:
    """LED spectra on ``grid`` from spectrometer exports, one per LED in channel order, read as
    ``msflash calibrate leds`` reads them with no options (:func:`calibration.led_exports.read_led_exports`: the
    baseline taken off — the dark an AvaSoft export stores, else the out-of-band tail, with a warning through
    ``report`` —, counts per second when the integration times are stated). Exports of raw counts still hold the
    spectrometer's own response: read, with a warning through ``report`` (``msflash calibrate leds
    --spectrometer-response`` makes them energy).

    Raises
    ------
    SpectralDataError
        One line naming the file (and line): what ``calibrate leds`` refuses.
    """
    try:
        exports = read_led_exports(
            paths, grid, ExportOptions(), lambda line: report(_calibrate_hint(line)), relative=True
        )
    except CalibrationError as err:
        raise SpectralDataError(_calibrate_hint(str(err))) from None
    if exports.unit == "counts":
        shown = ", ".join(shown_path(p) for p in paths[:3]) + (" …" if len(paths) > 3 else "")
        report(
            f"warning: {shown}: raw spectrometer counts: the spectrometer's own response is still in the LED "
            "spectra (their shapes and ratios); expected energy: 'msflash calibrate leds FILES --spectrometer-response "
            "FILE --out DIR', then --calibration DIR"
        )
    return exports.spectra.replace(
        metadata={**exports.spectra.metadata, "read_as": "spectrometer exports", "leds": exports.section}
    )


def _calibrate_hint(line: str) -> str:
    """``line`` with where its ``--dark``/``--no-dark`` are: options of ``calibrate leds``, not of the rig's commands."""
    if "--dark" not in line:
        return line
    return f"{line} (options of 'msflash calibrate leds FILES --out DIR', whose DIR --calibration takes)"
