"""Shipped spectral data and standard illuminants, loaded as :class:`~processing.spectra.Spectra`.

Public objects
--------------
- :func:`load_spectra_csv`: the one CSV reader for spectral tables.
- Paper data (Blasinski & Farrell 2017): :func:`paper_leds`, :func:`paper_led_subset`,
  :func:`natural100`, :func:`chart110`, :func:`macbeth`, :func:`paper_cameras`.
- Other shipped sets: :func:`isetcam_camera`, :func:`isetcam_leds`, :func:`vrhel`,
  :func:`water_absorption` (a path's transmittance is :func:`processing.water.water_transmittance`).
- Any shipped camera by name: :func:`camera_names`, :func:`camera_responsivities`.
- Illuminants: :func:`illuminant` (colour-science's CIE tables and black bodies). The ambients
  of the simulated rig and lights by name are :mod:`processing.lights`.

Files live in ``processing/data`` with their provenance and licences in
``processing/data/SOURCES.md``. Loaders return spectra on the file's own grid; callers resample
with :meth:`Spectra.resample`. Only :func:`illuminant` and :func:`cie1931_cmfs` take a
grid, because they compute or convert rather than read a file.

This module is the only place that converts colour-science objects into ``Spectra``.

References
----------
Blasinski H., Farrell J. "Computational multispectral flash", ICCP 2017.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from msflash.processing.errors import SpectralDataError
from msflash.processing.led_wavelength import PEAK_METADATA_KEY, led_name, led_peaks_nm, with_peaks
from msflash.processing.names import unknown_name
from msflash.processing.spectra import (
    DEFAULT_GRID,
    MAX_TABLE_MAGNITUDE,
    MIN_TABLE_PEAK,
    Spectra,
    SpectralKind,
    SpectralUnit,
    WavelengthGrid,
    require_same_grid,
    tiny_columns,
)
from msflash.processing.spectral_rows import in_wavelength_order
from msflash.processing.user_files import SPECTRAL_TABLE_MAX_BYTES, printable, read_user_bytes, shown_path
from msflash.processing.user_numbers import plain_number, written_as_number

DATA_DIR = Path(__file__).resolve().parent / "data"
"""Folder of the shipped data files (see ``SOURCES.md`` there)."""

PAPER_LED_PEAKS_NM = (440, 480, 500, 520, 596, 636, 660)
"""The paper's nominal peaks of its 7 Luxeon LEDs ("≈"), in file order. Not the LEDs' names: those are
made from the measured peaks (:func:`paper_leds`)."""

PAPER_LED_SUBSETS: dict[int, tuple[int, ...]] = {
    3: (1, 4, 7),
    4: (1, 3, 4, 7),
    5: (1, 3, 4, 5, 7),
    6: (1, 2, 3, 4, 5, 7),
    7: (1, 2, 3, 4, 5, 6, 7),
}
"""The paper's LED subsets by count, as 1-based indices into :func:`paper_leds` (Section 5)."""

ISETCAM_CAMERAS = (
    "AptinaMT9M031",
    "AptinaMT9M131",
    "NikonD1",
    "NikonD70",
    "NikonD100",
    "NikonD200IR",
    "NikonD2xsNikon50mm",
)
"""Cameras whose ISETCam responsivities are shipped (MIT licence)."""

ISETCAM_LED_SETS = {
    "luxeon8": "LuxeonLEDSpectra_8LED.csv",
    "luxeon4": "Luxeon4LEDs.csv",
    "luxeon5": "Luxeon5LEDs.csv",
    "six": "SixLEDs.csv",
    "ledsix": "ledSixSpectra.csv",
}
"""ISETCam LED sets by short name."""

VRHEL_SETS = {
    "objects": "Objects_Vhrel.csv",
    "munsell": "MunsellSamples_Vhrel.csv",
    "dupont": "DupontPaintChip_Vhrel.csv",
    "nature": "Nature_Vhrel.csv",
    "food": "Food_Vhrel.csv",
    "clothes": "Clothes_Vhrel.csv",
    "hair": "Hair_Vhrel.csv",
    "skin_african_american": "AfricanAmerican_Vhrel.csv",
    "skin_asian": "Asian_Vhrel.csv",
    "skin_caucasian": "Caucasian_Vhrel.csv",
    "skin_east_indian": "EastIndian_Vhrel.csv",
}
"""Vrhel et al. (1994) reflectance sets by short name; ``"skin"`` joins the four skin sets."""

