"""Export a sequence and what msflash makes of it: DNG, OME-TIFF, CSV and EXR files in a new folder.

What each format holds is docs/cli.md (``msflash export``). In short: ``dng`` one DNG per frame of a raw
(CFA) sequence, its ``AsShotNeutral`` the camera's response to that frame's light (the estimated ambient plus
the LEDs at the frame's levels, eq. 4–6; without responsivities camera RGB is taken as linear sRGB, with a
note), RGB or float frames refused; ``ome-tiff`` every frame as recorded (:mod:`.ome_tiff`); ``csv`` the
estimate with its ± 1σ band, the LEDs and the flash mixes (:mod:`.spectra_csv`) plus ``spectra.json``;
``exr`` the ambient and the two computational flash images (eq. 7–9), linear RGB
(:func:`acquisition.sequence.exr_metadata.exr_image`).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from msflash.acquisition.errors import UsageError
from msflash.acquisition.export.dng import write_dng
from msflash.acquisition.export.formats import EXPORT_FORMATS
from msflash.acquisition.export.ome_tiff import OmeLight, OmePlane, write_ome_tiff
from msflash.acquisition.export.spectra_csv import SpectrumColumn, write_spectra_csv
from msflash.acquisition.export.staging import check_not_inside, staged_export
from msflash.acquisition.progress import progress
from msflash.acquisition.sequence.exr_metadata import exr_image
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.image_files import read_image_header, write_image
from msflash.acquisition.session import analysis, sequence_spectra
from msflash.acquisition.session.one_sequence import refuse_dark_ambient
from msflash.processing.ambient import AmbientEstimate
from msflash.processing.errors import TargetUnreachableWarning
from msflash.processing.flash import FlashSolution
from msflash.processing.raw_colour import camera_matrix, camera_neutral
from msflash.processing.user_files import check_output_name

FLASH_MODES = ("matching", "complementary")


def check_export(sequence: Sequence, formats: tuple[str, ...]) -> None:
    """Refuse what cannot be exported, before anything is written.

    Raises
    ------
    UsageError
        DNG of an RGB (debayered) sequence or of float frames, or a sequence with no frames.
    """
    if not sequence.frames:
        raise UsageError(f"{sequence.path}: frames is empty; expected a sequence with frames to export")
    if "dng" in formats:
        if sequence.camera.cfa is None:
            raise UsageError(
                f"{sequence.path}: camera.cfa is null (RGB, debayered frames), and a DNG holds a raw mosaic; "
                "expected a raw (CFA) sequence for --to dng (export RGB frames with --to ome-tiff or exr)"
            )
        header = read_image_header(sequence.frame_path(0))
        if not np.issubdtype(header.dtype, np.integer):
            raise UsageError(
                f"{sequence.path}: frames[0].file '{sequence.frames[0].file}' holds {header.dtype} values; expected "
                "integer counts for --to dng (export float frames with --to ome-tiff or exr)"
            )


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_sequence` wrote."""

    directory: Path
    """The new folder."""
    files: tuple[Path, ...]
    """Every file written, in the folder."""
    notes: tuple[str, ...] = ()
    """What was assumed or left out (no responsivities, …)."""
    details: dict = field(default_factory=dict)
    """Values worth printing (``ambient_neutral``, ``color_matrix_source``)."""


@dataclass
class _Work:
    """One export's sequence, its estimate and flash solutions (made once, when first needed)."""

    sequence: Sequence
    target: str
    estimate_given: AmbientEstimate | None
    solutions_given: dict[str, FlashSolution] | None
    solver: str = "tikhonov"
    alpha: float | str = "auto"
    bin_factor: int = analysis.DEFAULT_BIN_FACTOR
    files: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    details: dict = field(default_factory=dict)

    def estimate(self) -> AmbientEstimate:
        if self.estimate_given is None:
            progress(f"estimating the ambient of {self.sequence.directory}")
            estimate = analysis.estimate_sequence(self.sequence, self.solver, self.alpha, bin_factor=self.bin_factor)
            refuse_dark_ambient(
                self.sequence, estimate, "export a neutral, spectra and flash images for (--to ome-tiff needs none)"
            )
            for warning in estimate.warnings:
                self.note(f"estimate: {warning}")
            self.estimate_given = estimate
        return self.estimate_given

    def solutions(self) -> dict[str, FlashSolution]:
        if self.solutions_given is None:
            if self.sequence.camera_responsivities() is None:
                self.note("no camera responsivities in the sequence: no flash mixes (the flash solvers need them)")
                self.solutions_given = {}
            else:
                weights = self.estimate().ambient_weights
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always", TargetUnreachableWarning)
                    self.solutions_given = {
                        mode: analysis.solve_sequence_flash(self.sequence, mode, weights, self.target)
                        for mode in FLASH_MODES
                    }
                for warning in caught:
                    self.note(str(warning.message))
        return self.solutions_given

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)


