"""Sequence format v1 (docs/architecture.md §6): the data model, a validating reader and a crash-safe writer.

Public objects
--------------
- :class:`Sequence`, :class:`SequenceCamera`, :class:`SequenceLed`, :class:`SequenceFrame`:
  frozen dataclasses mirroring ``sequence.json``; unknown keys are kept in ``extra``.
- :func:`read_sequence`: read and validate a sequence directory (complete or partial).
- :class:`SequenceWriter`: write a sequence frame by frame, crash-safe.
- :func:`write_sequence`: write a whole sequence at once (copying, converting, test data).

Every problem is a :class:`~acquisition.errors.RecordingError` whose message names the file and
the field: ``".../sequence.json: frames[3].file 'frames/003-led.tiff' is missing"``.

Crash safety
------------
The writer writes ``sequence.json`` with ``complete: false`` before any frame, writes each frame
file atomically, then replaces ``sequence.json`` atomically (temporary file, fsync,
``os.replace``). So at every instant the directory holds a readable sequence listing only frames
that are fully on disk; a crash (exception, Ctrl-C, SIGKILL) leaves ``complete: false``.
The reader accepts such partial sequences and reports them through :attr:`Sequence.partial`.
Reading a partial sequence notes (logging, never deleting) the temporary files a killed writer
left, unless the process named in its ``.msflash-lock`` still runs (:mod:`acquisition.sequence.folder_claim`).
"""

from __future__ import annotations

import contextlib
import copy
import json
import logging
import math
import os
import sys
import tempfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields, replace
from datetime import UTC, datetime
from pathlib import Path, PurePosixPath
from types import TracebackType
from typing import Any, ClassVar, Literal, NoReturn, TypeVar, overload

import numpy as np

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.folder_claim import FolderClaim, claim_folder, stale_temporaries
from msflash.acquisition.sequence.frame_binding import SelfDescription, binding_problem
from msflash.acquisition.sequence.frame_digest import SHA256_PATTERN, FileDigest, check_frame_digest
from msflash.acquisition.sequence.frame_integrity import check_frame_levels
from msflash.acquisition.sequence.image_files import (
    ImageHeader,
    image_suffix,
    read_image_and_header,
    read_image_header,
    write_image_digest,
)
from msflash.calibration.file_modes import default_file_mode
from msflash.processing.errors import SpectralDataError
from msflash.processing.json_input import MAX_NESTING as MAX_NESTING  # the deepest a sequence.json may nest
from msflash.processing.json_input import parse_json_document
from msflash.processing.led_wavelength import PEAK_METADATA_KEY, led_peaks_nm
from msflash.processing.negative_values import blind_columns, clip_negative_noise
from msflash.processing.spectra import Spectra, WavelengthGrid
from msflash.processing.synthesis import linearise
from msflash.processing.user_files import IMAGE_MAX_BYTES, JSON_MAX_BYTES, check_user_file, read_user_text, shown_path

SEQUENCE_FORMAT = "msflash-sequence"
"""The value of the ``format`` key."""
SEQUENCE_VERSION = 1
"""The format version this module reads and writes."""
SEQUENCE_FILE = "sequence.json"
"""Name of the description file inside a sequence directory."""
FRAMES_DIR = "frames"
"""Sub-directory the writer puts frame files in."""
FRAME_ROLES: tuple[FrameRole, ...] = ("ambient", "led", "flash", "dark")
"""Allowed ``frames[].role`` values."""
CFA_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
"""Allowed ``camera.cfa`` values besides null."""
SPECTRAL_UNITS: tuple[Literal["energy", "photons"], ...] = ("energy", "photons")
"""Allowed ``spectral_unit`` values."""
RESPONSIVITY_CHANNELS = ("R", "G", "B")
"""Channels ``camera.responsivity`` must hold."""

_log = logging.getLogger(__name__)

FrameRole = Literal["ambient", "led", "flash", "dark"]

_TOP_KEYS = ("format", "version", "complete", "wavelengths_nm", "spectral_unit", "camera", "leds", "frames")
_CAMERA_KEYS = ("model", "serial", "pixel_format", "cfa", "black_level", "white_level", "responsivity")
_LED_KEYS = ("name", "spd", "peak_nm")
_FRAME_KEYS = ("file", "role", "led_levels", "exposure_us", "gain", "sha256", "file_bytes", "time_utc")

TIME_UTC_KEY = "time_utc"
"""Optional ``frames[]`` key (docs/architecture.md §6): the wall-clock time the frame was handed to the writer."""
ISO_SPEED_KEY = "iso_speed_at_unit_gain"
"""Optional ``camera`` key (docs/architecture.md §6): the ISO speed the camera's maker states at linear gain 1."""
PEAK_NM_KEY = "peak_nm"
"""Optional ``leds[]`` key (docs/architecture.md §6): the LED's measured peak wavelength, nm."""