_ISETCAM_LICENCE = "MIT (ISETCam, © 2020 Stanford SCIEN); see processing/data/LICENSE-ISETCam-MIT.txt"
_PAPER_LICENCE = "no licence stated by the authors (hblasins/compMultispFlash); cite Blasinski & Farrell 2017"
_JIANG_LICENCE = (
    "CC BY-NC-SA 4.0 (Jiang et al. 2013, © RIT); non-commercial; see processing/data/noncommercial/LICENSE.md"
)


# -- the CSV reader ---------------------------------------------------------------------------
_TABLE = "a spectral table (UTF-8 CSV file)"


class NotATableError(SpectralDataError):
    """A file that does not start as a spectral table: not UTF-8 text, or its first line (after comments) is no
    ``wavelength_nm,<name>,…`` header. It may be a spectrometer export (:mod:`calibration.light_files` reads both)."""


def _cut(cell: str) -> str:
    """A cell quoted in a message: at most 40 characters (a 5000-digit number stays readable)."""
    return cell if len(cell) <= 40 else f"{cell[:37]}... ({len(cell)} characters)"


def load_spectra_csv(
    path: str | Path,
    kind: SpectralKind,
    unit: SpectralUnit,
    names: Sequence[str] | None = None,
    source: str | None = None,
    nan: Literal["error", "zero"] = "error",
) -> Spectra:
    """Read a spectral table: first column ``wavelength_nm``, one column per spectrum.

    Lines starting with ``#`` are comments (kept in ``metadata["comments"]``), blank lines are
    skipped, the first other line is the header, and ``nan`` or an empty cell is a missing value.
    Cells are separated by commas, else by the header's semicolons or tabs (:func:`_separator`),
    where a decimal comma is read as a point (``0,25`` is 0.25; ``1.234,5`` is refused).
    The rows follow the one set of row rules of every user's spectral file
    (:func:`processing.spectral_rows.in_wavelength_order`): descending wavelengths are read in
    ascending order, a row written twice is read once, readings of one wavelength are averaged
    with a :class:`~processing.errors.SpectralDataWarning` naming the file and lines, and
    wavelengths that turn back are refused naming both lines; ``metadata["row_order"]`` says
    what was done, ``metadata["lines"]`` the file line of each row read. An ascending table is
    read as written.

    Parameters
    ----------
    names
        Names for the spectra, replacing the header's (same count).
    source
        Provenance text for ``Spectra.source``; the file path by default.
    nan
        ``"error"`` (default) refuses missing values; ``"zero"`` replaces them with 0, as the
        paper does for the AptinaMT9M031 responsivities.

    Returns
    -------
    Spectra
        On the file's own wavelength grid, which must be uniform.

    Raises
    ------
    SpectralDataError
        On a missing or unreadable file, one that is not a regular file (FIFO, device, directory,
        symlink loop) or is above 16 MiB (checked before reading), a bad header, a ragged row, a
        non-number, wavelengths that rise and fall or are not nanometres, a non-uniform grid or
        (with ``nan="error"``) a missing value; the message names the file, line and column.
        :class:`NotATableError` (a ``SpectralDataError``) for text that is not UTF-8 or a first
        line that is no table header: another kind of file, such as a spectrometer export.
    """
    path = Path(path)
    where = shown_path(path)
    # The one safe way to open a user's file: regular files only, at most 16 MiB, read with a cap.
    # utf-8-sig: a byte-order mark (Excel's "CSV UTF-8") is dropped instead of becoming part of the header.
    data = read_user_bytes(path, _TABLE, SPECTRAL_TABLE_MAX_BYTES)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:  # UTF-16 or Latin-1: no table, perhaps a spectrometer export
        raise NotATableError(
            f"{where}: is not UTF-8 text ({err.reason} at byte {err.start}); expected {_TABLE}"
        ) from err

    comments, header, rows, lines, missing = _parse_table(text, where, nan)
    # The one set of row rules (descending reversed, repeats once, readings of one wavelength averaged with a
    # warning, wavelengths that turn back refused): an ascending table comes back as it is.
    table, row_lines, row_notes = in_wavelength_order(np.asarray(rows, dtype=float), lines, where)
    for column in tiny_columns(table[:, 1:]):
        raise SpectralDataError(
            f"{where}: column '{printable(_cut(header[column + 1]))}' peaks at {np.max(np.abs(table[:, column + 1])):.3g}; "
            f"expected values of magnitude at least {MIN_TABLE_PEAK:g} where there are any (a table scaled by mistake?)"
        )
    grid = WavelengthGrid.from_wavelengths(table[:, 0], where=f"{where}: column '{header[0]}'")
    spectrum_names = tuple(header[1:]) if names is None else tuple(names)
    if len(spectrum_names) != table.shape[1] - 1:
        raise SpectralDataError(
            f"{where}: {len(spectrum_names)} names given for {table.shape[1] - 1} spectra; expected one per column"
        )
    metadata: dict = {"path": where, "comments": comments, "header": tuple(header[1:]), "lines": tuple(row_lines)}
    if missing:
        metadata["nan_set_to_zero"] = missing
    if row_notes:
        metadata["row_order"] = row_notes
    return Spectra(grid, table[:, 1:], spectrum_names, kind=kind, unit=unit, source=source or where, metadata=metadata)


