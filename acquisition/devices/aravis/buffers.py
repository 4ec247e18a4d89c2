"""The stream's buffers: the pool (copying or zero-copy), a popped buffer as a context manager, what the pump hands over.

A buffer popped from the stream is taken with ``with pool.fetch(timeout_us) as popped:`` (the idea
of harvesters' ``with ia.fetch() as buffer``): it goes back into the stream when the block ends,
unless :meth:`PoppedBuffer.hand_out` gave its array to the caller as a frame (zero copy).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from msflash.acquisition.devices.aravis.gi_typelib import Aravis

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Good:
    pixels: np.ndarray
    frame_id: int
    timestamp_ns: int
    received_ns: int
    popped_ns: int


@dataclass(frozen=True)
class Bad:
    frame_id: int
    status: str


@dataclass(frozen=True)
class Failure:
    error: BaseException


CONTROL_LOST = object()

ZERO_COPY_PROTOCOLS = ("gige", "fake")
"""Transports whose streams can hand buffers out as frames. USB3 Vision keeps copying: Aravis's
asynchronous USB3 stream (0.8.26, ``arvuvstream.c``) sets up one set of USB transfers per buffer
*address*, pointing at that buffer's memory, and reuses it for any later buffer at the same
address, so a buffer replaced by a new one would be filled through the old one's pointer."""


def prefaulted(n_bytes: int) -> np.ndarray:
    """A new byte array with every page written once, so the first write by Aravis's receive
    thread takes no page fault (``np.zeros`` would map untouched zero pages)."""
    array = np.empty(n_bytes, dtype=np.uint8)
    array.fill(0)
    return array


class PoppedBuffer:
    """A buffer popped from the stream, inside ``with pool.fetch(…) as popped`` (:meth:`BufferPool.fetch`).

    It goes back into the stream when the block ends, whatever happened in it, unless
    :meth:`hand_out` gave its array to the caller as a frame (zero copy): then it is never pushed
    again and the pool pushes a replacement (:meth:`BufferPool.replace`).
    """

    def __init__(self, pool: BufferPool, buffer: Any, popped_ns: int) -> None:
        self.pool = pool
        self.buffer = buffer
        """The Aravis buffer."""
        self.popped_ns = popped_ns
        """When it was popped (host ``CLOCK_REALTIME`` ns)."""
        self.handed_out = False
        """Its array went to the caller: never pushed back."""

    def array(self) -> np.ndarray | None:
        """The array behind the buffer, or None when its memory is Aravis's (copy it out)."""
        return self.pool.array_of(self.buffer)

    def hand_out(self) -> None:
        """Give the buffer's array to the caller (call last: nothing after it may fail)."""
        self.pool.hand_out(self.buffer)
        self.handed_out = True


