"""From the LED exports a spectrometer wrote to LED spectra: unit, integration time, dark, response.

Public objects
--------------
- :class:`ExportOptions`: what the user says about the exports (unit, integration time, dark, response).
- :class:`LedExports`, :func:`read_led_exports`: the exports read, their baselines removed, made
  counts per second, and energy when a response is given; with what the calibration records.
- :func:`read_spectrometer_response`: the spectrometer's response (irradiance calibration) on a grid.
- :func:`resolved_export`: an export's unit and integration time, as its header states them or the options say.

Units
-----
A raw-counts export still holds the spectrometer's own response (grating efficiency, detector
quantum efficiency, fibre): its counts stay **counts** — per second when the integration times
are known — until divided by the spectrometer's response (``--spectrometer-response``), which
makes them **energy**. The unit of an export is what its header says (AvaSoft's ``[counts]``
row, SpectraWiz ``SCOPE``, Thorlabs ``#YAxisUnit``), ``counts`` for the Ocean programs (their
exports do not say; scope mode is counts), else ``--unit`` (default ``energy`` for a plain file,
which is what a spectroradiometer such as the paper's PR-715 writes; a note says so). A ``--unit``
contradicting the header is refused.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from msflash.calibration.errors import CalibrationError
from msflash.calibration.spectrometer import (
    SpectrometerMeasurement,
    measurement_to_spectra,
    read_spectrometer_file,
)
from msflash.calibration.spectrometer_dark import counts_per_second, divide_by_response, remove_baseline
from msflash.processing.spectra import Spectra, WavelengthGrid

Report = Callable[[str], None]
ExportUnit = Literal["energy", "photons", "counts"]
_OCEAN = ("OceanView", "SpectraSuite", "OOIBase32")


@dataclass(frozen=True)
class ExportOptions:
    """What the user says about the exports (``msflash calibrate leds`` options)."""

    unit: ExportUnit | None = None
    """What the value column holds; None: the header's word, else counts (Ocean) or energy (plain)."""
    column: int | None = None
    """The value column when a file has more than two (AvaSoft: Sample by default)."""
    integration_time_s: float | None = None
    """For exports (and the dark) whose header states none."""
    dark: str | Path | tuple[str | Path, ...] | None = None
    """A dark export (shutter closed), or one per integration time (each export takes the dark of its
    own time; with none of its time, the nearest, scaled as :func:`remove_baseline` allows)."""
    no_dark: bool = False
    """The exports need no dark: take them as they are."""
    response: str | Path | None = None
    """The spectrometer's response (irradiance calibration): counts per unit energy, or energy per count."""


@dataclass(frozen=True)
class LedExports:
    """LED exports read as the instrument wrote them."""

    measurements: tuple[SpectrometerMeasurement, ...]
    """On the instrument grid, baseline removed (values before counts-per-second and the response)."""
    spectra: Spectra
    """One column per LED on the grid: energy (or photons), or counts (per second) when ``unit`` is counts."""
    unit: ExportUnit
    """``counts`` (the spectrometer's response still in them), ``energy`` or ``photons``."""
    section: dict[str, Any]
    """What the calibration's ``leds`` section records about the exports."""


def resolved_export(measurement: SpectrometerMeasurement, options: ExportOptions) -> SpectrometerMeasurement:
    """The export with its unit (``settings.value_unit``) and integration time settled (see the module notes)."""
    settings = measurement.settings
    stated = settings.value_unit
    if options.unit is not None and stated is not None and options.unit != stated:
        raise CalibrationError(
            f"{measurement.source}: --unit {options.unit} but the export's header says its values are {stated} "
            f"({settings.instrument}); expected --unit {stated}, or no --unit"
        )
    unit = options.unit or stated or ("counts" if settings.instrument in _OCEAN else "energy")
    time = settings.integration_time_s
    if time is None:
        time = options.integration_time_s  # the option fills in what the header does not state
    return replace(
        measurement,
        unit="photons" if unit == "photons" else "energy",
        settings=replace(settings, value_unit=unit, integration_time_s=time),
    )


def dark_paths(options: ExportOptions) -> tuple[str | Path, ...]:
    """The dark exports given (``--dark``, once or once per integration time)."""
    if options.dark is None:
        return ()
    return tuple(options.dark) if isinstance(options.dark, tuple | list) else (options.dark,)


def _dark_record(options: ExportOptions) -> str | list[str] | None:
    paths = [str(p) for p in dark_paths(options)]
    return None if not paths else paths[0] if len(paths) == 1 else paths


def _check_darks(darks: list[SpectrometerMeasurement]) -> None:
    """Several darks: each states its integration time, no two the same."""
    if len(darks) < 2:
        return
    seen: dict[float, str] = {}
    for dark in darks:
        time = dark.settings.integration_time_s
        if time is None:
            raise CalibrationError(
                f"--dark {dark.source}: states no integration time; expected each of several darks to state its "
                "own (a header line), so that each export takes the dark of its time"
            )
        if time in seen:
            raise CalibrationError(
                f"--dark {dark.source} and {seen[time]} are both {1e3 * time:g} ms; expected one dark per "
                "integration time"
            )
        seen[time] = dark.source