def _separator(header: str) -> str:
    r"""The cell separator a table's header line uses: ``,``; else ``;`` (a spreadsheet in a locale whose decimal mark
    is a comma, as European Excel saves "CSV"), else a tab (a spreadsheet's "tab delimited" text).

    >>> _separator("wavelength_nm,a,b"), _separator("wavelength_nm;a;b"), _separator("wavelength_nm\ta")
    (',', ';', '\t')
    """
    for separator in (",", ";", "\t"):
        if separator in header:
            return separator
    return ","


def _parse_table(
    text: str, where: str, nan: Literal["error", "zero"]
) -> tuple[list[str], list[str], list[list[float]], list[int], list[tuple[int, str]]]:
    """A spectral table's comments, header, number rows, the line of each row and missing cells (line, column) set
    to 0."""
    comments: list[str] = []
    header: list[str] | None = None
    rows: list[list[float]] = []
    lines: list[int] = []
    missing: list[tuple[int, str]] = []
    separator = ","
    for line_number, raw_line in enumerate(text.splitlines(), start=1):
        line = raw_line.strip()
        if not line:
            continue
        if line.startswith("#"):
            comments.append(line[1:].strip())
            continue
        if header is None:
            separator = _separator(line)
            cells = [cell.strip() for cell in line.split(separator)]
            if not cells[0].lower().startswith("wavelength") or len(cells) < 2:
                raise NotATableError(
                    f"{where}:{line_number}: header is '{printable(line[:60])}'; expected 'wavelength_nm,<name>,…'"
                )
            header = cells
            continue
        cells = [cell.strip() for cell in line.split(separator)]
        if separator != ",":  # a spreadsheet that writes ';' or a tab between cells writes a decimal comma
            cells = [cell.replace(",", ".", 1) if cell.count(",") == 1 and "." not in cell else cell for cell in cells]
        if len(cells) != len(header):
            raise SpectralDataError(
                f"{where}:{line_number}: {len(cells)} cells; expected {len(header)} as in the header"
            )
        row, blanks = _parse_row(cells, header, f"{where}:{line_number}", nan)
        rows.append(row)
        lines.append(line_number)
        missing += [(line_number, column) for column in blanks]
    if header is None or not rows:
        raise SpectralDataError(f"{where}: no data rows; expected a header and at least two wavelengths")
    if len(rows) < 2:
        raise SpectralDataError(f"{where}:{lines[0]}: one data row; expected at least two wavelengths")
    return comments, header, rows, lines, missing


