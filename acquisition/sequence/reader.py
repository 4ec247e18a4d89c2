"""Reading sequence format v1: :func:`read_sequence` reads and validates a sequence directory.

Complete or partial: a writer's crash leaves ``complete: false`` (:mod:`acquisition.sequence.writer`),
and such a sequence is read, reported through :attr:`Sequence.partial`. Reading a partial sequence notes
(logging, never deleting) the temporary files a killed writer left, unless the process named in its
``.msflash-lock`` still runs (:mod:`acquisition.sequence.folder_claim`). Every problem is a
:class:`~acquisition.errors.RecordingError` naming the file and the field.
"""

from __future__ import annotations

import copy
import logging
import math
import os
import sys
from pathlib import Path, PurePosixPath
from typing import Any, Literal, NoReturn, TypeVar, overload

import numpy as np

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.folder_claim import stale_temporaries
from msflash.acquisition.sequence.format import (
    CAMERA_KEYS,
    CFA_PATTERNS,
    FRAME_KEYS,
    FRAME_ROLES,
    FRAMES_DIR,
    ISO_SPEED_KEY,
    LED_KEYS,
    PEAK_NM_KEY,
    RESPONSIVITY_CHANNELS,
    SEQUENCE_FILE,
    SEQUENCE_FORMAT,
    SEQUENCE_VERSION,
    SPECTRAL_UNITS,
    TIME_UTC_KEY,
    TOP_KEYS,
    Sequence,
    SequenceCamera,
    SequenceFrame,
    SequenceLed,
    parse_time_utc,
)
from msflash.acquisition.sequence.frame_digest import SHA256_PATTERN, FileDigest
from msflash.processing.errors import SpectralDataError
from msflash.processing.json_input import parse_json_document
from msflash.processing.negative_values import blind_columns, clip_negative_noise
from msflash.processing.spectra import WavelengthGrid
from msflash.processing.spectral_rows import NANOMETRE_RANGE
from msflash.processing.user_files import IMAGE_MAX_BYTES, JSON_MAX_BYTES, check_user_file, read_user_text, shown_path

_log = logging.getLogger(__name__)

_Choice = TypeVar("_Choice", bound=str)


