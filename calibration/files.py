"""Versioned calibration files: one directory with ``calibration.json`` and its CSV tables.

Layout (format ``msflash-calibration``, version 2; version 1 files are read as before)::

    calibration.json   id, created_utc, and one optional section per measurement:
                         "leds":   {"file": "leds.csv", "unit", "names", "peaks_nm", "fwhm_nm",
                                    "models", "relative_power", "sources", "warnings",
                                    "acquisition", "baselines", "counts_per_second",
                                    "spectrometer_response"}
                         "chart":  {"file": "chart.csv", "names", "rows", "columns", "sources"}
                         "camera": {"file": "camera.csv", "unit", "channels", "method", "validation"}
                         "dark":   {"black_level": [per channel], "read_noise_dn": [...], "cfa"}
                         "linearity": {"slope_dn_per_exposure": [...], "max_relative_deviation",
                                       "emva_nonlinearity", "saturation_level", "linear_limit_dn", …}
    leds.csv           wavelength_nm, one column per LED (full-drive spectra, true ratios)
    camera.csv         wavelength_nm, R, G, B (responsivities)
    chart.csv          wavelength_nm, one reflectance per chart patch (``calibrate chart``)

Unknown keys are kept and written back; a newer ``version`` is refused; what version 2 added:
``docs/calibration.md`` ("Files"). The CSV tables hold values ≥ 0 (negative noise clipped on writing
and reading by :mod:`processing.negative_values`, reported in the section's ``clipped_negatives`` or
:attr:`CalibrationSet.notes`); hostile JSON is refused naming the file and field
(:mod:`processing.json_input`). A sequence refers to a calibration with ``"calibration": {"id": …,
"file": "<dir>"}`` (relative to the sequence directory, or absolute). Each calibrate command updates
the sections it measures and keeps the others; every save gets a new ``id``.
"""

from __future__ import annotations

import json
import math
import os
import uuid
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, cast

import numpy as np

from msflash.calibration.errors import CalibrationError
from msflash.calibration.file_modes import write_whole
from msflash.processing.datasets import load_spectra_csv
from msflash.processing.errors import SpectralDataError
from msflash.processing.json_input import parse_json_document
from msflash.processing.led_wavelength import PEAK_METADATA_KEY
from msflash.processing.negative_values import blind_columns, clip_negative_noise
from msflash.processing.spectra import Spectra, SpectralKind, SpectralUnit
from msflash.processing.user_files import JSON_MAX_BYTES, read_user_text, shown_path

FORMAT = "msflash-calibration"
VERSION = 2
"""Written; every version up to it is read (1: no ``counts`` unit, no chart section)."""
CALIBRATION_FILE = "calibration.json"
LED_FILE = "leds.csv"
CAMERA_FILE = "camera.csv"
CHART_FILE = "chart.csv"
_KNOWN = ("format", "version", "id", "created_utc", "leds", "camera", "dark", "linearity", "chart")


def new_calibration_id() -> str:
    """A fresh id: UTC time plus 8 random hex digits."""
    return f"cal-{datetime.now(UTC):%Y%m%dT%H%M%SZ}-{uuid.uuid4().hex[:8]}"