def _parse_row(cells: list[str], header: list[str], where: str, nan: str) -> tuple[list[float], list[str]]:
    """One data row's numbers and the columns whose missing cell (``nan="zero"``) was set to 0."""
    blanks: list[str] = []
    row: list[float] = []
    for column, cell in enumerate(cells):
        if cell == "" or cell.lower() == "nan":
            if column == 0 or nan == "error":
                raise SpectralDataError(
                    f"{where}: column '{header[column]}' is missing (NaN); expected a number "
                    "(write 0 where the value is zero)"
                )
            blanks.append(header[column])
            row.append(0.0)
            continue
        try:
            value = plain_number(cell)  # the one reading of a user's number: not 1_0, ١٢ or infinity
        except ValueError as err:
            if not written_as_number(cell):
                raise SpectralDataError(
                    f"{where}: column '{header[column]}' holds '{printable(_cut(cell))}'; expected a number "
                    "(ASCII digits, a point, an optional exponent: 1.5, -2, 3e-4)"
                ) from err
            value = math.inf  # 1e400: refused below as out of range
        if not math.isfinite(value) or abs(value) > MAX_TABLE_MAGNITUDE:
            raise SpectralDataError(
                f"{where}: column '{header[column]}' holds '{printable(_cut(cell))}'; expected a finite "
                f"number of magnitude at most {MAX_TABLE_MAGNITUDE:g}"
            )
        row.append(value)
    return row, blanks


def _shipped(relative: str, kind: SpectralKind, unit: SpectralUnit, licence: str, **options: Any) -> Spectra:
    """Load a shipped file and record its licence."""
    spectra = load_spectra_csv(DATA_DIR / relative, kind, unit, source=f"msflash data {relative}", **options)
    return spectra.replace(metadata={**spectra.metadata, "licence": licence})


def _choose(what: str, name: str, valid: Sequence[str]) -> str:
    """Case-insensitive lookup of a dataset name, or an error listing the valid ones."""
    for candidate in valid:
        if candidate.lower() == name.lower():
            return candidate
    raise SpectralDataError(unknown_name(what, name, valid))


# -- the paper's data -------------------------------------------------------------------------
def paper_leds() -> Spectra:
    """The paper's 7 Luxeon LEDs at full drive, energy units, true ratios between LEDs.

    Names are made from the measured peaks (:func:`processing.led_wavelength.led_name` of
    :func:`~processing.led_wavelength.peak_nm` on the shipped 4 nm samples, recorded in
    ``metadata["peak_nm"]``): ``led440, led478, led500, led522, led597, led636, led661`` — the paper
    calls them ≈ 440, 480, 500, 520, 596 (a broad phosphor-converted amber), 636 and 660 nm
    (:data:`PAPER_LED_PEAKS_NM`, ``metadata["nominal_peak_nm"]``). Grid 380–1068 nm / 4 nm.

    Examples
    --------
    >>> paper_leds().names
    ('led440', 'led478', 'led500', 'led522', 'led597', 'led636', 'led661')
    """
    measured = with_peaks(_shipped("paper/ximeaLights_energy_380_1068_4nm.csv", "spd", "energy", _PAPER_LICENCE))
    peaks = led_peaks_nm(measured)
    names = tuple(led_name(peak) for peak in peaks)
    return measured.replace(
        names=names,
        metadata={
            **measured.metadata,
            PEAK_METADATA_KEY: dict(zip(names, peaks, strict=True)),
            "nominal_peak_nm": dict(zip(names, PAPER_LED_PEAKS_NM, strict=True)),
        },
    )


def paper_led_subset(n_leds: int) -> Spectra:
    """The paper's subset of ``n_leds`` LEDs (3 → 1,4,7; 4 → 1,3,4,7; 5 → 1,3,4,5,7; 6 → 1,2,3,4,5,7; 7 → all).

    Raises
    ------
    SpectralDataError
        For a count the paper does not define.

    Examples
    --------
    >>> paper_led_subset(3).names
    ('led440', 'led522', 'led661')
    """
    if n_leds not in PAPER_LED_SUBSETS:
        raise SpectralDataError(
            f"paper LED subset: {n_leds} LEDs; expected one of {', '.join(map(str, PAPER_LED_SUBSETS))}"
        )
    return paper_leds().select([index - 1 for index in PAPER_LED_SUBSETS[n_leds]])


def natural100() -> Spectra:
    """Natural-100 reflectances (20 clothes, 20 food, 20 nature, 5 hair, 15 skin, 20 DuPont), 400–700/10."""
    return _shipped("paper/natural100_reflectance_400_700_10nm.csv", "reflectance", "none", _PAPER_LICENCE)


def chart110() -> Spectra:
    """The paper's 110-patch simulation chart: Natural-100 then a 10-step gray strip, 400–700/10."""
    return _shipped(
        "paper/natural110_chart_reflectance_400_700_10nm_DERIVED.csv", "reflectance", "none", _PAPER_LICENCE
    )


