"""A sequence's spectra as processing takes them: in photons, from a calibration, and the target.

The LED spectra and camera responsivities a sequence records, or those of a calibration that replaces
them (:func:`apply_calibration`: resampled onto the sequence's grid, refused when its range misses an
LED's light), in the processing unit (photons) and back (:func:`spectrum_in_sequence_unit`), and the
complementary flash's target illuminant on the sequence's grid (:func:`target_illuminant`).
"""

from __future__ import annotations

import functools
import os
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.progress import progress
from msflash.acquisition.sequence.format import Sequence
from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.negative_values import clip_negative_noise
from msflash.processing.spectra import DEFAULT_GRID, Spectra
from msflash.processing.user_files import known_to, names_a_file, printable, shown_path


def apply_calibration(sequence: Sequence, directory: str | Path | None = None) -> tuple[Sequence, list[str]]:
    """The sequence with LED spectra and/or responsivities taken from a calibration, and what changed.

    ``directory`` is a ``msflash calibrate`` output; without it, the sequence's own
    ``"calibration": {"file": …}`` reference is used if present (relative to the sequence
    directory). LEDs are matched by name; spectra are resampled onto the sequence's grid and
    converted to its unit. Without either, the sequence is returned unchanged. A note says so
    when the calibration's id is not the one the sequence recorded (re-calibrated since).

    Raises
    ------
    RecordingError
        If the calibration cannot be read or lacks one of the sequence's LEDs.
    """

    from msflash.calibration.errors import CalibrationError
    from msflash.calibration.files import load_calibration

    if directory is None:
        reference = sequence.extra.get("calibration")
        if not isinstance(reference, dict) or not reference.get("file"):
            return sequence, []
        directory = sequence.directory / str(reference["file"])
    try:
        calibration = load_calibration(directory)
    except CalibrationError as err:
        raise RecordingError(str(err)) from err
    notes: list[str] = list(calibration.notes)  # negative noise clipped on reading
    reference = sequence.extra.get("calibration")
    recorded_id = reference.get("id") if isinstance(reference, dict) else None
    if recorded_id and recorded_id != calibration.id:
        notes.append(
            f"the sequence was captured with calibration {recorded_id}; {directory} now holds "
            f"{calibration.id}, which is used"
        )
    grid = sequence.grid
    leds = sequence.leds
    if calibration.led_spectra is not None:
        _require_coverage(
            directory, calibration.id, "LED spectra", calibration.led_spectra.wavelengths_nm, sequence.led_spectra()
        )
        spectra = calibration.led_spectra.resample(grid, outside="zero").to_unit(sequence.spectral_unit)
        missing = [led.name for led in leds if led.name not in spectra.names]
        if missing:
            raise RecordingError(
                f"{directory}: calibration {calibration.id} has no LED named {', '.join(missing)}; "
                f"expected the sequence's LEDs ({', '.join(led.name for led in leds)})"
            )
        leds = tuple(replace(led, spd=spectra.column(led.name)) for led in leds)
        notes.append(f"LED spectra from calibration {calibration.id} ({directory}) replace the sequence's")
    camera = sequence.camera
    if calibration.camera_responsivities is not None:
        lights = replace(sequence, leds=leds).led_spectra()  # the LEDs the responsivities will meet
        _require_coverage(
            directory, calibration.id, "camera responsivities", calibration.camera_responsivities.wavelengths_nm, lights
        )
        curves = calibration.camera_responsivities.resample(grid, outside="zero").to_unit(sequence.spectral_unit)
        camera = replace(camera, responsivity={name: curves.column(name) for name in curves.names})
        notes.append(f"camera responsivities from calibration {calibration.id} ({directory}) replace the sequence's")
    return replace(sequence, leds=leds, camera=camera), notes


COVERAGE_TOLERANCE = 0.01
"""Largest share of the LEDs' energy a calibration's wavelength range may leave out."""


def _shares_outside(values: np.ndarray, covered: np.ndarray, empty: float = 0.0) -> np.ndarray:
    """Each column's share of its absolute sum on the wavelengths outside ``covered`` (``empty`` for a zero column)."""
    energy = np.abs(values)
    totals = energy.sum(axis=0)
    return np.divide(energy[~covered].sum(axis=0), totals, out=np.full_like(totals, empty), where=totals > 0)