@dataclass(frozen=True)
class CalibrationSet:
    """A calibration: any of LED spectra, camera responsivities, dark and linearity results."""

    id: str = field(default_factory=new_calibration_id)
    """Identifier, new on every save (sequences record it)."""
    created_utc: str = field(default_factory=lambda: datetime.now(UTC).isoformat(timespec="seconds"))
    """When it was written."""
    led_spectra: Spectra | None = None
    """LED spectra at full drive, (n_wavelengths, k), true ratios between LEDs (energy; spectrometer
    counts read as relative energy when ``leds["unit"]`` is ``counts``)."""
    leds: dict = field(default_factory=dict)
    """The ``leds`` section without the spectra: peaks, FWHM, models, relative power, warnings;
    ``unit`` only when it is ``counts``."""
    camera_responsivities: Spectra | None = None
    """Camera responsivities, (n_wavelengths, 3), channels R, G, B."""
    camera: dict = field(default_factory=dict)
    """The ``camera`` section without the curves: method, validation."""
    dark: dict | None = None
    """Black level per channel and read noise."""
    linearity: dict | None = None
    """Linearity and saturation level."""
    chart_reflectances: Spectra | None = None
    """The chart's patches as measured (``calibrate chart``), (n_wavelengths, n_patches), in chart order."""
    chart: dict = field(default_factory=dict)
    """The ``chart`` section without the table: rows, columns, sources."""
    extra: dict = field(default_factory=dict)
    """Unknown top-level keys, kept."""
    notes: tuple[str, ...] = field(default=(), compare=False)
    """What reading it changed (negative noise clipped to 0), one line each, for stderr."""

    def updated(self, **changes: Any) -> CalibrationSet:
        """A copy with some sections changed and a new id and time."""
        return replace(
            self,
            id=new_calibration_id(),
            created_utc=datetime.now(UTC).isoformat(timespec="seconds"),
            notes=(),
            **changes,
        )


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _csv_text(spectra: Spectra, calibration_id: str, what: str, unit: str | None = None) -> str:
    lines = [
        f"# msflash calibration {calibration_id}: {what}, unit {unit or spectra.unit}",
        "wavelength_nm," + ",".join(spectra.names),
    ]
    for wavelength, row in zip(spectra.wavelengths_nm, spectra.values):
        lines.append(f"{wavelength:g}," + ",".join(repr(float(v)) for v in row))
    return "\n".join(lines) + "\n"


def _without_negative_noise(spectra: Spectra, what: str, section: dict) -> tuple[Spectra, dict]:
    """``spectra`` with negative noise clipped (what :func:`load_calibration` reads back is what was written).

    The clipped columns are added to the section's ``clipped_negatives``; a value beyond noise is
    refused before anything is written.
    """
    try:
        values, report = clip_negative_noise(spectra.wavelengths_nm, spectra.values, spectra.names, what)
    except SpectralDataError as err:
        raise CalibrationError(f"{err} (not written)") from None
    blind = blind_columns(values, spectra.names)
    if blind:  # the reader refuses it: never written
        raise CalibrationError(f"{what}: column '{blind[0]}' has no positive value on {spectra.grid} (not written)")
    if not report:
        return spectra, section
    clipped = [*(section.get("clipped_negatives") or []), *(item.as_dict() for item in report)]
    return spectra.replace(values=values), {**section, "clipped_negatives": clipped}


def save_calibration(calibration: CalibrationSet, directory: str | Path) -> Path:
    """Write a calibration directory (created if needed); returns the ``calibration.json`` path.

    Spectra are written ≥ 0: negative noise is clipped by the rule every reader applies
    (:func:`processing.negative_values.clip_negative_noise`) and recorded in the section's
    ``clipped_negatives``; a value beyond noise raises :class:`CalibrationError` and nothing is written.
    """
    directory = Path(directory)
    leds, led_section = (
        _without_negative_noise(calibration.led_spectra, "LED spectra", calibration.leds)
        if calibration.led_spectra is not None
        else (None, calibration.leds)
    )
    camera, camera_section = (
        _without_negative_noise(calibration.camera_responsivities, "camera responsivities", calibration.camera)
        if calibration.camera_responsivities is not None
        else (None, calibration.camera)
    )
    calibration = replace(
        calibration, led_spectra=leds, leds=led_section, camera_responsivities=camera, camera=camera_section
    )
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise CalibrationError(f"{directory}: cannot create the calibration directory ({err.strerror or err})") from err
    document: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "id": calibration.id,
        "created_utc": calibration.created_utc,
    }
    if calibration.led_spectra is not None:
        led_unit = "counts" if calibration.leds.get("unit") == "counts" else calibration.led_spectra.unit
        write_whole(directory / LED_FILE, _csv_text(calibration.led_spectra, calibration.id, "LED spectra", led_unit))
        document["leds"] = {
            **calibration.leds,
            "file": LED_FILE,
            "unit": led_unit,
            "names": list(calibration.led_spectra.names),
        }
    if calibration.camera_responsivities is not None:
        write_whole(
            directory / CAMERA_FILE,
            _csv_text(calibration.camera_responsivities, calibration.id, "camera responsivities"),
        )
        document["camera"] = {
            **calibration.camera,
            "file": CAMERA_FILE,
            "unit": calibration.camera_responsivities.unit,
            "channels": list(calibration.camera_responsivities.names),
        }
    if calibration.chart_reflectances is not None:
        write_whole(
            directory / CHART_FILE, _csv_text(calibration.chart_reflectances, calibration.id, "chart reflectances")
        )
        document["chart"] = {
            **calibration.chart,
            "file": CHART_FILE,
            "names": list(calibration.chart_reflectances.names),
        }
    if calibration.dark is not None:
        document["dark"] = calibration.dark
    if calibration.linearity is not None:
        document["linearity"] = calibration.linearity
    document.update(calibration.extra)
    path = directory / CALIBRATION_FILE
    write_whole(path, json.dumps(_plain(document), indent=2, allow_nan=False) + "\n")
    return path


