"""Write a sequence from a background thread so the capture loop never waits for the disk.

:class:`AsyncSequenceWriter` wraps a :class:`~acquisition.sequence.writer.SequenceWriter` (the
format and its crash-safety contract are unchanged: each frame file is written, then
``sequence.json`` replaced atomically, in capture order). :meth:`AsyncSequenceWriter.add_frame`
only queues the frame and returns at once with the entry it *will* have; one writer thread
calls ``SequenceWriter.add_frame`` for each queued frame in order.

Guarantees
----------
- **Order**: frames reach the disk in the order they were added (one thread, a FIFO).
- **Back-pressure, never loss**: the queue is bounded (``max_queued``); when the disk falls
  behind, ``add_frame`` blocks until there is room rather than dropping a frame.
- **Drain on every exit a Python process survives**: leaving the ``with`` block — normally,
  through an exception, or through ``KeyboardInterrupt`` / ``SystemExit`` (Ctrl-C, SIGTERM via
  :func:`acquisition.signals.sigterm_as_exit`) — first writes every queued frame, then re-raises
  the original exception. So ``sequence.json`` lists every frame captured (``complete: false``
  after an error).
- **SIGKILL / power loss**: what is on disk is still a readable sequence (the wrapped writer's
  guarantee), but the frames still in the queue — at most ``max_queued`` plus the one being
  written — are lost.
- **Write errors**: the first error of the writer thread is raised by the next ``add_frame``,
  :meth:`flush`, :meth:`finish` or by leaving the ``with`` block normally; frames after it are not
  written (the sequence stays consistent and incomplete). The disk failing (full, gone, I/O error:
  an ``OSError``) is :class:`~acquisition.errors.OutputWriteError`, a runtime failure naming the
  frame, the cause and what is saved; a frame the format refuses stays a ``RecordingError``.

Pixels are not copied: the caller must not modify an array after handing it over (camera frames,
:class:`~acquisition.devices.camera.RawFrame`, are read-only).
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Iterable, Mapping
from pathlib import Path
from types import TracebackType

import numpy as np

from msflash.acquisition.errors import OutputWriteError, RecordingError
from msflash.acquisition.sequence.format import (
    FRAME_ROLES,
    FRAMES_DIR,
    FrameRole,
    Sequence,
    SequenceFrame,
    utc_now_text,
)
from msflash.acquisition.sequence.image_files import image_suffix
from msflash.acquisition.sequence.writer import SequenceWriter

log = logging.getLogger(__name__)

DEFAULT_MAX_QUEUED = 16
"""Frames that may wait for the disk before ``add_frame`` blocks (a sequence is ~10 frames)."""

_STOP = object()


class AsyncSequenceWriter:
    """A :class:`SequenceWriter` (already created) fed through a queue of at most ``max_queued`` frames and a
    writer thread."""

    def __init__(self, writer: SequenceWriter, max_queued: int = DEFAULT_MAX_QUEUED) -> None:
        if max_queued < 1:
            raise ValueError(f"AsyncSequenceWriter: max_queued {max_queued}; expected at least 1")
        self._writer = writer
        self._queue: queue.Queue = queue.Queue(maxsize=max_queued)
        self._error: BaseException | None = None
        self._failed_file: str | None = None  # the frame file whose writing failed
        self._added = len(writer.sequence.frames)
        self._written = self._added
        self._closed = False
        self._running = threading.Event()  # cleared by pause(): the thread waits before its next frame
        self._running.set()
        self._max_queued = max_queued
        self._held: list[tuple] = []  # frames added while paused, not yet handed to the thread
        self._held_lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name=f"sequence-writer {writer.path.parent}", daemon=False)
        self._thread.start()

    # -- what SequenceWriter offers ----------------------------------------------------------
    @property
    def path(self) -> Path:
        """The ``sequence.json`` being written."""
        return self._writer.path

    @property
    def sequence(self) -> Sequence:
        """What is on disk so far (frames still queued are not listed yet; :meth:`flush` first)."""
        return self._writer.sequence

    @property
    def queued(self) -> int:
        """Frames handed over but not yet on disk."""
        return self._added - self._written

    def add_frame(
        self,
        pixels: np.ndarray,
        role: FrameRole,
        led_levels: Iterable[float],
        exposure_us: float,
        gain: float = 1.0,
        extra: Mapping | None = None,
    ) -> SequenceFrame:
        """Queue one frame for :meth:`SequenceWriter.add_frame`; returns the entry it will be written as.

        The frame's ``time_utc`` is stamped here, when it is handed over.

        Blocks only while the queue is full (back-pressure). Raises the writer thread's error, if any.
        The entry returned has no ``digest`` yet: the file's SHA-256 is taken when the thread writes
        it (:attr:`sequence`, after :meth:`flush`, has it).
        """
        self._raise_error()
        if self._closed:
            raise RecordingError(f"{self.path}: the asynchronous writer is closed; expected add_frame before close()")
        pixels = np.asarray(pixels)
        extra = dict(extra or {})
        handed_at = utc_now_text()  # the frame's time_utc: when it was handed over, not when the disk caught up
        name_role = role if role in FRAME_ROLES else "frame"
        entry = SequenceFrame(
            f"{FRAMES_DIR}/{self._added:03d}-{name_role}{image_suffix(pixels)}",
            role,
            tuple(led_levels),
            exposure_us,
            gain,
            extra,
            time_utc=handed_at,
        )
        self._added += 1
        item = (pixels, role, entry.led_levels, exposure_us, gain, extra, entry.file, handed_at)
        with self._held_lock:
            # Paused: keep the frame here rather than wake the writer thread only for it to wait
            # (each wake-up takes the GIL from the latency-critical capture thread).
            paused = not self._running.is_set()
            if paused and len(self._held) + self._queue.qsize() < self._max_queued:
                self._held.append(item)
                return entry
        if paused:
            self.resume()  # back-pressure: a paused writer must make room (held frames go first)
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.resume()
            self._queue.put(item)
        return entry

    def pause(self) -> None:
        """Hold the writer thread before its next frame (the frame being written is finished).

        For a latency-critical moment of the capture loop (the flash decision and trigger): frames
        keep being accepted (nothing is dropped; ``add_frame`` blocks only when ``max_queued`` are
        waiting) and are written, in order, after :meth:`resume`. Frames added while paused are
        held back from the thread, so adding one does not wake it. :meth:`close`, :meth:`flush`
        and leaving the ``with`` block resume first.
        """
        self._running.clear()

    def resume(self) -> None:
        """Let the writer thread go on after :meth:`pause` (frames added meanwhile follow, in order); idempotent."""
        with self._held_lock:
            self._running.set()
            for item in self._held:  # in order, after what was queued before the pause
                self._queue.put(item)  # never waits long: held + queued stay within max_queued
            self._held.clear()

    def flush(self) -> Sequence:
        """Wait until every queued frame is on disk; raises the writer thread's error, if any."""
        self.resume()
        self._queue.join()
        self._raise_error()
        return self._writer.sequence

    def finish(self) -> Sequence:
        """Write every queued frame, stop the thread, then mark the sequence complete."""
        self.close()
        self._raise_error()
        return self._writer.finish()

    def close(self) -> None:
        """Write every queued frame and stop the writer thread; idempotent. Never raises the thread's error."""
        if self._closed:
            return
        self._closed = True
        self.resume()
        self._queue.put(_STOP)
        while self._thread.is_alive():
            try:
                self._thread.join()
            except KeyboardInterrupt:  # a second Ctrl-C while draining: keep draining, then re-raise
                self._thread.join()
                raise

    def __enter__(self) -> AsyncSequenceWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()  # drain first, whatever happened: nothing captured is lost
        if exc_type is None:
            self._raise_error()
        elif self._error is not None and not _caused_by(exc, self._error):
            log.error("%s: writing failed as well: %s", self.path, self._error)

    # -- the writer thread -------------------------------------------------------------------
    def _raise_error(self) -> None:
        if self._error is None:
            return
        error = self._error
        if not isinstance(error, OSError):
            raise RecordingError(f"{self.path}: writing a frame failed: {error}") from error
        saved = len(self._writer.sequence.frames)
        lost = self._added - saved - 1
        cause = error.strerror or str(error)
        where = f" ({error.filename})" if error.filename else ""
        raise OutputWriteError(
            f"{self.path.parent}: writing {self._failed_file} failed: {cause}{where}; expected a writable "
            f"disk with room for the frames. {saved} frame(s) saved and readable (complete: false)"
            + (f"; {lost} later frame(s) captured but not written" if lost > 0 else "")
        ) from error

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            self._running.wait()
            try:
                if item is _STOP:
                    return
                if self._error is None:  # after an error nothing more is written: the sequence stays consistent
                    pixels, role, levels, exposure_us, gain, extra, file, handed_at = item
                    self._failed_file = file
                    self._writer.add_frame(pixels, role, levels, exposure_us, gain, extra=extra, time_utc=handed_at)
            except BaseException as err:  # noqa: BLE001 - handed to the capture thread, which reports it
                self._error = err
                log.debug("%s: writing a frame failed: %s", self.path, err)
            finally:
                if item is not _STOP:
                    self._written += 1
                self._queue.task_done()


def _caused_by(error: BaseException | None, cause: BaseException) -> bool:
    """Whether ``error`` is ``cause`` or was raised from it (the writer's own error coming back)."""
    while error is not None:
        if error is cause:
            return True
        error = error.__cause__
    return False