def _require_coverage(
    directory: str | Path, calibration_id: str, what: str, calibrated_nm: np.ndarray, leds: Spectra
) -> None:
    """Refuse a calibration whose range misses more than 1 % of an LED's energy (it would be zero-filled there)."""
    low, high = float(calibrated_nm[0]), float(calibrated_nm[-1])
    wavelengths = leds.wavelengths_nm
    shares = _shares_outside(leds.values, (wavelengths >= low - 1e-9) & (wavelengths <= high + 1e-9))
    worst = int(np.argmax(shares)) if shares.size else 0
    if shares.size and shares[worst] > COVERAGE_TOLERANCE:
        raise RecordingError(
            f"{directory}: calibration {calibration_id} has {what} from {low:g} to {high:g} nm, but LED "
            f"'{leds.names[worst]}' puts {100 * shares[worst]:.0f} % of its light outside that range; expected a "
            f"calibration covering the sequence's LEDs ({float(wavelengths[0]):g}–{float(wavelengths[-1]):g} nm)"
        )


def led_spectra_photons(sequence: Sequence) -> Spectra:
    """The sequence's LED spectra in photons (the processing unit)."""
    return sequence.led_spectra().to_unit("photons")


def camera_responsivities_photons(sequence: Sequence) -> Spectra:
    """The sequence's camera responsivities in photons; a clear error if the sequence has none."""
    responsivities = sequence.camera_responsivities()
    if responsivities is None:
        raise RecordingError(
            f"{sequence.path}: camera.responsivity is missing; the flash solvers need the camera's "
            "spectral responsivities (add them, or calibrate the camera)"
        )
    return responsivities.to_unit("photons")


def spectrum_in_sequence_unit(sequence: Sequence, spectrum: Spectra) -> np.ndarray:
    """A processing spectrum (photons) in the sequence's spectral unit, shape (n_wavelengths,)."""
    return spectrum.to_unit(sequence.spectral_unit).values[:, 0]


def is_target_file(target: str) -> bool:
    """Whether ``--target`` names a file (:func:`processing.user_files.names_a_file`); an illuminant's name is the
    illuminant even where a file of that name lies beside the command (``./D65`` reads the file)."""
    return names_a_file(target, known_to(lambda name: datasets.illuminant(name, DEFAULT_GRID, outside="zero")))


VISIBLE_TO_CAMERAS_NM = (300.0, 1100.0)
"""Where a silicon camera sees: a target light with no power in this range cannot be matched by any flash."""


def target_file_spectrum(target: str, say_warnings: bool = True) -> Spectra:
    """The one spectrum of a ``--target`` file, its negative noise clipped, as read (energy, the file's grid).

    The file is a spectral table ``wavelength_nm,value`` or a spectrometer export of the light
    (:func:`calibration.light_files.read_measured_light`: one set of row rules for both). Needs no sequence, so
    ``--target`` is read when the command line is parsed: a missing, empty or dark file (or one of several spectra)
    is refused before a rig opens, not after the frames were metered and captured. A file is read once per version
    (path, size, modification time) in a process, and its warnings (averaged rows, raw counts) said once, by the first
    reading with ``say_warnings`` (the one of the command line); ``say_warnings=False`` never says them
    (:func:`target_illuminant`, once per sequence, perhaps in a worker process).

    Raises
    ------
    RecordingError
        Missing, more than one spectrum, negative beyond noise, or no light between 300 and 1100 nm; the readers'
        own errors (:class:`~processing.errors.SpectralDataError`), naming the file and line.
    """
    path = Path(target)
    if not os.path.lexists(path):
        raise RecordingError(f"{target}: target illuminant file not found; expected a CSV file or a name like D65")
    try:
        found = os.stat(path)
    except OSError:  # a symlink loop, a dangling link: the reader refuses it by what it is
        reading = _read_target(target, None)
    else:
        reading = _read_target(target, (found.st_dev, found.st_ino, found.st_size, found.st_mtime_ns))
    if say_warnings and not reading.said:
        reading.said = True
        for line in reading.reports:
            progress(line)
        for warning in reading.warnings:
            warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    return reading.spectra


class _TargetReading:
    """One reading of one version of a ``--target`` file: its spectrum, what the reader reported and warned, and
    whether that was said yet (once per version, by the first reading that may say it)."""

    def __init__(self, spectra: Spectra, reports: list[str], said: list[warnings.WarningMessage]) -> None:
        self.spectra, self.reports, self.warnings, self.said = spectra, tuple(reports), tuple(said), False


@functools.lru_cache(maxsize=16)
def _read_target(target: str, version: tuple[int, ...] | None) -> _TargetReading:
    """:func:`target_file_spectrum`'s reading of one version of the file (``version`` keys the cache only): read
    once, whether its warnings are said or not."""
    from msflash.calibration.light_files import read_measured_light

    path = Path(target)
    reports: list[str] = []
    with warnings.catch_warnings(record=True) as said:  # said once the file is taken, not before a refusal
        warnings.simplefilter("always")
        light = read_measured_light(path, report=reports.append)
        spectra = _checked_target(light, shown_path(path))
    spectra.values.setflags(write=False)  # one array for every reading of this version of the file
    return _TargetReading(spectra, reports, said)