def _frame_notes(sequence: Sequence, index: int) -> dict[str, str]:
    frame = sequence.frames[index]
    return {
        "file": frame.file,
        "role": frame.role,
        "led_levels": json.dumps(list(frame.led_levels)),
        "exposure_us": repr(frame.exposure_us),
        "gain": repr(frame.gain),
    }


def _led_notes(sequence: Sequence) -> dict[str, object]:
    """The LEDs' names and measured peaks (nm), the one number for each (:meth:`Sequence.led_peaks_nm`)."""
    return {"led_names": [led.name for led in sequence.leds], "led_peak_nm": list(sequence.led_peaks_nm())}


def _iso_speed(work: _Work, gain: float) -> float | None:
    """A frame's ISO speed: ``camera.iso_speed_at_unit_gain`` × its linear gain, or None (with a note) when unknown."""
    camera = work.sequence.camera
    iso = camera.iso_speed_at_unit_gain
    if iso is None:
        work.note(
            "DNG: no ISOSpeedRatings: the camera's ISO equivalence is unknown (no camera.iso_speed_at_unit_gain "
            "in the sequence; machine-vision cameras state none)"
        )
        return None
    if camera.gain_is_relative:
        work.note("DNG: no ISOSpeedRatings: the frames' linear gain is unknown (camera.gain.linear is relative)")
        return None
    return iso * gain


def _delta_t(sequence: Sequence) -> tuple[list[float | None], str]:
    """Each frame's time after frame 0, s, and where it comes from.

    The camera's clock (``timestamp_ns``) where frame 0 and the frame both have one and it did not run
    back (a camera reopened or a replay without timestamps); else the wall clock (``time_utc``); else None.
    """
    frames = sequence.frames
    first_tick = frames[0].extra.get("timestamp_ns") if frames else None
    first_time = frames[0].captured_utc if frames else None
    times: list[float | None] = []
    sources: set[str] = set()
    for index, frame in enumerate(frames):
        tick = frame.extra.get("timestamp_ns")
        moment = frame.captured_utc
        if (
            isinstance(tick, int)
            and isinstance(first_tick, int)
            and not isinstance(tick, bool)
            and (tick > first_tick or (index == 0 and tick >= 0))
        ):
            times.append((tick - first_tick) / 1e9)
            sources.add("the camera's clock (frames[].timestamp_ns)")
        elif moment is not None and first_time is not None:
            times.append((moment - first_time).total_seconds())
            sources.add("the wall clock when each frame reached the writer (frames[].time_utc)")
        else:
            times.append(None)
    return times, "; ".join(sorted(sources)) or "unknown (no timestamp_ns or time_utc recorded)"


def _lone_led(levels: tuple[float, ...]) -> int | None:
    lit = [k for k, level in enumerate(levels) if level > 0]
    return lit[0] if len(lit) == 1 else None


def _write_dng(work: _Work, out: Path) -> None:
    sequence = work.sequence
    cfa = sequence.camera.cfa
    assert cfa is not None  # check_export refused RGB sequences
    estimate = work.estimate()
    responsivities = sequence.camera_responsivities()
    if responsivities is None:
        work.note(
            "no camera responsivities in the sequence: DNG ColorMatrix1 and AsShotNeutral assume camera RGB is "
            "linear sRGB (as msflash's previews do)"
        )
    matrix = camera_matrix(responsivities)
    leds = sequence_spectra.led_spectra_photons(sequence)
    ambient = estimate.spectrum.values[:, 0]
    work.details["color_matrix_source"] = matrix.source
    if any(frame.captured_utc is None for frame in sequence.frames):
        work.note(
            "DNG: frames recorded without time_utc (by an older msflash or another tool) have no DateTimeOriginal"
        )
    for index, frame in enumerate(sequence.frames):
        light = ambient + leds.values @ np.asarray(frame.led_levels)
        illuminant = estimate.spectrum.replace(values=light[:, None], source=f"{sequence.path}: frames[{index}] light")
        neutral = camera_neutral(illuminant, responsivities)
        if frame.role == "ambient" and "ambient_neutral" not in work.details:
            work.details["ambient_neutral"] = [round(float(v), 6) for v in neutral]
        path = out / f"{Path(frame.file).stem}.dng"
        write_dng(
            path,
            sequence.load_frame(index),
            cfa,
            sequence.camera.black_level,
            sequence.camera.white_level,
            neutral,
            matrix.xyz_to_camera,
            sequence.camera.model,
            json.dumps(
                {
                    "msflash:" + key: value
                    for key, value in {**_frame_notes(sequence, index), **_led_notes(sequence)}.items()
                }
            ),
            frame.exposure_us,
            frame.captured_utc,
            _iso_speed(work, frame.gain),
        )
        work.files.append(path)