def _section(path: Path, document: dict, key: str) -> dict | None:
    value = document.get(key)
    if value is None:
        return None
    if not isinstance(value, dict):
        raise CalibrationError(f"{path}: field '{key}' is a {type(value).__name__}; expected an object")
    return value


def _spectra(
    path: Path, section: dict, key: str, kind: SpectralKind, names_key: str
) -> tuple[Spectra, tuple[str, ...]]:
    file_name = section.get("file")
    if not isinstance(file_name, str) or not file_name:
        raise CalibrationError(f"{path}: field '{key}.file' is {file_name!r}; expected a CSV file name")
    table = path.parent / file_name
    if Path(file_name).is_absolute() or ".." in Path(file_name).parts:
        raise CalibrationError(
            f"{path}: field '{key}.file' '{file_name}' leaves the calibration directory; expected a file name inside it"
        )
    unit = "none" if kind == "reflectance" else section.get("unit")
    if unit == "counts" and key == "leds":
        unit = "energy"  # spectrometer counts, read as relative energy (load_calibration notes it)
    if unit not in ("energy", "photons", "none"):
        raise CalibrationError(
            f"{path}: field '{key}.unit' is {unit!r}; expected 'energy' or 'photons'"
            + (" (or 'counts')" if key == "leds" else "")
        )
    if not os.path.lexists(table):  # anything else there (a directory, a FIFO) the table reader names
        raise CalibrationError(f"{path}: field '{key}.file': {table} is missing; expected the CSV table beside it")
    try:
        spectra = load_spectra_csv(table, kind=kind, unit=cast(SpectralUnit, unit))
    except SpectralDataError as err:
        raise CalibrationError(f"{path}: field '{key}.file': {err}") from err
    names = section.get(names_key)
    if names is not None and (not isinstance(names, list) or names != list(spectra.names)):
        raise CalibrationError(
            f"{path}: field '{key}.{names_key}' is {_shown(names)}; expected the columns of "
            f"{table.name}: {list(spectra.names)}"
        )
    try:
        values, report = clip_negative_noise(spectra.wavelengths_nm, spectra.values, spectra.names, shown_path(table))
    except SpectralDataError as err:
        raise CalibrationError(str(err)) from None
    blind = blind_columns(values, spectra.names)
    if blind:
        raise CalibrationError(
            f"{shown_path(table)}: column '{blind[0]}' has no positive value on {spectra.grid}; expected "
            f"{'a sensitivity' if kind == 'responsivity' else 'an emission'} somewhere on the grid ({path.name} field '{key}')"
        )
    return spectra.replace(values=values), tuple(item.note(shown_path(table)) for item in report)