def _dark_for(
    measurement: SpectrometerMeasurement, darks: list[SpectrometerMeasurement]
) -> SpectrometerMeasurement | None:
    """The dark of the export's integration time; else the one nearest it (scaled, or refused, by remove_baseline)."""
    if len(darks) < 2:
        return darks[0] if darks else None
    time = measurement.settings.integration_time_s
    if time is None:
        return darks[0]  # remove_baseline refuses an unstated time against a stated one, naming both
    return min(darks, key=lambda dark: abs(np.log((dark.settings.integration_time_s or time) / time)))


def read_spectrometer_response(path: str | Path, grid: WavelengthGrid) -> Spectra:
    """The spectrometer's response on ``grid``: signal per unit energy, one column (any common scale).

    The file is any export :func:`calibration.spectrometer.read_spectrometer_file` reads (two
    columns, or ``--column``-free AvaSoft), on any grid. Its value column holds counts per second
    per unit irradiance (what dividing by it makes energy) — or, when its header names the column
    *per count* (``µJ/count``, ``uW/cm2/nm per count``, the form of Ocean's irradiance calibration
    files), energy per count, which is inverted.

    Raises
    ------
    CalibrationError
        Naming the file: what the spectrometer reader refuses, or a response that misses the grid.
    """
    measurement = read_spectrometer_file(path, "energy", None, Path(path).stem)
    column = str(measurement.metadata.get("column") or "")
    per_count = bool(re.search(r"/\s*counts?\b|per\s+counts?\b", column, re.IGNORECASE))
    if per_count:
        positive = measurement.values > 0
        values = np.where(positive, 1.0 / np.where(positive, measurement.values, 1.0), 0.0)
        measurement = replace(measurement, values=values)
    spectra = measurement_to_spectra(measurement, grid)
    return spectra.replace(
        names=("response",),
        source=f"{measurement.source} ({'energy per count, inverted' if per_count else 'counts per unit energy'})",
    )


def read_led_exports(
    files: Sequence[str | Path],
    grid: WavelengthGrid,
    options: ExportOptions,
    report: Report = lambda line: None,
    relative: bool = False,
) -> LedExports:
    """Read one export per LED; remove each baseline; counts per second; energy if a response is given.

    ``relative``: the exports are only compared with each other on one instrument (a chart's
    patches against its white), so counts need no response and no warning.

    Raises
    ------
    CalibrationError
        One line naming the file (and line or field): what the reader, the unit and time checks
        (:func:`resolved_export`), the baseline (:func:`calibration.spectrometer_dark.remove_baseline`)
        and the response refuse; exports mixing raw counts and calibrated units; a response given
        for calibrated exports.
    """
    if not files:
        raise CalibrationError("LED spectra: no export given; expected one spectrometer file per LED")
    darks = [
        resolved_export(read_spectrometer_file(path, "energy", options.column), options) for path in dark_paths(options)
    ]
    if darks and options.no_dark:
        raise CalibrationError(f"--dark {darks[0].source} and --no-dark exclude each other; expected one")
    _check_darks(darks)
    measurements = []
    unstated = []
    for file in files:
        measurement = resolved_export(read_spectrometer_file(file, "energy", options.column), options)
        if options.unit is None and measurement.settings.instrument == "plain":
            unstated.append(measurement.source)
        measurements.append(remove_baseline(measurement, _dark_for(measurement, darks), options.no_dark, report))
    if unstated:
        report(
            f"{', '.join(unstated[:3])}{' …' if len(unstated) > 3 else ''}: the export does not say what its values "
            "are: taken as energy (--unit counts for raw spectrometer counts)"
        )
    units = {m.settings.value_unit for m in measurements}
    if len(units) > 1:
        raise CalibrationError(
            "LED exports mix "
            + " and ".join(
                f"{u} ({next(m.source for m in measurements if m.settings.value_unit == u)})"
                for u in sorted(str(u) for u in units)
            )
            + "; expected one unit for all (--unit)"
        )
    unit: ExportUnit = measurements[0].settings.value_unit  # type: ignore[assignment]
    scaled, per_second = counts_per_second(measurements, report)
    spectra = measurement_to_spectra(scaled, grid)
    response_source = None
    if options.response is not None:
        if unit != "counts":
            raise CalibrationError(
                f"--spectrometer-response {options.response}: the exports are already {unit}; expected raw-counts "
                "exports to divide by it"
            )
        response = read_spectrometer_response(options.response, grid)
        spectra = divide_by_response(spectra, response, str(options.response))
        unit, response_source = "energy", response.source
    elif unit == "counts" and not relative:
        report(
            "warning: LED spectra stored as spectrometer counts"
            + (" per second" if per_second else "")
            + ": the spectrometer's own response is still in them (shapes and ratios); give "
            "--spectrometer-response FILE (its irradiance calibration) to make them energy, or measure the "
            "ratios through the camera with --white SEQ"
        )
    section: dict[str, Any] = {
        "unit": unit,
        "counts_per_second": per_second,
        "spectrometer_response": response_source,
        "acquisition": [m.settings.as_dict() for m in measurements],
        "baselines": [m.metadata.get("baseline") for m in measurements],
        "dark": _dark_record(options),
        "no_dark": options.no_dark,
    }
    return LedExports(tuple(measurements), spectra, unit, section)