def _checked_target(spectra: Spectra, shown: str) -> Spectra:
    """A target file's spectra with negative noise clipped, refused if not one light a camera sees."""
    if spectra.count != 1:  # its first column was taken: another file's numbers, silently
        raise RecordingError(
            f"--target {shown}: {spectra.count} spectra ({printable(', '.join(spectra.names))[:120]}); expected one "
            "target illuminant (wavelength_nm, value) — an exported spectra.csv holds several: keep the column meant"
        )
    # Negative noise clipped to 0 as every measured spectrum's is; beyond it, and no light at all, refused.
    lines = spectra.metadata.get("lines") or None
    values, _ = clip_negative_noise(spectra.wavelengths_nm, spectra.values, spectra.names, f"--target {shown}", lines)
    if not values.max() > 0:
        raise RecordingError(f"--target {shown}: no light; expected a spectrum with some positive values")
    low, high = VISIBLE_TO_CAMERAS_NM
    seen = (spectra.wavelengths_nm >= low) & (spectra.wavelengths_nm <= high)
    if not np.any(values[seen] > 0):
        lit = np.flatnonzero(values[:, 0] > 0)
        first = f":{lines[lit[0]]}" if lines else ""
        raise RecordingError(
            f"--target {shown}{first}: light only at {spectra.wavelengths_nm[lit[0]]:g}–"
            f"{spectra.wavelengths_nm[lit[-1]]:g} nm; expected some light between {low:g} and {high:g} nm, where a "
            "camera sees (wavelengths in nanometres?)"
        )
    return spectra.replace(values=values)


def target_illuminant(target: str, sequence: Sequence) -> Spectra:
    """The complementary target ``i_d`` in photons on the sequence's grid: a name or a CSV file.

    Names are those of :func:`processing.datasets.illuminant` (D65, A, FL2, …); a file is a
    two-column CSV ``wavelength_nm, value`` in energy units, or a spectrometer export of the light
    (:func:`target_file_spectrum`, which says the file's warnings: this reading, once per sequence, does not).
    """
    if is_target_file(target):
        spectra = target_file_spectrum(target, say_warnings=False)  # said when --target was read (target_value)
        try:
            resampled = spectra.resample(sequence.grid, outside="error")
        except SpectralDataError as err:
            resampled = spectra.resample(sequence.grid, outside="zero")
            inside = (sequence.wavelengths_nm >= spectra.wavelengths_nm[0]) & (
                sequence.wavelengths_nm <= spectra.wavelengths_nm[-1]
            )
            _require_camera_coverage(sequence, inside, f"target illuminant {target}", err)
    else:
        try:
            resampled = datasets.illuminant(target, sequence.grid)
        except SpectralDataError as err:
            # A table narrower than the sequence's grid (e.g. FL2's 380–780 nm on 360–830 nm): zero beyond
            # it is harmless only where the camera sees (almost) nothing.
            resampled = datasets.illuminant(target, sequence.grid, outside="zero")
            _require_camera_coverage(
                sequence, resampled.values[:, 0] > 0, f"target illuminant '{target}'", err, " (give --target FILE.csv)"
            )
    return resampled.to_unit("photons")


def _require_camera_coverage(
    sequence: Sequence, covered: np.ndarray, what: str, cause: Exception, hint: str = ""
) -> None:
    """Refuse zero beyond ``covered`` if the camera puts more than COVERAGE_TOLERANCE of its response there."""
    curves = sequence.camera.responsivity
    if curves is None:
        raise RecordingError(f"{what}: {cause}") from cause
    response = np.abs(np.stack([np.asarray(curve, dtype=float) for curve in curves.values()], axis=1))
    share = float(_shares_outside(response.sum(axis=1, keepdims=True), covered, empty=1.0)[0])
    if share > COVERAGE_TOLERANCE:
        grid = sequence.wavelengths_nm
        known = grid[covered] if covered.any() else grid[:0]
        span = f"{float(known[0]):g}–{float(known[-1]):g} nm" if known.size else "none"
        raise RecordingError(
            f"{what}: its data cover {span} of the sequence's {float(grid[0]):g}–{float(grid[-1]):g} nm, and the "
            f"camera puts {100 * share:.1f} % of its response outside that; expected a target covering the camera's "
            f"range{hint}"
        ) from cause