def _shown(value: Any) -> str:
    """A JSON value for a message: its repr, cut to one short line."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _number_list(
    path: Path,
    section: dict,
    key: str,
    field_name: str,
    *,
    minimum: float | None = None,
    sizes: tuple[int, int] = (0, 10_000),
) -> None:
    value = section.get(field_name)
    if value is None:
        return
    if not isinstance(value, list) or not all(_is_number(v) for v in value):
        raise CalibrationError(f"{path}: field '{key}.{field_name}' is {_shown(value)}; expected a list of numbers")
    if not sizes[0] <= len(value) <= sizes[1]:
        raise CalibrationError(
            f"{path}: field '{key}.{field_name}' has {len(value)} values; expected {sizes[0]}–{sizes[1]}"
        )
    if minimum is not None and any(v < minimum for v in value):
        bad = next(v for v in value if v < minimum)
        raise CalibrationError(f"{path}: field '{key}.{field_name}' holds {bad!r}; expected numbers ≥ {minimum:g}")


def _optional_number(path: Path, section: dict, key: str, field_name: str) -> None:
    value = section.get(field_name)
    if value is not None and not _is_number(value):
        raise CalibrationError(f"{path}: field '{key}.{field_name}' is {_shown(value)}; expected a number or null")


def load_calibration(directory: str | Path) -> CalibrationSet:
    """Read and validate a calibration directory (or its ``calibration.json``).

    Raises
    ------
    CalibrationError
        Naming the file and field: missing or unreadable file, wrong format, a newer version,
        a section of the wrong type, a missing or malformed table.
    """
    directory = Path(directory)
    path = directory if directory.suffix == ".json" else directory / CALIBRATION_FILE
    document = _read_document(path)
    calibration_id, created = document["id"], document.get("created_utc", "")
    led_section = _section(path, document, "leds")
    chart_section = _section(path, document, "chart")
    camera_section = _section(path, document, "camera")
    dark = _section(path, document, "dark")
    linearity = _section(path, document, "linearity")
    led_spectra = camera = chart = None
    notes: tuple[str, ...] = ()
    if led_section is not None:
        led_spectra, clipped = _led_spectra(path, led_section)
        notes += clipped
    if chart_section is not None:
        chart, clipped = _chart(path, chart_section)
        notes += clipped
    if camera_section is not None:
        camera, clipped = _spectra(path, camera_section, "camera", "responsivity", "channels")
        notes += clipped
        if camera.count != 3:
            raise CalibrationError(f"{path}: field 'camera.file' holds {camera.count} channels; expected R, G, B")
    if dark is not None:
        _check_dark(path, dark)
    if linearity is not None:
        _number_list(path, linearity, "linearity", "slope_dn_per_exposure", sizes=(1, 4))
        for name in ("max_relative_deviation", "emva_nonlinearity", "saturation_level", "linear_limit_dn"):
            _optional_number(path, linearity, "linearity", name)
    strip = ("file", "unit", "names", "channels")
    return CalibrationSet(
        id=calibration_id,
        created_utc=str(created),
        led_spectra=led_spectra.replace(source=f"calibration {calibration_id} ({led_spectra.source})")
        if led_spectra
        else None,
        leds={k: v for k, v in (led_section or {}).items() if k not in strip or (k, v) == ("unit", "counts")},
        camera_responsivities=camera.replace(source=f"calibration {calibration_id} ({camera.source})")
        if camera
        else None,
        camera={k: v for k, v in (camera_section or {}).items() if k not in strip},
        dark=dark,
        linearity=linearity,
        chart_reflectances=chart.replace(source=f"calibration {calibration_id} ({chart.source})") if chart else None,
        chart={k: v for k, v in (chart_section or {}).items() if k not in strip},
        extra={k: v for k, v in document.items() if k not in _KNOWN},
        notes=notes,
    )


def _read_document(path: Path) -> dict:
    """``calibration.json`` read safely and parsed: format, a version this msflash reads, an id, a time."""
    if not os.path.lexists(path):
        raise CalibrationError(
            f"{shown_path(path)}: cannot be read (No such file or directory); expected a "
            "calibration directory written by 'msflash calibrate'"
        )
    text = read_user_text(
        path,
        f"a calibration's {CALIBRATION_FILE} (UTF-8 JSON) written by 'msflash calibrate'",
        JSON_MAX_BYTES,
        CalibrationError,
    )
    document = parse_json_document(text, shown_path(path), CalibrationError)  # NaN, huge numbers, deep nesting named
    if not isinstance(document, dict):
        raise CalibrationError(f"{path}: top level is a {type(document).__name__}; expected an object")
    if document.get("format") != FORMAT:
        raise CalibrationError(f"{path}: field 'format' is {document.get('format')!r}; expected '{FORMAT}'")
    version = document.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise CalibrationError(f"{path}: field 'version' is {version!r}; expected a whole number ≥ 1")
    if version > VERSION:
        raise CalibrationError(
            f"{path}: field 'version' is {version}; this msflash reads version {VERSION} — upgrade msflash to read it"
        )
    calibration_id = document.get("id")
    if not isinstance(calibration_id, str) or not calibration_id:
        raise CalibrationError(f"{path}: field 'id' is {calibration_id!r}; expected a non-empty string")
    created = document.get("created_utc", "")
    if not isinstance(created, str):
        raise CalibrationError(f"{path}: field 'created_utc' is {_shown(created)}; expected an ISO 8601 time string")
    return document


def _led_spectra(path: Path, section: dict) -> tuple[Spectra, tuple[str, ...]]:
    """The ``leds`` section's spectra (with their measured peaks) and notes (clipped noise, counts)."""
    led_spectra, notes = _spectra(path, section, "leds", "spd", "names")
    for name in ("peaks_nm", "fwhm_nm", "centroids_nm"):
        _number_list(path, section, "leds", name)
    peaks = section.get("peaks_nm")
    if isinstance(peaks, list) and len(peaks) == led_spectra.count:
        # Measured on the spectrometer's own sampling: the one number for each LED (processing/led_wavelength.py).
        led_spectra = led_spectra.replace(
            metadata={**led_spectra.metadata, PEAK_METADATA_KEY: dict(zip(led_spectra.names, peaks, strict=True))}
        )
    _number_list(path, section, "leds", "relative_power", minimum=0.0)
    if section.get("unit") == "counts":
        ratios = (
            "ratios measured through the camera (--white), shapes"
            if section.get("relative_power_source")
            else "shapes and ratios"
        )
        notes += (
            f"{shown_path(path)}: LED spectra are spectrometer counts: the spectrometer's response is still in "
            f"their {ratios} (calibrate leds --spectrometer-response FILE makes them energy)",
        )
    return led_spectra, notes