def macbeth(source: Literal["isetcam", "paper"] = "isetcam") -> Spectra:
    """Macbeth ColorChecker, 24 patches in ISET order (white = patch 4), 380–1068/4.

    Parameters
    ----------
    source
        ``"isetcam"`` (MIT, default) or ``"paper"`` (the authors' copy, a different measurement).
    """
    if source == "isetcam":
        spectra = _shipped("reflectances/charts/macbethChart_24.csv", "reflectance", "none", _ISETCAM_LICENCE)
    elif source == "paper":
        spectra = _shipped("paper/macbethChart_reflectance_380_1068_4nm.csv", "reflectance", "none", _PAPER_LICENCE)
    else:
        raise SpectralDataError(f"macbeth: unknown source '{source}'; expected isetcam or paper")
    return spectra.replace(names=tuple(f"macbeth{i:02d}" for i in range(1, spectra.count + 1)))


def _split_cameras(spectra: Spectra, licence: str) -> dict[str, Spectra]:
    """Split a table with ``<camera>|<channel>`` columns into one 3-channel Spectra per camera."""
    cameras: dict[str, list[int]] = {}
    for index, name in enumerate(spectra.names):
        camera, _, _channel = name.partition("|")
        cameras.setdefault(camera, []).append(index)
    result = {}
    for camera, columns in cameras.items():
        if len(columns) != 3:
            raise SpectralDataError(
                f"{spectra.source}: camera '{camera}' has {len(columns)} channels; expected R, G, B"
            )
        result[camera] = spectra.select(columns).replace(
            names=("R", "G", "B"),
            source=f"{spectra.source} [{camera}]",
            metadata={"camera": camera, "licence": licence, "path": spectra.metadata.get("path", "")},
        )
    return result


def paper_cameras(include_noncommercial: bool = True) -> dict[str, Spectra]:
    """The paper's 34 cameras (6 ISETCam + 28 Jiang et al. 2013), 400–700/10, each max-normalised.

    Responsivities are labelled ``photons``, the unit of the paper's simulations (ISETCam's
    convention; the paper uses the Jiang curves in the same way).

    Parameters
    ----------
    include_noncommercial
        Include the 28 Jiang cameras, licensed CC BY-NC-SA 4.0 (non-commercial; see
        ``processing/data/noncommercial/LICENSE.md``). With False, only the 6 MIT cameras.

    Returns
    -------
    dict
        Camera name → Spectra with channels ``R, G, B``; each carries its licence in metadata.
    """
    cameras = _split_cameras(
        _shipped("cameras/paper_isetcam6_cameras_400_700_10nm.csv", "responsivity", "photons", _ISETCAM_LICENCE),
        _ISETCAM_LICENCE,
    )
    if include_noncommercial:
        cameras.update(
            _split_cameras(
                _shipped(
                    "noncommercial/jiang2013_paper28_cameras_400_700_10nm.csv",
                    "responsivity",
                    "photons",
                    _JIANG_LICENCE,
                ),
                _JIANG_LICENCE,
            )
        )
    return cameras


def _camera_key(name: str) -> str:
    """A camera name as it is matched: case, spaces, hyphens and underscores ignored."""
    return "".join(c for c in name.lower() if c not in " -_")


def camera_names(include_noncommercial: bool = True) -> tuple[str, ...]:
    """Every shipped camera: the ISETCam files (:data:`ISETCAM_CAMERAS`), then the paper's other
    cameras (:func:`paper_cameras`; the 28 Jiang et al. ones are non-commercial)."""
    names = list(ISETCAM_CAMERAS)
    keys = {_camera_key(n) for n in names}
    names += [n for n in paper_cameras(include_noncommercial) if _camera_key(n) not in keys]
    return tuple(names)


def camera_responsivities(name: str, include_noncommercial: bool = True) -> Spectra:
    """Any shipped camera's R, G, B responsivities (photons) by name, on the file's grid.

    An ISETCam camera comes from its own file (:func:`isetcam_camera`), any other from the paper's
    34-camera table (:func:`paper_cameras`). Names match ignoring case, spaces, ``-`` and ``_``
    (``canon5dmarkii`` is ``Canon 5DMarkII``).

    Raises
    ------
    SpectralDataError
        For an unknown name; the message lists every camera.

    Examples
    --------
    >>> camera_responsivities("canon_5dmarkii").metadata["camera"]
    'Canon 5DMarkII'
    """
    names = camera_names(include_noncommercial)
    found = next((n for n in names if _camera_key(n) == _camera_key(name)), None)
    if found is None:
        raise SpectralDataError(unknown_name("camera", name, names))
    if found in ISETCAM_CAMERAS:
        return isetcam_camera(found)
    return paper_cameras(include_noncommercial)[found]