class _Fields:
    """Typed access to one JSON object, with errors naming the file and the dotted field."""

    def __init__(self, file: Path, where: str, value: Any, known: tuple[str, ...]) -> None:
        self.file = file
        self.where = where
        if not isinstance(value, dict):
            self.fail(where or "the document", f"is {_json_type(value)}", "an object")
        self.value: dict = value
        self.extra = {k: copy.deepcopy(v) for k, v in value.items() if k not in known}

    def name(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def fail(self, field_name: str, what: str, expected: str) -> NoReturn:
        raise RecordingError(f"{self.file}: {field_name} {what}; expected {expected}")

    def get(self, key: str, expected: str, *, optional: bool = False) -> Any:
        if key not in self.value:
            if optional:
                return None
            self.fail(self.name(key), "is missing", expected)
        return self.value[key]

    @overload
    def string(self, key: str, *, optional: Literal[False] = False, choices: tuple[str, ...] = ()) -> str: ...
    @overload
    def string(self, key: str, *, optional: bool, choices: tuple[str, ...] = ()) -> str | None: ...
    def string(self, key: str, *, optional: bool = False, choices: tuple[str, ...] = ()) -> str | None:
        expected = f"one of {', '.join(repr(c) for c in choices)}" if choices else "a non-empty string"
        value = self.get(key, expected, optional=optional)
        if value is None and optional:
            return None
        if not isinstance(value, str) or not value:
            self.fail(self.name(key), f"is {_describe(value)}", expected)
        if choices and value not in choices:
            self.fail(self.name(key), f"is {value!r}", expected)
        return value

    def choice(self, key: str, choices: tuple[_Choice, ...]) -> _Choice:
        """The member of ``choices`` the field holds (a failure naming them otherwise)."""
        return choices[choices.index(self.string(key, choices=choices))]

    def number(self, key: str, expected: str = "a number") -> float:
        value = self.get(key, expected)
        return _number(self.file, self.name(key), value, expected)


def _json_type(value: Any) -> str:
    return {
        dict: "an object",
        list: "a list",
        str: "a string",
        bool: "a boolean",
        int: "a number",
        float: "a number",
        type(None): "null",
    }.get(type(value), type(value).__name__)


def _describe(value: Any) -> str:
    return repr(value) if isinstance(value, str) else _json_type(value)


def _number(file: Path, field_name: str, value: Any, expected: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise RecordingError(f"{file}: {field_name} is {_describe(value)}; expected {expected}")
    try:
        number = float(value)
    except OverflowError:
        raise RecordingError(
            f"{file}: {field_name} is an integer of {len(str(abs(value)))} digits; expected {expected} (finite)"
        ) from None
    if not math.isfinite(number):
        raise RecordingError(f"{file}: {field_name} is {value}; expected {expected} (finite)")
    return number


def _number_list(file: Path, field_name: str, value: Any, length: int | None, what: str) -> np.ndarray:
    if not isinstance(value, list):
        raise RecordingError(f"{file}: {field_name} is {_json_type(value)}; expected a list of numbers")
    if length is not None and len(value) != length:
        raise RecordingError(f"{file}: {field_name} has {len(value)} values; expected {length} ({what})")
    for i, item in enumerate(value):
        if isinstance(item, bool) or not isinstance(item, int | float):
            raise RecordingError(f"{file}: {field_name}[{i}] is {_describe(item)}; expected a number")
        try:
            finite = math.isfinite(item)
        except OverflowError:
            raise RecordingError(
                f"{file}: {field_name}[{i}] is an integer of {len(str(abs(item)))} digits; expected a finite number"
            ) from None
        if not finite:
            raise RecordingError(f"{file}: {field_name}[{i}] is {item}; expected a finite number")
    return np.array(value, dtype=float)


def _spectrum(file: Path, field_name: str, value: Any, wavelengths_nm: np.ndarray) -> np.ndarray:
    """A spectrum's values; negatives within measurement noise become 0, larger ones are refused.

    Measured spectra (dark-subtracted spectrometer readings of LEDs, monochromator sweeps of a
    camera) carry small negative values in their tails. They are clipped by the one rule every
    reader of measured spectra applies (:func:`processing.negative_values.clip_negative_noise`);
    a value below it is no noise and the sequence is refused.
    """
    values = _number_list(file, field_name, value, wavelengths_nm.size, "one per wavelength")
    try:
        clipped, _ = clip_negative_noise(
            wavelengths_nm, values, [field_name], str(file), place=lambda row, _column: f"{field_name}[{row}]"
        )
    except SpectralDataError as err:
        raise RecordingError(str(err)) from None
    return clipped


def _load_json(path: Path) -> Any:
    """The document in ``sequence.json``, refused naming the field for anything but plain finite JSON.

    One reader for every JSON file a user hands msflash (:func:`msflash.processing.json_input.parse_json_document`):
    a key twice, an integer of thousands of digits, nesting deeper than
    :data:`~msflash.processing.json_input.MAX_NESTING` (format v1 needs 4).
    """
    if not os.path.lexists(path):
        raise RecordingError(
            f"{shown_path(path)}: file is missing; expected a sequence directory holding {SEQUENCE_FILE}"
        )
    text = read_user_text(path, f"a sequence's {SEQUENCE_FILE} (UTF-8 JSON)", JSON_MAX_BYTES, RecordingError)
    # Other tools' unknown keys are kept uninterpreted, whatever numbers they hold; each field
    # format v1 defines is checked as it is read (finite, in range).
    return parse_json_document(text, shown_path(path), RecordingError, finite_numbers=False)


def _parse_camera(file: Path, value: Any, wavelengths_nm: np.ndarray) -> SequenceCamera:
    camera = _Fields(file, "camera", value, CAMERA_KEYS)
    model = camera.string("model")
    serial = camera.string("serial", optional=True)
    pixel_format = camera.string("pixel_format")
    cfa = camera.get("cfa", "null or one of " + ", ".join(CFA_PATTERNS))
    if cfa is not None and cfa not in CFA_PATTERNS:
        camera.fail("camera.cfa", f"is {_describe(cfa)}", "null (RGB frames) or one of " + ", ".join(CFA_PATTERNS))
    black = camera.number("black_level", "a number ≥ 0")
    white = camera.number("white_level", "a number above black_level")
    if black < 0:
        camera.fail("camera.black_level", f"is {black:g}", "a number ≥ 0")
    if not black < white:
        camera.fail("camera.white_level", f"is {white:g}, not above black_level {black:g}", "black_level < white_level")
    responsivity = None
    raw = camera.get("responsivity", "", optional=True)
    if raw is not None:
        if not isinstance(raw, dict):
            camera.fail("camera.responsivity", f"is {_json_type(raw)}", "null or an object with R, G and B spectra")
        missing = [c for c in RESPONSIVITY_CHANNELS if c not in raw]
        if missing:
            camera.fail("camera.responsivity", f"lacks {', '.join(missing)}", "R, G and B spectra")
        # Channels beyond R, G, B are kept (and validated) rather than refused: unknown keys survive.
        responsivity = {str(c): _spectrum(file, f"camera.responsivity.{c}", v, wavelengths_nm) for c, v in raw.items()}
        # A channel blind on the whole grid is no camera's: the estimate read it as LEDs that gave
        # no light (exit 1, blaming the booth), and the flash solvers as a camera that sees nothing.
        blind = blind_columns(np.column_stack([responsivity[c] for c in RESPONSIVITY_CHANNELS]), RESPONSIVITY_CHANNELS)
        if blind:
            camera.fail(
                f"camera.responsivity.{blind[0]}",
                f"has no positive value on {wavelengths_nm[0]:g}–{wavelengths_nm[-1]:g} nm",
                "each of R, G and B sensitive somewhere on the sequence's grid (or responsivity null)",
            )
    if ISO_SPEED_KEY in camera.extra:
        iso = _number(file, f"camera.{ISO_SPEED_KEY}", camera.extra[ISO_SPEED_KEY], "an ISO speed > 0")
        if iso <= 0:
            camera.fail(f"camera.{ISO_SPEED_KEY}", f"is {iso:g}", "an ISO speed > 0 (or no such key: unknown)")
    return SequenceCamera(model, serial, pixel_format, cfa, black, white, responsivity, camera.extra)


def _parse_leds(file: Path, value: Any, wavelengths_nm: np.ndarray) -> tuple[SequenceLed, ...]:
    if not isinstance(value, list):
        raise RecordingError(f"{file}: leds is {_json_type(value)}; expected a list of LED objects")
    leds = []
    seen: dict[str, int] = {}
    for i, item in enumerate(value):
        led = _Fields(file, f"leds[{i}]", item, LED_KEYS)
        name = led.string("name")
        if name in seen:
            led.fail(f"leds[{i}].name", f"{name!r} repeats leds[{seen[name]}].name", "unique LED names")
        seen[name] = i
        spd = _spectrum(file, f"leds[{i}].spd", led.get("spd", "a list of numbers"), wavelengths_nm)
        peak = led.get(PEAK_NM_KEY, "", optional=True)
        if peak is not None:
            peak = _number(file, f"leds[{i}].{PEAK_NM_KEY}", peak, "a wavelength in nm > 0")
            if peak <= 0:
                led.fail(f"leds[{i}].{PEAK_NM_KEY}", f"is {peak:g}", "a wavelength in nm > 0")
        leds.append(SequenceLed(name, spd, led.extra, peak))
    return tuple(leds)


def _check_file(file: Path, directory: Path, where: str, value: Any, *, must_exist: bool) -> str:
    if not isinstance(value, str) or not value:
        raise RecordingError(f"{file}: {where} is {_describe(value)}; expected a relative file path")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise RecordingError(
            f"{file}: {where} {value!r} is not a UTF-8 file name; expected a file name in UTF-8 "
            "(rename the file and its entry)"
        ) from None
    if (
        "\\" in value
        and must_exist
        and not (directory / value).exists()
        and (directory / value.replace("\\", "/")).exists()
    ):
        value = value.replace("\\", "/")  # written on Windows (str of a WindowsPath): '\' separators
    relative = PurePosixPath(value)
    if relative.is_absolute() or Path(value).is_absolute():
        raise RecordingError(
            f"{file}: {where} {value!r} is absolute; expected a path relative to the sequence directory"
        )
    try:
        root = directory.resolve()
        target = (directory / value).resolve()
    except (RuntimeError, OSError) as err:  # a symlink loop: RuntimeError before Python 3.13, OSError after
        raise RecordingError(
            f"{file}: {where} {value!r} cannot be resolved ({err}); expected a frame file, not a symlink loop"
        ) from None
    if target == root or not target.is_relative_to(root):
        raise RecordingError(
            f"{file}: {where} {value!r} points outside the sequence directory; expected a path inside it"
        )
    if must_exist:
        if not target.exists():
            raise RecordingError(f"{file}: {where} {value!r} is missing; expected the frame file on disk")
        # A FIFO, a device or a directory is refused by what it is, before anything opens it.
        check_user_file(target, "a frame image", IMAGE_MAX_BYTES, RecordingError, name=f"{file}: {where} {value!r}")
    return value


def parse_frame(
    file: Path, directory: Path, index: int, value: Any, n_leds: int, *, must_exist: bool = True
) -> SequenceFrame:
    frame = _Fields(file, f"frames[{index}]", value, FRAME_KEYS)
    name = frame.name
    path = _check_file(file, directory, name("file"), frame.get("file", "a relative file path"), must_exist=must_exist)
    role = frame.choice("role", FRAME_ROLES)
    levels = _number_list(file, name("led_levels"), frame.get("led_levels", "a list of numbers"), n_leds, "one per LED")
    for i, level in enumerate(levels):
        if not 0.0 <= level <= 1.0:
            frame.fail(f"{name('led_levels')}[{i}]", f"is {level:g}", "a level in [0, 1]")
    if role in ("ambient", "dark") and np.any(levels != 0):
        frame.fail(name("led_levels"), f"are {levels.tolist()} for role '{role}'", "all 0 (the LEDs are off)")
    exposure = frame.number("exposure_us", "a number > 0")
    if exposure <= 0:
        frame.fail(name("exposure_us"), f"is {exposure:g}", "a number > 0")
    gain = frame.number("gain", "a number > 0")
    if gain <= 0:
        frame.fail(name("gain"), f"is {gain:g}", "a number > 0")
    # Processing divides by exposure · gain: a denormal one (5e-324) would make the frame's scale infinite.
    if exposure * gain == 0 or not math.isfinite(1.0 / (exposure * gain)):
        frame.fail(
            name("exposure_us"),
            f"× gain is {exposure:g} × {gain:g}, too small to divide by",
            f"exposure_us × gain of at least {1 / sys.float_info.max:.3g}",
        )
    digest = _parse_digest(frame)
    moment = frame.get(TIME_UTC_KEY, "", optional=True)
    if moment is not None and parse_time_utc(moment) is None:
        frame.fail(
            name(TIME_UTC_KEY),
            f"is {_describe(moment)}",
            "an ISO 8601 time with its zone, e.g. 2026-03-01T12:30:05.250000Z",
        )
    return SequenceFrame(path, role, tuple(levels.tolist()), exposure, gain, frame.extra, digest, moment)


def _parse_digest(frame: _Fields) -> FileDigest | None:
    """``sha256`` and ``file_bytes``: both or neither (optional fields of format v1, docs/architecture.md §6)."""
    sha256 = frame.get("sha256", "", optional=True)
    size = frame.get("file_bytes", "", optional=True)
    if sha256 is None and size is None:
        return None
    if sha256 is None or size is None:
        present, absent = ("sha256", "file_bytes") if size is None else ("file_bytes", "sha256")
        frame.fail(frame.name(absent), f"is missing but {present} is given", "both or neither (the file's digest)")
    if not isinstance(sha256, str) or not SHA256_PATTERN.fullmatch(sha256):
        frame.fail(
            frame.name("sha256"), f"is {_describe(sha256)}", "64 lowercase hexadecimal digits (the file's SHA-256)"
        )
    if isinstance(size, bool) or not isinstance(size, int) or size < 0:
        frame.fail(frame.name("file_bytes"), f"is {_describe(size)}", "an integer ≥ 0 (the file's length in bytes)")
    return FileDigest(sha256, size)


def parse_document(file: Path, directory: Path, document: Any, *, check_files: bool = True) -> Sequence:
    top = _Fields(file, "", document, TOP_KEYS)
    fmt = top.get("format", repr(SEQUENCE_FORMAT))
    if fmt != SEQUENCE_FORMAT:
        top.fail("format", f"is {_describe(fmt)}", repr(SEQUENCE_FORMAT))
    version = top.get("version", str(SEQUENCE_VERSION))
    if isinstance(version, bool) or not isinstance(version, int):
        top.fail("version", f"is {_describe(version)}", f"the integer {SEQUENCE_VERSION}")
    if version > SEQUENCE_VERSION:
        raise RecordingError(
            f"{file}: version {version} is newer than this msflash reads ({SEQUENCE_VERSION}); upgrade msflash"
        )
    if version < SEQUENCE_VERSION:
        top.fail("version", f"{version} is not a version of this format", str(SEQUENCE_VERSION))
    complete = top.get("complete", "true or false")
    if not isinstance(complete, bool):
        top.fail("complete", f"is {_describe(complete)}", "true or false")
    wavelengths = _number_list(file, "wavelengths_nm", top.get("wavelengths_nm", "a list of numbers"), None, "")
    try:
        grid = WavelengthGrid.from_wavelengths(wavelengths, where="wavelengths_nm")
    except SpectralDataError as err:
        raise RecordingError(f"{file}: {err}") from err
    low, high = NANOMETRE_RANGE  # the rule of every user's spectral file: a grid in µm or Å is another unit
    if grid.start_nm < low or grid.stop_nm > high:
        top.fail(
            "wavelengths_nm",
            f"spans {grid.start_nm:g}–{grid.stop_nm:g}",
            f"nanometres within {low:g}–{high:g} (a grid of 0.4–0.7 is in micrometres: times 1000)",
        )
    unit = top.choice("spectral_unit", SPECTRAL_UNITS)
    camera = _parse_camera(file, top.get("camera", "an object"), grid.wavelengths_nm)
    leds = _parse_leds(file, top.get("leds", "a list of LED objects"), grid.wavelengths_nm)
    raw_frames = top.get("frames", "a list of frame objects")
    if not isinstance(raw_frames, list):
        top.fail("frames", f"is {_json_type(raw_frames)}", "a list of frame objects")
    frames = tuple(
        parse_frame(file, directory, i, item, len(leds), must_exist=check_files) for i, item in enumerate(raw_frames)
    )
    # One file per frame: an entry repeating another's file (an edit gone wrong) gives two LEDs the
    # same image, which estimation cannot tell from two real frames (no error, skewed weights).
    seen_files: dict[str, int] = {}
    for i, frame in enumerate(frames):
        key = os.path.normpath(frame.file)
        if key in seen_files:
            top.fail(
                f"frames[{i}].file", f"{frame.file!r} is also frames[{seen_files[key]}].file", "one file per frame"
            )
        seen_files[key] = i
    # A partial sequence may stop before its first frame; a complete one must be usable.
    if complete and not any(f.role == "ambient" for f in frames):
        top.fail("frames", "has no frame with role 'ambient'", "at least one ambient frame in a complete sequence")
    return Sequence(directory, complete, wavelengths, unit, camera, leds, frames, top.extra)


def read_sequence(directory: str | os.PathLike, *, require_files: bool = True) -> Sequence:
    """Read and validate a sequence directory (or its ``sequence.json``, format v1), complete or partial: check
    :attr:`Sequence.partial` before treating it as a finished capture; pixels are read with :meth:`Sequence.load_frame`.

    ``require_files`` False accepts missing or irregular frame files (``msflash check`` reports each itself).

    Raises
    ------
    RecordingError
        Naming the file and the field, for malformed JSON (with line and column), a missing
        or mistyped field, a newer version, a non-uniform grid, spectra of the wrong length or
        with negative values, an unknown role or CFA, out-of-range levels, exposures or gains,
        frame files missing or outside the directory, or a complete sequence without ambient frame.
    """
    directory = Path(directory)
    if directory.name == SEQUENCE_FILE and directory.is_file():
        directory = directory.parent
    file = directory / SEQUENCE_FILE
    sequence = parse_document(file, directory, _load_json(file), check_files=require_files)
    if sequence.partial:
        _report_stale_temporaries(directory)
    return sequence


def _report_stale_temporaries(directory: Path) -> None:
    """One note for the temporary files a killed writer left (reading never deletes them)."""
    stale = stale_temporaries(directory, FRAMES_DIR)
    if stale:
        _log.warning(
            "%s: %d temporary file(s) left by a writer that was stopped (%s%s); not part of the sequence, "
            "safe to delete",
            directory,
            len(stale),
            stale[0].relative_to(directory),
            ", …" if len(stale) > 1 else "",
        )