def _chart(path: Path, section: dict) -> tuple[Spectra, tuple[str, ...]]:
    """The ``chart`` section's reflectances, its grid (rows × columns) matching the patch count."""
    chart, notes = _spectra(path, section, "chart", "reflectance", "names")
    for name in ("rows", "columns"):
        value = section.get(name)
        if value is not None and (not isinstance(value, int) or isinstance(value, bool) or value < 1):
            raise CalibrationError(f"{path}: field 'chart.{name}' is {_shown(value)}; expected a whole number ≥ 1")
    rows, columns = section.get("rows"), section.get("columns")
    if rows is not None and columns is not None and rows * columns != chart.count:
        raise CalibrationError(
            f"{path}: fields 'chart.rows' × 'chart.columns' are {rows} × {columns}; expected {chart.count}, the "
            "number of patches in the chart's file"
        )
    return chart, notes


def _check_dark(path: Path, dark: dict) -> None:
    """The ``dark`` section: a black level per channel, read noise, a Bayer layout name or null."""
    if "black_level" not in dark:
        raise CalibrationError(f"{path}: field 'dark.black_level' is missing; expected one number per channel")
    _number_list(path, dark, "dark", "black_level", sizes=(1, 4))
    _number_list(path, dark, "dark", "read_noise_dn", minimum=0.0, sizes=(1, 4))
    cfa = dark.get("cfa")
    if cfa is not None and not isinstance(cfa, str):
        raise CalibrationError(f"{path}: field 'dark.cfa' is {_shown(cfa)}; expected null or a Bayer layout name")


def load_or_new(directory: str | Path) -> CalibrationSet:
    """The calibration in ``directory`` if there is one (to update), else an empty one."""
    directory = Path(directory)
    if (directory / CALIBRATION_FILE).exists():
        return load_calibration(directory)
    return CalibrationSet()
