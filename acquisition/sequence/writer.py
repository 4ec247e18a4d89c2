"""Writing sequence format v1: :class:`SequenceWriter` frame by frame, crash-safe; :func:`write_sequence` at once.

The writer writes ``sequence.json`` with ``complete: false`` before any frame, writes each frame
file atomically, then replaces ``sequence.json`` atomically (temporary file, fsync,
``os.replace``). So at every instant the directory holds a readable sequence listing only frames
that are fully on disk; a crash (exception, Ctrl-C, SIGKILL) leaves ``complete: false``. What it
writes is validated by the reader's own parser (:mod:`acquisition.sequence.reader`).
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterable, Mapping
from dataclasses import fields, replace
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.folder_claim import FolderClaim, claim_folder
from msflash.acquisition.sequence.format import (
    FRAME_KEYS,
    FRAME_ROLES,
    FRAMES_DIR,
    PEAK_NM_KEY,
    SEQUENCE_FILE,
    SEQUENCE_FORMAT,
    SEQUENCE_VERSION,
    TIME_UTC_KEY,
    FrameRole,
    Sequence,
    SequenceCamera,
    SequenceFrame,
    SequenceLed,
    utc_now_text,
)
from msflash.acquisition.sequence.frame_digest import FileDigest
from msflash.acquisition.sequence.image_files import (
    image_suffix,
    write_image_digest,
)
from msflash.acquisition.sequence.reader import parse_document, parse_frame, read_sequence
from msflash.calibration.file_modes import write_whole


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
    write_whole(path, document if isinstance(document, str) else _json_text(path, document))
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
    return writer._directory, writer._finished or _complete_on_disk(writer._path)


def _complete_on_disk(path: Path) -> bool:
    """Whether ``sequence.json`` at ``path`` says ``complete: true``. A signal arriving inside :meth:`SequenceWriter.finish`
    after the file was replaced but before the writer noted it left the flag behind the disk: the stop line then
    said "marked incomplete" of a complete sequence."""
    try:
        return json.loads(path.read_text(encoding="utf-8")).get("complete") is True
    except (OSError, ValueError, AttributeError):
        return False


def forget_latest_sequence() -> None:
    """Start afresh (each command run in-process does): :func:`latest_sequence_written` returns None until a
    writer is made."""
    _LATEST_WRITER.clear()


class SequenceWriter:
    """Write a sequence frame by frame, so that a crash at any point leaves a readable sequence.

    ``sequence.json`` is written (``complete: false``) when the writer is created; each
    :meth:`add_frame` writes the frame file, then replaces ``sequence.json`` atomically;
    :meth:`finish` (or leaving the ``with`` block normally) sets ``complete: true``. Leaving the
    ``with`` block through an exception keeps ``complete: false`` and every frame written so far; a
    sequence left without any frame is removed (with the folders the writer made, when empty).

    Parameters
    ----------
    directory
        The sequence directory; created if needed. It must not already hold a sequence.
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
        self._made_directory = not os.path.lexists(self._directory)
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
        parse_document(self._path, self._directory, _document(self._sequence), check_files=False)
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
        time_utc, stamp_time
            The frame's ``time_utc`` (:func:`utc_now_text`'s form); None records now, the time the frame
            reached the writer (:class:`~acquisition.sequence.async_writer.AsyncSequenceWriter` passes the
            time the frame was handed to it) — or no time with ``stamp_time=False`` (a copy of a frame
            recorded without one, :func:`write_sequence`).

        Raises
        ------
        RecordingError
            If the writer is finished, the frame fields are invalid, or the pixels' channel count
            or size does not match the camera and the earlier frames.
        """
        if self._finished:
            raise RecordingError(f"{self._path}: the sequence is finished; expected add_frame before finish()")
        index = len(self._sequence.frames)
        pixels = self._as_stored(pixels)
        # An invalid role is refused by parse_frame below; it must not shape a path before that.
        name_role = role if role in FRAME_ROLES else "frame"
        relative = f"{FRAMES_DIR}/{index:03d}-{name_role}{image_suffix(pixels)}"
        where = f"{self._path}: frames[{index}]"
        clash = sorted(set(extra or {}) & set(FRAME_KEYS))
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
        frame = parse_frame(self._path, self._directory, index, entry, len(self._sequence.leds), must_exist=False)
        self._check_pixels(where, relative, pixels)
        # Serialised before the frame file is written, so unstorable extras fail with nothing on disk.
        _json_text(self._path, _document(_replace(self._sequence, frames=(*self._sequence.frames, frame))))
        # The digest of the bytes written, recorded with the frame (read back and checked on loading).
        frame = _replace_frame(frame, digest=self._write_frame_file(relative, pixels, frame, index))
        updated = _replace(self._sequence, frames=(*self._sequence.frames, frame))
        _replace_json(self._path, _json_text(self._path, _document(updated)))
        self._sequence = updated
        return frame

    def _as_stored(self, pixels: np.ndarray) -> np.ndarray:
        """The pixels as they are written: (H, W, 1) as (H, W); a mono camera's (H, W) as three channels."""
        pixels = np.asarray(pixels)
        if pixels.ndim == 3 and pixels.shape[2] == 1:
            pixels = pixels[:, :, 0]
        if self._mono and pixels.ndim == 2 and self._sequence.camera.cfa is None:
            pixels = mono_as_rgb(pixels)
        return pixels

    def _write_frame_file(self, relative: str, pixels: np.ndarray, frame: SequenceFrame, index: int) -> FileDigest:
        """The frame file, with what it says of itself (:mod:`acquisition.sequence.frame_binding`); its digest."""
        return write_image_digest(
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
            if exc_type is not None and not self._sequence.frames:
                self._discard_empty()

    def _discard_empty(self) -> None:
        """Remove a sequence that never got a frame (a replay refused at its plan, a camera failing at step 0, Ctrl-C
        before the first frame): its ``complete: false`` file with no frame kept nothing, yet made the ``--out`` it
        sat in "already hold a run" and said frames were kept. The folders it made go too, when empty."""
        with contextlib.suppress(OSError):
            self._path.unlink()
        for folder in (self._directory / FRAMES_DIR, *((self._directory,) if self._made_directory else ())):
            with contextlib.suppress(OSError):  # absent, or holding something that is not ours
                folder.rmdir()
        if _LATEST_WRITER and _LATEST_WRITER[0] is self:
            _LATEST_WRITER.clear()


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
    """Write ``sequence``'s header and frame entries with ``frames`` (one pixel array per entry, in order)
    into a new directory; return it as :func:`read_sequence` reads it.

    Frame files are renamed to the writer's scheme (``frames/NNN-<role>.tiff|exr``); everything
    else, unknown keys included, is kept. The result is complete if ``sequence`` is.
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