def _write_ome(work: _Work, out: Path) -> None:
    sequence = work.sequence
    names = [led.name for led in sequence.leds]
    delta_t, delta_t_source = _delta_t(sequence)
    planes = []
    for index, frame in enumerate(sequence.frames):
        lone = _lone_led(frame.led_levels)
        label = names[lone] if lone is not None and frame.role == "led" else frame.role
        planes.append(
            OmePlane(
                f"{index:03d} {label}",
                frame.exposure_us,
                frame.gain,
                lone if frame.role == "led" else None,
                _frame_notes(sequence, index),
                delta_t[index],
            )
        )
    lights = [OmeLight(name, peak) for name, peak in zip(names, sequence.led_peaks_nm(), strict=True)]
    camera = sequence.camera
    acquired = sequence.frames[0].captured_utc
    if acquired is None:
        work.note(
            "OME-TIFF: no AcquisitionDate: frame 0 was recorded without time_utc (an older msflash or another tool)"
        )
    notes = {
        # The folder's name, not its path: a file that travels should not carry the user's directories.
        "sequence": sequence.directory.name,
        "delta_t_source": delta_t_source,
        "spectral_unit": sequence.spectral_unit,
        "cfa": camera.cfa or "none (RGB)",
        "black_level": repr(camera.black_level),
        "white_level": repr(camera.white_level),
        "pixel_format": camera.pixel_format,
        "led_names": json.dumps(names),
    }

    def frames() -> Iterator[np.ndarray]:
        for index in range(len(sequence.frames)):
            yield sequence.load_frame(index)

    path = out / "sequence.ome.tif"
    write_ome_tiff(path, frames(), planes, lights, camera.model, sequence.directory.name, notes, acquired)
    work.files.append(path)


def _write_csv(work: _Work, out: Path) -> None:
    sequence = work.sequence
    estimate = work.estimate()
    unit = f"relative {sequence.spectral_unit}"
    payload = analysis.estimate_payload(sequence, estimate)
    spectrum, std = np.asarray(payload["spectrum"]), np.asarray(payload["spectrum_std"])
    leds = sequence.led_spectra()
    columns = [
        SpectrumColumn("ambient estimate", unit, spectrum),
        SpectrumColumn("ambient estimate - 1 sigma", unit, spectrum - std),
        SpectrumColumn("ambient estimate + 1 sigma", unit, spectrum + std),
    ]
    columns += [
        SpectrumColumn(f"LED {name} at full drive", unit, leds.values[:, k]) for k, name in enumerate(leds.names)
    ]
    for mode, solution in work.solutions().items():
        mix = leds.values @ solution.flash_weights
        columns.append(SpectrumColumn(f"{mode} flash mix", unit, mix))
        if mode == "complementary":
            columns.append(
                SpectrumColumn(f"ambient + complementary flash (target {work.target})", unit, spectrum + mix)
            )
    path = out / "spectra.csv"
    write_spectra_csv(path, sequence.wavelengths_nm, columns)
    work.files.append(path)
    # What a CSV header cannot say (a comment line would trip CSV readers): the band's meaning, the weights.
    about = {
        "spectra": path.name,
        "sequence": sequence.directory.name,
        "unit": f"{unit}: the sequence's spectral_unit, on the scale of the LED spectra at full drive",
        "band": estimate.band_meaning,
        **_led_notes(sequence),
        "ambient_weights": [float(w) for w in payload["ambient_weights"]],
        "flash_weights": {mode: solution.flash_weights.tolist() for mode, solution in work.solutions().items()},
        "complementary_target": work.target,
        "warnings": list(payload["warnings"]),
    }
    about_path = out / "spectra.json"
    about_path.write_text(json.dumps(about, indent=1) + "\n", encoding="utf-8")
    work.files.append(about_path)


