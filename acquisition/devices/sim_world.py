"""What the ``sim`` rig simulates, as the command line names it: camera, LEDs, ambient and scene.

Each option (``--sim-camera``, ``--led-spectra``/``--leds``, ``--ambient``, ``--scene``) is a shipped name or a
CSV file (energy units; reflectances 0–1), resolved here into spectra on the sim's wavelength grid
(:data:`processing.spectra.DEFAULT_GRID`, 400–700 nm). Files are read by the one spectral table reader (:func:`processing.datasets.load_spectra_csv`) and
put on the grid only by :meth:`Spectra.resample`. A sim file must cover the whole grid: the error
says which range the file covers and which is needed. Every problem is a one-line
:class:`~acquisition.errors.UsageError` naming the option or the file and what was expected.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Literal

import numpy as np

from msflash.acquisition.errors import UsageError
from msflash.acquisition.progress import progress
from msflash.processing import datasets, lights
from msflash.processing.errors import SpectralDataError
from msflash.processing.names import unknown_name
from msflash.processing.negative_values import clip_negative_noise
from msflash.processing.spectra import DEFAULT_GRID, Spectra, SpectralKind, WavelengthGrid
from msflash.processing.user_files import known_to, names_a_file, shown_path

SimSceneName = Literal["chart110", "macbeth", "white"]
SIM_SCENES: tuple[SimSceneName, ...] = ("chart110", "macbeth", "white")
"""Scene names of the sim rig (a reflectance CSV is the other choice)."""

SIM_DEFAULT_CAMERA = "NikonD100"
"""The sim rig's camera unless ``--sim-camera`` names another."""


class _NotATable(UsageError):
    """:func:`read_spectra_file` of a file that does not start as a table (it may be a spectrometer export)."""


def read_spectra_file(path: str | Path, kind: SpectralKind) -> Spectra:
    """A spectral table (energy units, reflectances unitless; :func:`processing.datasets.load_spectra_csv`)
    on its own grid; in a light or responsivity table, negative noise is clipped to 0 (a note on
    stderr) and a value beyond it refused (:func:`processing.negative_values.clip_negative_noise`).

    Raises
    ------
    UsageError
        The file is missing, unreadable or malformed (the reader's message: file, line, column).
    """
    try:
        table = datasets.load_spectra_csv(path, kind=kind, unit="none" if kind == "reflectance" else "energy")
    except datasets.NotATableError as err:
        raise _NotATable(str(err)) from err
    except (SpectralDataError, OSError) as err:
        raise UsageError(str(err)) from err
    return table if kind == "reflectance" else _noise_clipped(table, path)


def _noise_clipped(measured: Spectra, path: str | Path) -> Spectra:
    """A measured light's or responsivity's negative noise clipped to 0 (a note on stderr), as every reader of
    measured spectra does; a value beyond noise refused (``UsageError`` naming the file and, when the reader kept
    each row's line, the line)."""
    lines = measured.metadata.get("lines") or None
    try:
        values, clipped = clip_negative_noise(
            measured.wavelengths_nm, measured.values, measured.names, shown_path(Path(path)), lines
        )
    except SpectralDataError as err:
        raise UsageError(str(err)) from err
    for item in clipped:
        progress(item.note(shown_path(Path(path))))
    return measured.replace(values=values) if clipped else measured


def read_light_file(path: str | Path) -> Spectra:
    """A measured light: a spectral table, or a spectrometer export of it, read as ``--target`` reads one
    (:func:`calibration.light_files.read_measured_light`: an AvaSoft stored dark taken off, a warning for raw
    counts), negative noise clipped.

    Raises
    ------
    UsageError
        One line naming the file (and line): a bad table, what the export reader refuses, or both readers' reasons
        for a file that is neither.
    """
    from msflash.calibration.light_files import read_measured_light  # tries the table first, then the export

    try:
        light = read_measured_light(path, progress)
    except (SpectralDataError, OSError) as err:
        raise UsageError(str(err)) from err
    return _noise_clipped(light, path)