# -- other shipped sets -----------------------------------------------------------------------
def isetcam_camera(name: str) -> Spectra:
    """ISETCam RGB responsivities (photons) of one camera, on the file's grid, channels ``R, G, B``.

    Missing values in the source (3 at 400 nm for ``AptinaMT9M031``) are set to 0, as the paper
    does; ``metadata["nan_set_to_zero"]`` lists them.

    Examples
    --------
    >>> isetcam_camera("AptinaMT9M031").names
    ('R', 'G', 'B')
    """
    camera = _choose("isetcam camera", name, ISETCAM_CAMERAS)
    spectra = _shipped(
        f"cameras/isetcam/{camera}.csv", "responsivity", "photons", _ISETCAM_LICENCE, names=("R", "G", "B"), nan="zero"
    )
    return spectra.replace(metadata={**spectra.metadata, "camera": camera})


def isetcam_leds(name: str) -> Spectra:
    """An ISETCam LED set (``luxeon8``, ``luxeon4``, ``luxeon5``, ``six``, ``ledsix``).

    ISETCam does not tag these with a unit; they are spectroradiometer outputs and are returned
    as energy.
    """
    key = _choose("isetcam leds", name, tuple(ISETCAM_LED_SETS))
    return _shipped(f"leds/isetcam/{ISETCAM_LED_SETS[key]}", "spd", "energy", _ISETCAM_LICENCE)


def vrhel(name: str) -> Spectra:
    """A Vrhel et al. (1994) reflectance set, 400–700/10 (see :data:`VRHEL_SETS`; ``"skin"`` joins all skin sets)."""
    if name.lower() == "skin":
        parts = [vrhel(key) for key in VRHEL_SETS if key.startswith("skin_")]
        require_same_grid(*parts)
        return parts[0].replace(
            values=np.hstack([part.values for part in parts]),
            names=tuple(n for part in parts for n in part.names),
            source="msflash data reflectances/vrhel/*skin*",
        )
    key = _choose("vrhel", name, tuple(VRHEL_SETS))
    return _shipped(f"reflectances/vrhel/{VRHEL_SETS[key]}", "reflectance", "none", _ISETCAM_LICENCE)


def water_absorption(source: Literal["pope_fry", "paper"] = "pope_fry") -> Spectra:
    """Pure-water absorption coefficient ``a_w(λ)`` in 1/m (Pope & Fry 1997, 380–700/2.5 by default).

    ``Spectra`` has no kind for absorption coefficients, so the result is returned as a unitless
    per-wavelength coefficient (``kind="reflectance"``, ``unit="none"``) with
    ``metadata["quantity"]`` saying what it really is. Use
    :func:`processing.water.water_transmittance` for the attenuation factor of a path.
    """
    if source == "pope_fry":
        spectra = _shipped(
            "water/pope_fry_1997_380_700_2p5nm.csv",
            "reflectance",
            "none",
            "published table, Pope & Fry, Appl. Opt. 36, 8710 (1997)",
            names=("a_w",),
        )
    elif source == "paper":
        spectra = _shipped(
            "paper/water_pure_absorption_400_700_5nm.csv", "reflectance", "none", _PAPER_LICENCE, names=("a_w",)
        )
    else:
        raise SpectralDataError(f"water_absorption: unknown source '{source}'; expected pope_fry or paper")
    return spectra.replace(metadata={**spectra.metadata, "quantity": "absorption coefficient a_w", "unit": "1/m"})


# -- illuminants ------------------------------------------------------------------------------
def _from_colour(
    wavelengths_nm: np.ndarray,
    values: np.ndarray,
    name: str,
    grid: WavelengthGrid,
    outside: Literal["error", "zero", "edge"] = "error",
) -> Spectra:
    """A colour-science spectral distribution as energy ``Spectra`` on ``grid``, peak 1."""
    native = Spectra(
        WavelengthGrid.from_wavelengths(wavelengths_nm, where=f"colour-science '{name}'"),
        np.asarray(values, dtype=float),
        (name,),
        kind="spd",
        unit="energy",
        source=f"colour-science {name}",
    )
    return native.resample(grid, outside).normalised("max")