def _write_exr(work: _Work, out: Path) -> None:
    sequence = work.sequence
    if sequence.camera_responsivities() is None:
        work.note("no camera responsivities in the sequence: EXR chromaticities are sRGB's (assumed)")
    stack = analysis.load_frame_stack(sequence)
    ambient, _ = sequence.load_linear_frame(stack.ambient_index)
    images = {"ambient": (ambient, {"msflash:content": "the ambient frame"})}
    for mode, solution in work.solutions().items():
        image, _, _ = analysis.synthesize_sequence(sequence, solution.flash_weights, stack, work.estimate().flicker)
        content = {
            "msflash:content": f"the {mode} computational flash image",
            "msflash:flash_weights": solution.flash_weights.tolist(),
        }
        images[mode] = (image, content)
    for name, (image, content) in images.items():
        path = out / f"{name}.exr"
        rgb, metadata = exr_image(sequence, image)
        write_image(path, rgb, {**metadata.attributes, **content}, metadata.chromaticities)
        work.files.append(path)


_WRITERS: dict[str, Callable[[_Work, Path], None]] = {
    "dng": _write_dng,
    "ome-tiff": _write_ome,
    "csv": _write_csv,
    "exr": _write_exr,
}


def check_out(out: Path, option: str = "--out") -> None:
    """Refuse an ``out`` that exists or whose parent folder does not.

    Raises
    ------
    UsageError
        Naming the option and the folder.
    """
    check_output_name(out, option, UsageError)
    if out.exists() or out.is_symlink():
        raise UsageError(f"{option} {out}: already exists; expected a new folder (nothing is overwritten)")
    if not out.parent.is_dir():
        raise UsageError(f"{option} {out}: its folder {out.parent} does not exist; expected an existing folder")


def export_sequence(
    sequence: Sequence,
    formats: tuple[str, ...],
    out: Path,
    *,
    estimate: AmbientEstimate | None = None,
    solutions: dict[str, FlashSolution] | None = None,
    target: str = "D65",
    solver: str = "tikhonov",
    alpha: float | str = "auto",
    bin_factor: int = analysis.DEFAULT_BIN_FACTOR,
    option: str = "--out",
) -> ExportResult:
    """Write ``formats`` of ``sequence`` into the new folder ``out``.

    The files are written into a hidden folder beside ``out``, renamed to ``out`` once all are
    written: on any failure nothing is left (the hidden folder is removed); one export at a time
    per ``out``, and the hidden folders of killed exports are removed (:mod:`.staging`).

    Parameters
    ----------
    out
        A folder that does not exist yet, in one that does.
    estimate, solutions
        The ambient estimate (photons) and the matching/complementary flash already made (``run``), or
        None to make them here through :mod:`acquisition.session.analysis` (the one route).
    solver, alpha, bin_factor
        How the ambient is estimated when ``estimate`` is None (:func:`acquisition.session.analysis.estimate_sequence`).

    Raises
    ------
    UsageError
        As :func:`check_out` and :func:`check_export`; ``out`` inside the sequence folder.
    FolderInUseError
        Another export is writing ``out`` (its PID named).
    RecordingError, SpectralDataError
        From reading the frames or estimating (nothing is left behind).
    OutputWriteError
        If writing fails (disk full…): nothing is left behind.
    """
    out = Path(out)
    unknown = [name for name in formats if name not in EXPORT_FORMATS]
    if unknown:
        raise UsageError(f"export format {unknown[0]!r} is unknown; expected some of {', '.join(EXPORT_FORMATS)}")
    check_out(out, option)
    check_not_inside(out, sequence.directory, option, "the sequence folder")
    check_export(sequence, formats)
    work = _Work(sequence, target, estimate, solutions, solver, alpha, bin_factor)
    with staged_export(out, option, check_out, work.notes) as staging:
        for name in formats:
            progress(f"exporting {name} of {sequence.directory}")
            _WRITERS[name](work, staging)
    files = tuple(out / path.relative_to(staging) for path in work.files)
    return ExportResult(out, files, tuple(work.notes), dict(work.details))