LedFiles = str | Path | tuple[str | Path, ...]
"""``--led-spectra``: one table (a column per channel), or spectrometer exports (one per channel, in channel order)."""


def led_files_shown(spec: LedFiles) -> str:
    """``--led-spectra``'s files as a message names them (several joined by commas)."""
    paths = (spec,) if isinstance(spec, str | Path) else spec
    return ", ".join(shown_path(path) for path in paths)


def read_led_files(spec: LedFiles, grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """The LED spectra ``--led-spectra`` names: a table on its own grid (:func:`read_spectra_file`), or the
    spectrometer exports of the LEDs, one per channel, read onto ``grid`` as ``msflash calibrate leds`` reads them
    (:func:`calibration.light_files.read_led_export_files`; what it notes and warns, on stderr).

    Raises
    ------
    UsageError
        One line naming the file (and line): a bad table, what ``calibrate leds`` refuses in an export, several
        files of which one is a table.
    """
    paths = (spec,) if isinstance(spec, str | Path) else tuple(spec)
    if len(paths) == 1:
        try:
            return read_spectra_file(paths[0], "spd")
        except _NotATable:
            pass  # a spectrometer export of one LED
    for path in paths if len(paths) > 1 else ():
        columns = _table_columns(path)
        if columns > 1:
            raise UsageError(
                f"--led-spectra {shown_path(path)}: a table of {columns} LEDs among {len(paths)} files; expected that "
                "table alone, or one spectrometer export (or one-LED table) per channel"
            )
    from msflash.calibration.light_files import read_led_export_files

    try:
        return read_led_export_files(paths, grid, progress)
    except (SpectralDataError, OSError) as err:
        raise UsageError(str(err)) from err


def _table_columns(path: str | Path) -> int:
    """How many spectra ``path`` holds if it is a spectral table (0 if it is not one, or a bad one: its reader says
    why)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # read again, and said, by the export reader
        try:
            return datasets.load_spectra_csv(path, kind="spd", unit="energy").count
        except (SpectralDataError, OSError):
            return 0


def read_responsivity_file(path: str | Path) -> Spectra:
    """Camera responsivities from a CSV ``wavelength_nm, R, G, B`` (energy), on the file's grid; a
    ``UsageError`` as :func:`read_spectra_file`'s, or for a table of other than three channels."""
    camera = read_spectra_file(path, "responsivity")
    if camera.count != 3:
        raise UsageError(
            f"{path}: {camera.count} responsivity columns ({', '.join(camera.names)}); expected 3 (R, G, B)"
        )
    return camera.replace(names=("R", "G", "B"), metadata={**camera.metadata, "camera": Path(path).stem})


def on_grid(spectra: Spectra, where: str, grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """``spectra`` resampled onto ``grid``, which its range must cover (no extrapolation, no zero fill).

    Raises
    ------
    UsageError
        Naming ``where``, the range the spectra cover and the range needed.
    """
    start, stop = spectra.grid.wavelengths_nm[[0, -1]]
    try:
        return spectra.resample(grid, outside="error")
    except SpectralDataError as err:
        raise UsageError(
            f"{where}: covers {start:g}–{stop:g} nm; expected at least {grid.start_nm:g}–"
            f"{grid.stop_nm:g} nm (the sim's wavelength grid)"
        ) from err


def _nonnegative_light(spectra: Spectra, where: str, what: str) -> Spectra:
    """Refuse negative values and spectra without light on the grid."""
    for index, name in enumerate(spectra.names):
        column = spectra.values[:, index]
        if np.any(column < 0) or not column.max() > 0:
            raise UsageError(
                f"{where}: {what} '{name}' has {'negative values' if np.any(column < 0) else 'no light'} "
                f"on {spectra.grid}; expected a non-negative spectrum with some light there"
            )
    return spectra


def sim_camera(spec: str | None, grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """``--sim-camera``: a shipped camera by name (default :data:`SIM_DEFAULT_CAMERA`) or a responsivity CSV.

    Raises
    ------
    UsageError
        An unknown name (every shipped camera is listed), or a bad or too narrow file.
    """
    spec = SIM_DEFAULT_CAMERA if spec is None else spec
    where = f"--sim-camera {spec}"
    if names_a_file(spec, known_to(datasets.camera_responsivities)):
        return _nonnegative_light(on_grid(read_responsivity_file(spec), where, grid), where, "channel")
    try:
        return datasets.camera_responsivities(spec).resample(grid)
    except SpectralDataError as err:
        raise UsageError(f"--sim-camera: {err}") from err


def sim_leds(led_spectra: LedFiles | None, n_leds: int | None, grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """The sim booth's LEDs: ``--led-spectra FILE.csv`` (one column per channel, or one spectrometer export per
    channel: :func:`read_led_files`) or the paper's ``--leds N``
    (3–7; neither: the paper's 7 LEDs). What the emulator can serve is checked when the rig opens.

    Raises
    ------
    UsageError
        Both given, a count the paper does not define, or a bad or too narrow file.
    """
    if led_spectra is not None and n_leds is not None:
        raise UsageError(
            f"--leds {n_leds} and --led-spectra {led_files_shown(led_spectra)}: two LED sets; expected one of them"
        )
    if led_spectra is not None:
        where = f"--led-spectra {led_files_shown(led_spectra)}"
        leds = on_grid(read_led_files(led_spectra, grid), where, grid)
        duplicated = sorted({n for n in leds.names if leds.names.count(n) > 1})
        if duplicated:
            raise UsageError(
                f"{where}: LED column(s) {', '.join(duplicated)} appear more than once; expected one "
                "named column per booth channel"
            )
        return _nonnegative_light(leds, where, "LED")
    try:
        return datasets.paper_led_subset(7 if n_leds is None else n_leds).resample(grid)
    except SpectralDataError as err:
        raise UsageError(f"--leds {n_leds}: {err}") from err


def sim_ambient(spec: str, grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """``--ambient``: a light by name (:func:`processing.lights.light_spectrum`), a CSV ``wavelength_nm, value`` or a
    spectrometer export of the light (:func:`read_light_file`).

    Raises
    ------
    UsageError
        An unknown name (every accepted one is listed), or a file that is bad, too narrow, holds
        more than one spectrum or no light.
    """
    if not names_a_file(spec, known_to(lights.light_spectrum)):
        try:
            return lights.light_spectrum(spec, grid)
        except SpectralDataError as err:
            raise UsageError(f"--ambient: {err}") from err
    where = f"--ambient {spec}"
    light = on_grid(read_light_file(spec), where, grid)
    if light.count != 1:
        raise UsageError(
            f"{where}: {light.count} spectra ({', '.join(light.names)}); expected one ambient (wavelength_nm, value)"
        )
    return _nonnegative_light(light, where, "ambient").replace(names=(Path(spec).stem,))


def sim_scene(spec: str, grid: WavelengthGrid = DEFAULT_GRID) -> SimSceneName | Spectra:
    """``--scene``: a name of :data:`SIM_SCENES`, or the reflectances of a CSV (one column per surface).

    Raises
    ------
    UsageError
        An unknown name, or a file that is bad, too narrow or not reflectances in 0–1.
    """
    if not names_a_file(spec, SIM_SCENES.__contains__):
        name = next((n for n in SIM_SCENES if n == spec), None)
        if name is None:
            raise UsageError(
                unknown_name("--scene", spec, SIM_SCENES, "a reflectance CSV (wavelength_nm, one column per surface)")
            )
        return name
    where = f"--scene {spec}"
    surfaces = on_grid(read_spectra_file(spec, "reflectance"), where, grid)
    low, high = float(surfaces.values.min()), float(surfaces.values.max())
    if low < 0 or high > 1:
        hint = " (a table in percent? divide by 100)" if high > 1 else ""
        raise UsageError(f"{where}: reflectances span {low:g}–{high:g}{hint}; expected values in 0–1")
    return surfaces