def utc_now_text() -> str:
    """Now, in UTC, as ``frames[].time_utc`` holds it: ISO 8601 with microseconds and ``Z``.

    >>> len(utc_now_text()), utc_now_text()[-1]
    (27, 'Z')
    """
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def parse_time_utc(text: object) -> datetime | None:
    """The aware time of a ``frames[].time_utc`` value (ISO 8601 with a zone), or None if it is not one.

    >>> parse_time_utc("2026-03-01T12:30:05.250000Z").isoformat()
    '2026-03-01T12:30:05.250000+00:00'
    >>> parse_time_utc("2026-03-01 12:30"), parse_time_utc(5)
    (None, None)
    """
    if not isinstance(text, str):
        return None
    try:
        moment = datetime.fromisoformat(text)
    except ValueError:
        return None
    return moment if moment.tzinfo is not None else None


# -- data model ----------------------------------------------------------------------------------
def _frozen_array(values: Any) -> np.ndarray:
    array = np.array(values, dtype=float, copy=True)
    array.flags.writeable = False
    return array


def _values_equal(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and np.array_equal(a, b)
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_values_equal(a[k], b[k]) for k in a)
    if isinstance(a, tuple | list) and isinstance(b, tuple | list):
        return type(a) is type(b) and len(a) == len(b) and all(_values_equal(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


class _ArrayEquality:
    """Field-wise equality that compares arrays by value (dataclass ``eq`` cannot); fields with
    ``compare=False`` are left out."""

    __dataclass_fields__: ClassVar[dict[str, Any]]  # the classes mixing this in are dataclasses

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return all(_values_equal(getattr(self, f.name), getattr(other, f.name)) for f in fields(self) if f.compare)

    __hash__ = None  # type: ignore[assignment]


def _check_extra(owner: str, extra: Mapping, known: tuple[str, ...]) -> dict:
    clash = sorted(set(extra) & set(known))
    if clash:
        raise RecordingError(f"{owner}: extra keys {clash} clash with format keys; expected only unknown keys")
    return copy.deepcopy(dict(extra))


@dataclass(frozen=True, eq=False)
class SequenceCamera(_ArrayEquality):
    """The ``camera`` object: identity and pixel encoding of the camera that took the frames."""

    model: str
    """Camera model name."""
    serial: str | None
    """Serial number, or None when the writer did not record one (the key is then omitted)."""
    pixel_format: str
    """GenICam pixel format name (RGB16, BayerRG16, Mono16…)."""
    cfa: str | None
    """Colour filter array of one-channel (raw mosaic) frames: RGGB, BGGR, GRBG, GBRG; None for RGB."""
    black_level: float
    """Pixel value of no light."""
    white_level: float
    """Pixel value at or above which a pixel is saturated."""
    responsivity: dict[str, np.ndarray] | None = None
    """Spectral responsivity per channel (R, G, B; read-only arrays, shape (n_wavelengths,)), or None."""
    extra: dict = field(default_factory=dict)
    """Keys of the ``camera`` object this version does not know, kept and written back."""

    @property
    def iso_speed_at_unit_gain(self) -> float | None:
        """The ISO speed the camera's maker states at linear gain 1 (``camera.iso_speed_at_unit_gain``, optional,
        docs/architecture.md §6), or None: unknown, as for most machine-vision cameras."""
        value = self.extra.get(ISO_SPEED_KEY)
        return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None

    @property
    def gain_is_relative(self) -> bool:
        """True when ``camera.gain.linear`` says every frame records gain 1 for an unknown true gain (issue 29)."""
        gain = self.extra.get("gain")
        linear = gain.get("linear") if isinstance(gain, dict) else None
        return isinstance(linear, str) and linear.startswith("relative")

    def __post_init__(self) -> None:
        if self.responsivity is not None:
            object.__setattr__(self, "responsivity", {str(k): _frozen_array(v) for k, v in self.responsivity.items()})
        object.__setattr__(self, "black_level", float(self.black_level))
        object.__setattr__(self, "white_level", float(self.white_level))
        object.__setattr__(self, "extra", _check_extra("camera", self.extra, _CAMERA_KEYS))


@dataclass(frozen=True, eq=False)
class SequenceLed(_ArrayEquality):
    """One entry of ``leds``: an LED channel and its spectrum at full drive."""

    name: str
    """Channel name, unique in the sequence."""
    spd: np.ndarray
    """Spectral power at full drive, shape (n_wavelengths,), read-only; relative, true ratios between LEDs."""
    extra: dict = field(default_factory=dict)
    """Unknown keys of this LED entry, kept and written back."""
    peak_nm: float | None = field(default=None, compare=False)
    """The LED's peak wavelength as measured where its spectrum was (``peak_nm``; optional,
    docs/architecture.md §6), or None: then :meth:`Sequence.led_peaks_nm` computes it from ``spd``."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "spd", _frozen_array(self.spd))
        if self.peak_nm is not None:
            object.__setattr__(self, "peak_nm", float(self.peak_nm))
        object.__setattr__(self, "extra", _check_extra(f"led '{self.name}'", self.extra, _LED_KEYS))


@dataclass(frozen=True, eq=False)
class SequenceFrame(_ArrayEquality):
    """One entry of ``frames``: a frame file and the conditions it was taken in."""

    file: str
    """Path of the frame file, relative to the sequence directory, with ``/`` separators."""
    role: FrameRole
    """``ambient`` (LEDs off), ``led`` (ambient + LEDs at ``led_levels``), ``flash`` or ``dark``."""
    led_levels: tuple[float, ...]
    """Drive level of each LED in [0, 1], one per entry of ``Sequence.leds``."""
    exposure_us: float
    """Exposure time in microseconds (> 0)."""
    gain: float = 1.0
    """Linear gain (> 0); processing works in ``(value − black) / (exposure_us · gain)``."""
    extra: dict = field(default_factory=dict)
    """Unknown keys of this frame entry, kept and written back."""
    digest: FileDigest | None = field(default=None, compare=False)
    """The file's SHA-256 and length as written (``sha256``, ``file_bytes``; optional, docs/architecture.md §6),
    or None for a frame recorded without them: then the file is read unchecked. Not compared: it
    describes the file's bytes, not the frame (the same frame written a second later has other bytes:
    the TIFF's time stamp)."""

    time_utc: str | None = field(default=None, compare=False)
    """When the frame was handed to the writer, ISO 8601 in UTC with microseconds (``time_utc``; optional,
    docs/architecture.md §6), or None for a frame recorded without it. Not compared: the same frame
    written again is written at another time."""

    @property
    def captured_utc(self) -> datetime | None:
        """:attr:`time_utc` as an aware time, or None if not recorded."""
        return parse_time_utc(self.time_utc)

    def __post_init__(self) -> None:
        object.__setattr__(self, "led_levels", tuple(float(v) for v in self.led_levels))
        object.__setattr__(self, "exposure_us", float(self.exposure_us))
        object.__setattr__(self, "gain", float(self.gain))
        object.__setattr__(self, "extra", _check_extra(f"frame '{self.file}'", self.extra, _FRAME_KEYS))


@dataclass(frozen=True, eq=False)
class Sequence(_ArrayEquality):
    """A sequence directory as described by its ``sequence.json``; pixels are loaded on demand."""

    directory: Path
    """The sequence directory."""
    complete: bool
    """False while a writer is still adding frames, or if it crashed."""
    wavelengths_nm: np.ndarray
    """The uniform wavelength grid every spectrum is sampled on, shape (n_wavelengths,), read-only."""
    spectral_unit: Literal["energy", "photons"]
    """Unit of the LED spectra and responsivities."""
    camera: SequenceCamera
    """The camera."""
    leds: tuple[SequenceLed, ...]
    """The LED channels, in the order of every ``led_levels``."""
    frames: tuple[SequenceFrame, ...]
    """The frames, in capture order."""
    extra: dict = field(default_factory=dict)
    """Unknown top-level keys, kept and written back."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "directory", Path(self.directory))
        object.__setattr__(self, "wavelengths_nm", _frozen_array(self.wavelengths_nm))
        object.__setattr__(self, "leds", tuple(self.leds))
        object.__setattr__(self, "frames", tuple(self.frames))
        object.__setattr__(self, "extra", _check_extra(SEQUENCE_FILE, self.extra, _TOP_KEYS))

    @property
    def path(self) -> Path:
        """The ``sequence.json`` file."""
        return self.directory / SEQUENCE_FILE

    @property
    def partial(self) -> bool:
        """True if the sequence is not complete (a writer is running or crashed)."""
        return not self.complete

    @property
    def grid(self) -> WavelengthGrid:
        """The wavelength grid of :attr:`wavelengths_nm`."""
        return WavelengthGrid.from_wavelengths(self.wavelengths_nm, where=f"{self.path}: wavelengths_nm")

    def led_spectra(self) -> Spectra:
        """The LED spectra at full drive, shape (n_wavelengths, n_leds), in :attr:`spectral_unit`."""
        values = np.column_stack([led.spd for led in self.leds]) if self.leds else np.empty((self.grid.size, 0))
        return Spectra(
            self.grid,
            values,
            tuple(led.name for led in self.leds),
            kind="spd",
            unit=self.spectral_unit,
            source=str(self.path),
        )

    def led_peaks_nm(self) -> tuple[float, ...]:
        """Each LED's peak wavelength, nm: its recorded ``peak_nm``, else computed from its spectrum in energy.

        The one number every export, report and page gives for an LED
        (:func:`processing.led_wavelength.led_peaks_nm`).
        """
        recorded = {led.name: led.peak_nm for led in self.leds if led.peak_nm is not None}
        return led_peaks_nm(self.led_spectra().replace(metadata={PEAK_METADATA_KEY: recorded}))

    def camera_responsivities(self) -> Spectra | None:
        """The camera's R, G, B responsivities, shape (n_wavelengths, 3), or None if not recorded."""
        responsivity = self.camera.responsivity
        if responsivity is None:
            return None
        values = np.column_stack([responsivity[c] for c in RESPONSIVITY_CHANNELS])
        return Spectra(
            self.grid,
            values,
            RESPONSIVITY_CHANNELS,
            kind="responsivity",
            unit=self.spectral_unit,
            source=str(self.path),
        )

    def frame_path(self, index: int) -> Path:
        """The file of frame ``index``."""
        return self.directory / self.frames[index].file

    def indices(self, role: FrameRole) -> tuple[int, ...]:
        """Indices of the frames with ``role``, in capture order."""
        if role not in FRAME_ROLES:
            raise RecordingError(f"{self.path}: role '{role}' is unknown; expected one of {', '.join(FRAME_ROLES)}")
        return tuple(i for i, frame in enumerate(self.frames) if frame.role == role)

    def check_digests(self) -> None:
        """Refuse any frame file that is no longer, byte for byte, the one written (recorded SHA-256 and length;
        frames without them pass). Reads the files' bytes, decodes nothing: a run checks what it wrote this way
        (its estimate and report come from the frames in memory).

        Raises
        ------
        RecordingError
            As :meth:`load_frame` for a changed, truncated or missing file.
        """
        for index, entry in enumerate(self.frames):
            if entry.digest is not None:
                where = f"{self.path}: frames[{index}].file '{entry.file}'"
                check_frame_digest(self.frame_path(index), entry.digest, where)

    def load_frame(self, index: int, *, check_levels: bool = True) -> np.ndarray:
        """The pixels of frame ``index``: (H, W) for a raw mosaic (``cfa`` set), (H, W, 3) for RGB.

        Every route that reads a sequence's frames comes through here, so this is where a frame's
        values are checked against ``camera.black_level`` and ``camera.white_level``
        (:func:`acquisition.sequence.frame_integrity.check_frame_levels`). ``check_levels=False`` is for
        the one reader that measures the black level instead of trusting it (``calibrate dark``).

        Raises
        ------
        RecordingError
            If the file is not the one written (its recorded SHA-256 or length differ: changed,
            truncated or missing), was written for another entry (what the file says of its index,
            role, levels, exposure and gain differs from the entry: :mod:`frame_binding`), unreadable, its channel count does not match ``camera.cfa``, its
            size differs from frame 0's (both files are named), or it holds values above white or
            below black by more than read noise allows (the count and range are named).
        """
        path = self.frame_path(index)
        where = f"{self.path}: frames[{index}].file '{self.frames[index].file}'"
        entry = self.frames[index]
        recorded = entry.digest
        if recorded is not None:
            check_frame_digest(path, recorded, where)

        def declared(header: ImageHeader) -> None:
            """What the file's header says, checked before its pixels are decoded."""
            said = SelfDescription.from_attributes(header.attributes)
            problem = binding_problem(where, said, index, entry.role, entry.led_levels, entry.exposure_us, entry.gain)
            if problem is not None:
                raise RecordingError(problem)
            channels = header.channels
            if self.camera.cfa is not None and channels != 1:
                raise RecordingError(
                    f"{where} has {channels} channels but camera.cfa is '{self.camera.cfa}'; "
                    "expected one channel (a raw mosaic)"
                )
            if self.camera.cfa is None and channels != 3:
                raise RecordingError(
                    f"{where} has {channels} channel but camera.cfa is null; expected three channels (RGB), "
                    "or set camera.cfa for a raw mosaic"
                )
            # Checked lazily against frame 0's header only, so loading one frame never decodes another.
            if index != 0:
                first = read_image_header(self.frame_path(0))
                if (first.height, first.width) != (header.height, header.width):
                    raise RecordingError(
                        f"{where} is {header.width}×{header.height} pixels but frames[0].file "
                        f"'{self.frames[0].file}' is {first.width}×{first.height}; expected one size for all frames"
                    )

        _, pixels = read_image_and_header(path, declared)
        if check_levels:
            check_frame_levels(pixels, self.camera.black_level, self.camera.white_level, self.frames[index].gain, where)
        return pixels

    def load_linear_frame(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``index`` in processing units, ``(raw − black) / (exposure_us · gain)``, and its
        saturated pixels (:func:`processing.synthesis.linearise`).

        Raises
        ------
        RecordingError
            As :meth:`load_frame`.
        """
        frame = self.frames[index]
        return linearise(
            self.load_frame(index), self.camera.black_level, self.camera.white_level, frame.exposure_us, frame.gain
        )


# -- reading ---------------------------------------------------------------------------------------
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
    a key twice, an integer of thousands of digits, nesting deeper than :data:`MAX_NESTING`
    (format v1 needs 4).
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
    camera = _Fields(file, "camera", value, _CAMERA_KEYS)
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
        led = _Fields(file, f"leds[{i}]", item, _LED_KEYS)
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


def _parse_frame(
    file: Path, directory: Path, index: int, value: Any, n_leds: int, *, must_exist: bool = True
) -> SequenceFrame:
    frame = _Fields(file, f"frames[{index}]", value, _FRAME_KEYS)
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


def _parse_document(file: Path, directory: Path, document: Any, *, check_files: bool = True) -> Sequence:
    top = _Fields(file, "", document, _TOP_KEYS)
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
    unit = top.choice("spectral_unit", SPECTRAL_UNITS)
    camera = _parse_camera(file, top.get("camera", "an object"), grid.wavelengths_nm)
    leds = _parse_leds(file, top.get("leds", "a list of LED objects"), grid.wavelengths_nm)
    raw_frames = top.get("frames", "a list of frame objects")
    if not isinstance(raw_frames, list):
        top.fail("frames", f"is {_json_type(raw_frames)}", "a list of frame objects")
    frames = tuple(
        _parse_frame(file, directory, i, item, len(leds), must_exist=check_files) for i, item in enumerate(raw_frames)
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
    """Read and validate a sequence directory (format v1), complete or partial.

    Parameters
    ----------
    directory
        The sequence directory, or its ``sequence.json``.
    require_files
        Refuse a sequence whose frame files are missing or not regular files (the default). False
        for ``msflash check``, which reports each frame's file itself.

    Returns
    -------
    Sequence
        The description; pixels are read with :meth:`Sequence.load_frame`. Check
        :attr:`Sequence.partial` before treating it as a finished capture.

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
    sequence = _parse_document(file, directory, _load_json(file), check_files=require_files)
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


# -- writing ---------------------------------------------------------------------------------------
def _plain(value: Any) -> Any:
    if isinstance(value, float) and value.is_integer() and abs(value) < 2**53:
        return int(value)
    return value


def _camera_json(camera: SequenceCamera) -> dict:
    document: dict[str, Any] = {"model": camera.model}
    if camera.serial is not None:
        document["serial"] = camera.serial
    document.update(
        pixel_format=camera.pixel_format,
        cfa=camera.cfa,
        black_level=_plain(camera.black_level),
        white_level=_plain(camera.white_level),
        responsivity=None if camera.responsivity is None else {k: v.tolist() for k, v in camera.responsivity.items()},
    )
    document.update(camera.extra)
    return document


def _frame_json(frame: SequenceFrame) -> dict:
    document = {
        "file": frame.file,
        "role": frame.role,
        "led_levels": list(frame.led_levels),
        "exposure_us": _plain(frame.exposure_us),
        "gain": frame.gain,
    }
    if frame.digest is not None:
        document.update(sha256=frame.digest.sha256, file_bytes=frame.digest.file_bytes)
    if frame.time_utc is not None:
        document[TIME_UTC_KEY] = frame.time_utc
    document.update(frame.extra)
    return document


def _led_json(led: SequenceLed) -> dict:
    document: dict = {"name": led.name, "spd": led.spd.tolist()}
    if led.peak_nm is not None:
        document[PEAK_NM_KEY] = led.peak_nm
    return {**document, **led.extra}


def _document(sequence: Sequence) -> dict:
    return {
        "format": SEQUENCE_FORMAT,
        "version": SEQUENCE_VERSION,
        "complete": sequence.complete,
        "wavelengths_nm": [_plain(float(w)) for w in sequence.wavelengths_nm],
        "spectral_unit": sequence.spectral_unit,
        "camera": _camera_json(sequence.camera),
        "leds": [_led_json(led) for led in sequence.leds],
        "frames": [_frame_json(frame) for frame in sequence.frames],
        **sequence.extra,
    }


def _fsync_directory(directory: Path) -> None:
    # Makes the rename itself durable (power loss); harmless where directories cannot be opened.
    with contextlib.suppress(OSError):
        handle = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(handle)
        finally:
            os.close(handle)


def _json_text(path: Path, document: dict) -> str:
    try:
        return json.dumps(document, indent=1, allow_nan=False) + "\n"
    except (TypeError, ValueError, RecursionError) as err:
        raise RecordingError(f"{path}: cannot be written ({err}); expected JSON-compatible extra values") from err


def _replace_json(path: Path, document: dict | str) -> None:
    text = document if isinstance(document, str) else _json_text(path, document)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.fchmod(handle, default_file_mode())  # mkstemp's 0600 would keep other lab users out
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise
    _fsync_directory(path.parent)


def as_recorded(pixels: np.ndarray, cfa: str | None) -> np.ndarray:
    """A frame as a camera gave it, as :meth:`Sequence.load_frame` returns it once written.

    A (H, W, 1) frame is read back as (H, W); a mono camera's (H, W) frame without a CFA as three
    identical channels (:func:`mono_as_rgb`); anything else as it is. Frames kept in memory (a live
    run, a replay) go through it, so the estimate sees the same arrays whichever way it is fed.
    """
    if pixels.ndim == 3 and pixels.shape[2] == 1:
        return pixels[:, :, 0]
    return mono_as_rgb(pixels) if pixels.ndim == 2 and cfa is None else pixels


def mono_as_rgb(pixels: np.ndarray) -> np.ndarray:
    """A mono frame (H, W) as (H, W, 3) with its value in every channel; other shapes unchanged.

    Format v1 (docs/architecture.md §6) stores three channels, or one channel only for a raw mosaic with
    ``camera.cfa`` set, and ``camera.responsivity`` holds R, G and B: a mono camera's frames are
    recorded as three identical channels and the sequence's ``camera.extra["channels"]`` says so.
    ``np.stack`` writes the copy faster than ``np.repeat`` (docs/architecture.md §10).

    Examples
    --------
    >>> mono_as_rgb(np.arange(4, dtype=np.uint16).reshape(2, 2))[1]
    array([[2, 2, 2],
           [3, 3, 3]], dtype=uint16)
    """
    return np.stack((pixels, pixels, pixels), axis=-1) if pixels.ndim == 2 else pixels


_LATEST_WRITER: list[SequenceWriter] = []
"""This process's latest :class:`SequenceWriter` (at most one): its folder and its finished flag say what it left."""


def latest_sequence_written() -> tuple[Path, bool] | None:
    """The folder of the sequence this process wrote last and whether it is complete (None: none written).

    What a command stopped by Ctrl-C or SIGTERM reports: a sequence that finished before the signal
    stays complete, one cut short is marked incomplete.
    """
    if not _LATEST_WRITER:
        return None
    writer = _LATEST_WRITER[0]
    return writer._directory, writer._finished


def forget_latest_sequence() -> None:
    """Start afresh (each command run in-process does): :func:`latest_sequence_written` returns None until a
    writer is made."""
    _LATEST_WRITER.clear()


class SequenceWriter:
    """Write a sequence frame by frame, so that a crash at any point leaves a readable sequence.

    ``sequence.json`` is written (``complete: false``) when the writer is created; each
    :meth:`add_frame` writes the frame file, then replaces ``sequence.json`` atomically;
    :meth:`finish` (or leaving the ``with`` block normally) sets ``complete: true``. Leaving the
    ``with`` block through an exception keeps ``complete: false`` and every frame written so far.

    Parameters
    ----------
    directory
        The sequence directory; created if needed. It must not already hold a sequence.
    wavelengths_nm
        The uniform wavelength grid, shape (n_wavelengths,).
    spectral_unit
        ``"energy"`` or ``"photons"``.
    camera
        The camera description.
    leds
        The LED channels.
    extra
        Extra top-level keys to store.
    mono
        The camera is monochrome: its (H, W) frames (``camera.cfa`` null) are recorded as three
        identical channels (:func:`mono_as_rgb`), since format v1 holds RGB or raw mosaics. The
        copy is made here, on the writer's side, so the capture path handles one plane.

    Raises
    ------
    RecordingError
        If the header is invalid (same checks as :func:`read_sequence`) or the directory already
        holds a sequence; :class:`~acquisition.errors.FolderInUseError` if another process is
        writing there (the directory is claimed for the writer's life, :mod:`acquisition.sequence.folder_claim`;
        temporary files a killed writer left are removed).

    Examples
    --------
    >>> with SequenceWriter(out, wavelengths_nm=grid, spectral_unit="energy",
    ...                     camera=camera, leds=leds) as writer:  # doctest: +SKIP
    ...     writer.add_frame(ambient_pixels, "ambient", (0.0,) * len(leds), exposure_us=10000)
    """

    def __init__(
        self,
        directory: str | os.PathLike,
        *,
        wavelengths_nm: Iterable[float] | np.ndarray,
        spectral_unit: Literal["energy", "photons"],
        camera: SequenceCamera,
        leds: Iterable[SequenceLed],
        extra: Mapping | None = None,
        mono: bool = False,
    ) -> None:
        self._directory = Path(directory)
        self._mono = bool(mono)
        if self._mono and camera.cfa is None and "channels" not in camera.extra:
            # Say so in the file (format v1, §6): a reader takes the three identical channels as one plane.
            camera = replace(camera, extra={**camera.extra, "channels": "mono replicated to R, G, B"})
        self._path = self._directory / SEQUENCE_FILE
        self._claim: FolderClaim | None = None
        self._sequence = Sequence(
            self._directory,
            False,
            np.asarray(list(wavelengths_nm), dtype=float),
            spectral_unit,
            camera,
            tuple(leds),
            (),
            dict(extra or {}),
        )
        self._shape: tuple[int, ...] | None = None
        self._first_file: str | None = None
        self._finished = False
        # Validate through the reader's own parser so a writer can never produce what the reader refuses.
        _parse_document(self._path, self._directory, _document(self._sequence), check_files=False)
        # The folder is claimed before it is checked: two writers started together cannot both find
        # it empty (a check-then-act race that left one's sequence.json over the other's frames).
        self._claim = claim_folder(self._directory, "msflash sequence writer")
        try:
            if self._path.exists():
                raise RecordingError(
                    f"{self._path}: already exists; expected a new or empty directory for the sequence"
                )
            self._claim.clean_stale_temporaries(FRAMES_DIR)
            frames_dir = self._directory / FRAMES_DIR
            if frames_dir.is_dir() and any(frames_dir.iterdir()):
                # Frame files are named by index: they would be overwritten without a word.
                raise RecordingError(
                    f"{frames_dir}: holds files but there is no {SEQUENCE_FILE}; expected a new or "
                    "empty directory for the sequence (move those files away first)"
                )
            _replace_json(self._path, _document(self._sequence))
        except BaseException:
            self._release()
            raise
        _LATEST_WRITER[:] = [self]

    def _release(self) -> None:
        if self._claim is not None:
            self._claim.release()

    @property
    def sequence(self) -> Sequence:
        """What has been written so far."""
        return self._sequence

    @property
    def path(self) -> Path:
        """The ``sequence.json`` being written."""
        return self._path

    def add_frame(
        self,
        pixels: np.ndarray,
        role: FrameRole,
        led_levels: Iterable[float],
        exposure_us: float,
        gain: float = 1.0,
        extra: Mapping | None = None,
        *,
        time_utc: str | None = None,
        stamp_time: bool = True,
    ) -> SequenceFrame:
        """Write one frame file, then list it in ``sequence.json``.

        Parameters
        ----------
        pixels
            (H, W) for a raw mosaic (``camera.cfa`` set) or (H, W, 3) for RGB; integer counts
            become ``frames/NNN-<role>.tiff`` (16-bit), floats ``frames/NNN-<role>.exr``. A
            writer for a ``mono`` camera also takes (H, W) frames without ``camera.cfa`` and
            records them as three identical channels.
        role, led_levels, exposure_us, gain
            As in :class:`SequenceFrame`; validated as :func:`read_sequence` does.
        extra
            Extra keys for this frame's entry (``frame_id``, ``timestamp_ns``, ``time_utc``…).
        time_utc, stamp_time
            The frame's ``time_utc`` (:func:`utc_now_text`'s form); None records now, the time the frame
            reached the writer (:class:`~acquisition.sequence.async_writer.AsyncSequenceWriter` passes the
            time the frame was handed to it) — or no time with ``stamp_time=False`` (a copy of a frame
            recorded without one, :func:`write_sequence`).

        Returns
        -------
        SequenceFrame
            The entry added.

        Raises
        ------
        RecordingError
            If the writer is finished, the frame fields are invalid, or the pixels' channel count
            or size does not match the camera and the earlier frames.
        """
        if self._finished:
            raise RecordingError(f"{self._path}: the sequence is finished; expected add_frame before finish()")
        index = len(self._sequence.frames)
        pixels = np.asarray(pixels)
        if pixels.ndim == 3 and pixels.shape[2] == 1:
            pixels = pixels[:, :, 0]
        if self._mono and pixels.ndim == 2 and self._sequence.camera.cfa is None:
            pixels = mono_as_rgb(pixels)
        # An invalid role is refused by _parse_frame below; it must not shape a path before that.
        name_role = role if role in FRAME_ROLES else "frame"
        relative = f"{FRAMES_DIR}/{index:03d}-{name_role}{image_suffix(pixels)}"
        where = f"{self._path}: frames[{index}]"
        clash = sorted(set(extra or {}) & set(_FRAME_KEYS))
        if clash:
            raise RecordingError(f"{where}: extra keys {clash} clash with format keys; expected only unknown keys")
        entry = {
            "file": relative,
            "role": role,
            "led_levels": [_as_float(v) for v in led_levels],
            "exposure_us": _as_float(exposure_us),
            "gain": _as_float(gain),
            **({TIME_UTC_KEY: time_utc or utc_now_text()} if time_utc is not None or stamp_time else {}),
            **dict(extra or {}),
        }
        frame = _parse_frame(self._path, self._directory, index, entry, len(self._sequence.leds), must_exist=False)
        self._check_pixels(where, relative, pixels)
        updated = _replace(self._sequence, frames=(*self._sequence.frames, frame))
        # Serialised before the frame file is written, so unstorable extras fail with nothing on disk.
        _json_text(self._path, _document(updated))
        digest = write_image_digest(
            self._directory / relative,
            pixels,
            {
                "msflash:role": frame.role,
                "msflash:index": index,
                "msflash:led_levels": list(frame.led_levels),
                "msflash:exposure_us": frame.exposure_us,
                "msflash:gain": frame.gain,
                "msflash:led_names": [led.name for led in self._sequence.leds],
            },
        )
        # The digest of the bytes written, recorded with the frame (read back and checked on loading).
        frame = _replace_frame(frame, digest=digest)
        updated = _replace(self._sequence, frames=(*self._sequence.frames, frame))
        _replace_json(self._path, _json_text(self._path, _document(updated)))
        self._sequence = updated
        return frame

    def _check_pixels(self, where: str, relative: str, pixels: np.ndarray) -> None:
        cfa = self._sequence.camera.cfa
        if pixels.ndim not in (2, 3) or (pixels.ndim == 3 and pixels.shape[2] != 3):
            raise RecordingError(f"{where}: pixels have shape {pixels.shape}; expected (H, W) or (H, W, 3)")
        channels = 1 if pixels.ndim == 2 else 3
        if cfa is not None and channels != 1:
            raise RecordingError(
                f"{where}: pixels have 3 channels but camera.cfa is '{cfa}'; expected (H, W) raw mosaic"
            )
        if cfa is None and channels != 3:
            raise RecordingError(
                f"{where}: pixels have 1 channel but camera.cfa is null; expected (H, W, 3) RGB "
                "(or a writer made with mono=True for a monochrome camera)"
            )
        if self._shape is None:
            self._shape, self._first_file = pixels.shape, relative
        elif pixels.shape != self._shape:
            raise RecordingError(
                f"{where}: pixels for '{relative}' have shape {pixels.shape} but '{self._first_file}' has "
                f"{self._shape}; expected one size for all frames"
            )

    def finish(self) -> Sequence:
        """Mark the sequence complete and return it as :func:`read_sequence` reads it.

        Raises
        ------
        RecordingError
            If the sequence has no ambient frame (it then stays incomplete).
        """
        if not self._finished:
            if not self._sequence.indices("ambient"):
                raise RecordingError(
                    f"{self._path}: frames has no frame with role 'ambient'; expected at least one before finish()"
                )
            completed = _replace(self._sequence, complete=True)
            _replace_json(self._path, _document(completed))
            self._sequence = completed
            self._finished = True
            self._release()
        return read_sequence(self._directory)

    def __enter__(self) -> SequenceWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        # On an exception the sequence on disk is already consistent (complete: false, every
        # written frame listed), so nothing is written: the original error propagates untouched.
        try:
            if exc_type is None:
                self.finish()
        finally:
            self._release()


def _as_float(value: Any) -> Any:
    # Numpy scalars become plain floats so the reader's JSON type checks apply; anything else is
    # passed through unchanged for those checks to refuse with the field named.
    return float(value) if isinstance(value, np.generic) and np.issubdtype(type(value), np.number) else value


def _replace_frame(frame: SequenceFrame, **changes: Any) -> SequenceFrame:
    values = {f.name: getattr(frame, f.name) for f in fields(frame)}
    values.update(changes)
    return SequenceFrame(**values)


def _replace(sequence: Sequence, **changes: Any) -> Sequence:
    values = {f.name: getattr(sequence, f.name) for f in fields(sequence)}
    values.update(changes)
    return Sequence(**values)


def write_sequence(directory: str | os.PathLike, sequence: Sequence, frames: Iterable[np.ndarray]) -> Sequence:
    """Write ``sequence``'s header and frame entries with the given pixels into a new directory.

    Frame files are renamed to the writer's scheme (``frames/NNN-<role>.tiff|exr``); everything
    else, unknown keys included, is kept. The result is complete if ``sequence`` is.

    Parameters
    ----------
    directory
        The new sequence directory.
    sequence
        The header and frame entries to copy (for instance from :func:`read_sequence`).
    frames
        One pixel array per entry of ``sequence.frames``, in order.

    Returns
    -------
    Sequence
        The written sequence, as :func:`read_sequence` reads it.
    """
    writer = SequenceWriter(
        directory,
        wavelengths_nm=sequence.wavelengths_nm,
        spectral_unit=sequence.spectral_unit,
        camera=sequence.camera,
        leds=sequence.leds,
        extra=sequence.extra,
    )
    pixels_list = list(frames)
    if len(pixels_list) != len(sequence.frames):
        raise RecordingError(
            f"{writer.path}: {len(pixels_list)} pixel arrays for {len(sequence.frames)} frames; expected one per frame"
        )
    for frame, pixels in zip(sequence.frames, pixels_list, strict=True):
        writer.add_frame(
            pixels,
            frame.role,
            frame.led_levels,
            frame.exposure_us,
            frame.gain,
            frame.extra,
            time_utc=frame.time_utc,
            stamp_time=False,
        )
    return writer.finish() if sequence.complete else read_sequence(directory)
