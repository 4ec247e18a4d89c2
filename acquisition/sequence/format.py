"""Sequence format v1 (docs/architecture.md §6, docs/sequence-format.md): the data model.

:class:`Sequence`, :class:`SequenceCamera`, :class:`SequenceLed`, :class:`SequenceFrame` are frozen
dataclasses mirroring ``sequence.json``; unknown keys are kept in ``extra``. Pixels are loaded on
demand (:meth:`Sequence.load_frame`), checked against the digest written and the camera's levels.
Reading and validating a directory is :mod:`acquisition.sequence.reader`, writing one
:mod:`acquisition.sequence.writer`. Every problem is a :class:`~acquisition.errors.RecordingError`
whose message names the file and the field:
``".../sequence.json: frames[3].file 'frames/003-led.tiff' is missing"``.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.frame_binding import SelfDescription, binding_problem
from msflash.acquisition.sequence.frame_digest import FileDigest, check_frame_digest
from msflash.acquisition.sequence.frame_integrity import check_frame_levels
from msflash.acquisition.sequence.image_files import (
    ImageHeader,
    read_image_and_header,
    read_image_header,
)
from msflash.processing.led_wavelength import PEAK_METADATA_KEY, led_peaks_nm
from msflash.processing.spectra import Spectra, WavelengthGrid
from msflash.processing.synthesis import linearise

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

FrameRole = Literal["ambient", "led", "flash", "dark"]

TOP_KEYS = ("format", "version", "complete", "wavelengths_nm", "spectral_unit", "camera", "leds", "frames")
CAMERA_KEYS = ("model", "serial", "pixel_format", "cfa", "black_level", "white_level", "responsivity")
LED_KEYS = ("name", "spd", "peak_nm")
FRAME_KEYS = ("file", "role", "led_levels", "exposure_us", "gain", "sha256", "file_bytes", "time_utc")

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
def frozen_array(values: Any) -> np.ndarray:
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
            object.__setattr__(self, "responsivity", {str(k): frozen_array(v) for k, v in self.responsivity.items()})
        object.__setattr__(self, "black_level", float(self.black_level))
        object.__setattr__(self, "white_level", float(self.white_level))
        object.__setattr__(self, "extra", _check_extra("camera", self.extra, CAMERA_KEYS))


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
        object.__setattr__(self, "spd", frozen_array(self.spd))
        if self.peak_nm is not None:
            object.__setattr__(self, "peak_nm", float(self.peak_nm))
        object.__setattr__(self, "extra", _check_extra(f"led '{self.name}'", self.extra, LED_KEYS))


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
        object.__setattr__(self, "extra", _check_extra(f"frame '{self.file}'", self.extra, FRAME_KEYS))


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
        object.__setattr__(self, "wavelengths_nm", frozen_array(self.wavelengths_nm))
        object.__setattr__(self, "leds", tuple(self.leds))
        object.__setattr__(self, "frames", tuple(self.frames))
        object.__setattr__(self, "extra", _check_extra(SEQUENCE_FILE, self.extra, TOP_KEYS))

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
        frames without them pass; a ``RecordingError`` as :meth:`load_frame`'s). Reads the files' bytes, decodes
        nothing: a run checks what it wrote this way (its estimate and report come from the frames in memory).
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
            size or sample type differs from frame 0's (both files are named), or it holds values above white or
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
                if first.dtype != header.dtype:  # a frame re-encoded (as float, normalised to 1?) by another tool
                    raise RecordingError(
                        f"{where} holds {header.dtype} samples but frames[0].file '{self.frames[0].file}' holds "
                        f"{first.dtype}; expected one sample type for all frames (one camera, one encoding)"
                    )

        _, pixels = read_image_and_header(path, declared)
        if check_levels:
            check_frame_levels(pixels, self.camera.black_level, self.camera.white_level, self.frames[index].gain, where)
        return pixels

    def load_linear_frame(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``index`` in processing units, ``(raw − black) / (exposure_us · gain)``, and its
        saturated pixels (:func:`processing.synthesis.linearise`); refused as :meth:`load_frame` refuses."""
        frame = self.frames[index]
        return linearise(
            self.load_frame(index), self.camera.black_level, self.camera.white_level, frame.exposure_us, frame.gain
        )