def cie1931_cmfs(grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """The CIE 1931 2° colour-matching functions from colour-science on ``grid``.

    Returned as energy-unit responsivities (``x̄ᵀ s`` is X of an energy spectrum ``s``), columns
    ``x_bar, y_bar, z_bar``; ``to_unit("photons")`` gives the weights for photon spectra.
    """
    import colour  # imported here: loading colour-science takes a second and only these helpers need it

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour-science's own table handling; a plain lookup is unaffected
        cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
        wavelengths, values = np.asarray(cmfs.wavelengths, dtype=float), np.asarray(cmfs.values, dtype=float)
    native = Spectra(
        WavelengthGrid.from_wavelengths(wavelengths, where="colour-science CIE 1931 CMFs"),
        values,
        ("x_bar", "y_bar", "z_bar"),
        kind="responsivity",
        unit="energy",
        source="colour-science CIE 1931 2 Degree Standard Observer",
    )
    return native.resample(grid, outside="zero")


def illuminant(
    name: str, grid: WavelengthGrid = DEFAULT_GRID, outside: Literal["error", "zero", "edge"] = "error"
) -> Spectra:
    """A standard illuminant from colour-science, as energy ``Spectra`` on ``grid`` scaled to peak 1.

    Parameters
    ----------
    name
        A key of ``colour.SDS_ILLUMINANTS`` (``A``, ``D50``, ``D65``, ``FL2``, ``FL11``…), case
        insensitive, or ``"blackbody:<kelvin>"`` (Planck's law evaluated on the grid).
    grid
        The wavelength grid. The tables must cover it (no extrapolation), except that CIE A and the
        D series (D50, D55, D65, D75) are computed — Planck's law, and the CIE D-series basis
        (300–830 nm) at the illuminant's chromaticity — on grids beyond colour-science's 300–780 nm
        tables (the D65 computed agrees with its table within 0.3 % of its value at 560 nm).
    outside
        ``"error"`` (default) or ``"zero"``: what :meth:`Spectra.resample` does beyond the data.

    Raises
    ------
    SpectralDataError
        For an unknown name (the message lists a few valid ones) or a grid beyond the table.

    Examples
    --------
    >>> illuminant("D65").names
    ('D65',)
    """
    import colour  # imported here: loading colour-science takes a second and only these helpers need it

    if name.lower().startswith("blackbody:"):
        try:
            kelvin = float(name.split(":", 1)[1])
        except ValueError as err:
            raise SpectralDataError(f"illuminant '{name}': bad temperature; expected e.g. 'blackbody:3200'") from err
        if not (math.isfinite(kelvin) and kelvin > 0):
            raise SpectralDataError(f"illuminant '{name}': temperature {kelvin}; expected > 0 K")
        wavelengths = grid.wavelengths_nm
        with warnings.catch_warnings():
            # colour warns about its own numeric edge cases; they do not apply to a plain Planck evaluation.
            warnings.simplefilter("ignore", colour.utilities.ColourWarning)
            sd = colour.sd_blackbody(kelvin, colour.SpectralShape(wavelengths[0], wavelengths[-1], grid.step_nm))
        return _from_colour(sd.wavelengths, sd.values, f"blackbody {kelvin:g} K", grid)

    keys = list(colour.SDS_ILLUMINANTS.keys())
    key = next((k for k in keys if k.lower() == name.lower()), None)
    if key is None:
        raise SpectralDataError(unknown_name("illuminant", name, keys, "blackbody:<kelvin>"))
    sd = colour.SDS_ILLUMINANTS[key]
    wavelengths = grid.wavelengths_nm
    if wavelengths[0] < sd.wavelengths[0] or wavelengths[-1] > sd.wavelengths[-1]:
        observer = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]
        if key == "A":
            sd = colour.sd_CIE_standard_illuminant_A(
                colour.SpectralShape(wavelengths[0], wavelengths[-1], grid.step_nm)
            )
        elif key in ("D50", "D55", "D65", "D75") and key in observer:
            sd = colour.sd_CIE_illuminant_D_series(observer[key])
    return _from_colour(sd.wavelengths, sd.values, key, grid, outside)