class BufferPool:
    """One Aravis stream with its buffers and, when frames are delivered without a copy, the numpy
    arrays whose memory those buffers use.

    A copying pool lets Aravis allocate each buffer; frames are copied out (:func:`decode_pixels`)
    and buffers are pushed back. A zero-copy pool builds every buffer over a pre-faulted array it
    allocates (``Aravis.Buffer.new(size, address)``); a complete frame is handed to the caller as a
    view of its array (:func:`view_pixels`) and its buffer is never pushed again: a replacement over
    a fresh array (a spare readied beforehand, else a new one) takes its place in the stream.

    Memory-safety invariant (zero-copy): Aravis's stream thread writes into the memory of every
    buffer the stream holds — queued for input, being filled, or complete and not yet popped —
    and never frees memory it did not allocate. So every array backing a buffer the stream may
    hold is referenced from ``_in_stream``: registered *before* its buffer is pushed, removed only
    by :meth:`hand_out` (its buffer popped, complete, and never to be pushed again) or by
    :meth:`release`, which first stops the stream's thread (joined) and deletes every buffer the
    stream still holds. A buffer popped and pushed back (incomplete, stale, refused) keeps its
    array registered throughout. Call :meth:`release` after acquisition stopped and after the thread
    popping the stream exited; if that thread cannot be stopped, :meth:`abandon` keeps the arrays
    for the life of the process instead. A pool dropped unreleased releases itself first.
    """

    def __init__(self, stream: Any, payload: int, zero_copy: bool) -> None:
        self.stream: Any = stream
        """The Aravis stream (None once released)."""
        self.payload = payload
        """Bytes per buffer."""
        self.zero_copy = zero_copy
        """Frames are views of the buffers' arrays (else copies)."""
        self._in_stream: dict[Any, np.ndarray] = {}  # Aravis.Buffer wrapper -> the array it writes into
        self._spares: list[tuple[Any, np.ndarray]] = []
        self._abandoned = False

    @property
    def counts(self) -> tuple[int, int]:
        """(arrays backing buffers in the stream, spare arrays ready to replace handed-out ones)."""
        return len(self._in_stream), len(self._spares)

    def _new_buffer(self) -> tuple[Any, np.ndarray]:
        array = prefaulted(self.payload)
        return Aravis.Buffer.new(self.payload, array.ctypes.data), array

    def _push(self, buffer: Any, array: np.ndarray) -> None:
        self._in_stream[buffer] = array  # referenced before Aravis can write into it
        self.stream.push_buffer(buffer)

    def fill(self, n_buffers: int) -> None:
        """Push ``n_buffers`` new buffers into the stream."""
        for _ in range(n_buffers):
            if self.zero_copy:
                self._push(*self._new_buffer())
            else:
                self.stream.push_buffer(Aravis.Buffer.new_allocate(self.payload))

    def reserve(self, n_spares: int) -> None:
        """Have at least ``n_spares`` spare buffers ready (zero-copy pools only)."""
        while self.zero_copy and len(self._spares) < n_spares:
            self._spares.append(self._new_buffer())

    @contextmanager
    def fetch(self, timeout_us: int) -> Iterator[PoppedBuffer | None]:
        """The next completed buffer within ``timeout_us`` (None if none), pushed back into the stream
        when the block ends unless handed out (:class:`PoppedBuffer`); its array, if any, stays
        registered in the pool meanwhile (the memory-safety invariant above)."""
        buffer = self.stream.timeout_pop_buffer(timeout_us)
        if buffer is None:
            yield None
            return
        popped = PoppedBuffer(self, buffer, time.time_ns())
        try:
            yield popped
        finally:
            if not popped.handed_out:
                self.stream.push_buffer(buffer)

    def array_of(self, buffer: Any) -> np.ndarray | None:
        """The array behind a popped buffer, or None when its memory is Aravis's (copy it out)."""
        return self._in_stream.get(buffer)

    def hand_out(self, buffer: Any) -> None:
        """Give up a popped buffer's array to the caller; the buffer must never be pushed again."""
        del self._in_stream[buffer]

    def replace(self) -> None:
        """Push a buffer in place of one handed out: a spare, else a new one allocated now."""
        buffer, array = self._spares.pop() if self._spares else self._new_buffer()
        self._push(buffer, array)

    def release(self) -> None:
        """Stop the stream's thread, delete the buffers it holds, drop the stream, then the arrays.

        Call it after acquisition stopped and the popping thread exited. The stream's thread is
        started again, with no buffer left to write into, so that Aravis's finalisation (which
        stops it) finds it running. Idempotent.
        """
        stream, self.stream = self.stream, None
        if stream is not None and self._in_stream:
            stream.stop_thread(True)  # joins the thread, then unrefs every buffer in its queues
            stream.start_thread()
        stream = None  # noqa: F841 - the stream goes before the arrays
        self._in_stream.clear()
        self._spares.clear()

    def abandon(self) -> None:
        """Keep the stream and the arrays for the life of the process: the stream may still write
        into them, and its buffers may still be pushed back by a thread that did not stop."""
        self._abandoned = True
        ABANDONED.append(self)
        self._spares.clear()

    def __del__(self) -> None:
        if self.stream is not None and self._in_stream and not self._abandoned:
            self.release()


@dataclass(frozen=True)
class SpareStream:
    """A stopped stream kept, with its buffers, for the next :meth:`AravisCamera.prepare`."""

    pool: BufferPool
    n_buffers: int
    layout: tuple[str, int, int]


ABANDONED: list[BufferPool] = []
"""Pools whose stream may still write into their arrays (its popping thread did not stop):
leaked on purpose, since freeing them could let Aravis write into freed memory."""
