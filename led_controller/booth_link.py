"""The booth's serial link: a reader thread framing what arrives, the queues, the wire log, the exchange.

:class:`BoothLink` owns an open port. Its reader thread frames the incoming lines (resynchronising
after a lost line end) and puts replies and events into two separate queues; every byte is logged
in :meth:`BoothLink._wire` and nowhere else. :meth:`BoothLink._command` is one request and its
reply, asked once more where asking again cannot change what happens (:data:`IDEMPOTENT_COMMANDS`).
The commands built on it are ``booth_handshake.py``, ``booth_table.py`` and ``booth.py``.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import logging
import queue
import threading
import time
from pathlib import Path
from typing import Any

import serial

from msflash.led_controller import protocol
from msflash.led_controller.errors import BoothError, BoothProtocolError, BoothTimeoutError
from msflash.led_controller.protocol import BoothEvent, Command
from msflash.led_controller.serial_port import open_transcript

try:
    import termios

    _TERMIOS_ERRORS: tuple[type[Exception], ...] = (termios.error,)
except ImportError:  # not a POSIX host: pyserial raises no termios errors there
    _TERMIOS_ERRORS = ()

log = logging.getLogger(__name__)


class _LinkLost:
    """Queue item: the serial link failed (carries the cause)."""

    def __init__(self, error: BaseException) -> None:
        self.error = error


class _BootedMeanwhile(Exception):
    """The booth sent its boot banner while a request waited for its reply (the request went to its bootloader)."""


class _Garbled:
    """Queue item: a line that is not a valid frame (carries the protocol error)."""

    def __init__(self, error: BoothProtocolError) -> None:
        self.error = error


IDEMPOTENT_COMMANDS = frozenset(
    {
        Command.IDENTIFY,
        Command.STATUS,
        Command.COUNT,
        Command.PING,
        Command.SET,
        Command.OFF,
        Command.WATCHDOG,
        Command.PATTERN_CLEAR,
        Command.ROLL,
    }
)
"""Commands that leave the booth as one would, sent twice: sent again once after a damaged reply or
none. The others (NEXT, PADD, PSET, ARM, START, SERIAL …) are never resent: the booth may have acted on them,
and a frame-error reply (sequence 00) does not say which request it was for."""


class _Retryable(Exception):
    """A failed exchange :meth:`LedBooth._command` may send again (an idempotent command): the error to
    raise otherwise, and why."""

    def __init__(self, error: BoothError, why: str) -> None:
        super().__init__(why)
        self.error = error
        self.why = why


class BoothLink:
    """The link to one booth on an open ``port``, read by a thread (see :class:`~led_controller.booth.LedBooth`)."""

    def __init__(
        self,
        port: Any,
        *,
        timeout_s: float = 1.0,
        log_serial: str | Path | None = None,
        name: str | None = None,
    ) -> None:
        if not timeout_s > 0:
            raise ValueError(f"LedBooth: timeout_s {timeout_s!r} invalid; expected a positive number")
        self._port = port
        self._name = name or str(getattr(port, "name", None) or getattr(port, "portstr", "booth"))
        self.timeout_s = float(timeout_s)
        self._replies: queue.Queue[protocol.Frame | _Garbled | _LinkLost] = queue.Queue()
        self._events: collections.deque[BoothEvent | _Garbled | _LinkLost] = collections.deque()
        self._events_cv = threading.Condition()
        self._command_lock = threading.Lock()
        self._wire_lock = threading.Lock()
        self._seqs = itertools.cycle(range(1, 256))
        self._last_event_seq: int | None = None
        self._link_error: BaseException | None = None
        self._stop = threading.Event()
        self._closed = False
        self._boots = 0  # BOOT banners seen (the firmware started: a reset)
        self._transcript = open_transcript(log_serial, self._name, "booth")
        self._reader = threading.Thread(target=self._read_loop, name=f"booth-reader {self._name}", daemon=True)
        self._reader.start()

    def close(self) -> None:
        """Stop the reader thread and close the port (idempotent; does not switch LEDs off)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        with contextlib.suppress(Exception):
            self._port.cancel_read()
        self._reader.join(timeout=2.0)
        try:
            self._port.close()
        except (OSError, serial.SerialException) as err:
            log.warning("%s: closing the port failed: %s", self._name, err)
        if self._transcript is not None:
            self._transcript.close()

    def _command(
        self, command: str, *args: object, timeout_s: float | None = None, until_boot: bool = False
    ) -> tuple[protocol.Reply, bytes]:
        """One request and its reply, asked once more where asking again cannot change what happens.

        An idempotent command (:data:`IDEMPOTENT_COMMANDS`: the queries, SET, OFF, WDOG, PCLR, ROLL) is sent once
        more after a reply that arrived damaged (a flipped bit, a dropped byte), no reply at all, or a
        framing error the booth reports (sequence 00): sending it twice leaves the booth as once would.
        Other commands fail at once (the booth may have acted). Each retry is logged. ``until_boot``: give up (:class:`_BootedMeanwhile`) as soon as a ``BOOT``
        banner arrives, the request having gone to a bootloader that is now gone (never retried).
        """
        name = str(command)
        try:
            return self._exchange(name, *args, timeout_s=timeout_s, until_boot=until_boot)
        except _Retryable as first:
            if until_boot or name not in IDEMPOTENT_COMMANDS:
                raise first.error from first.error.__cause__
            log.warning("%s: %s once more after %s", self._name, name, first.why)
            try:
                return self._exchange(name, *args, timeout_s=timeout_s, until_boot=until_boot)
            except _Retryable as second:
                raise second.error from second.error.__cause__

    def _exchange(
        self, command: str, *args: object, timeout_s: float | None = None, until_boot: bool = False
    ) -> tuple[protocol.Reply, bytes]:
        """One request and its reply; :class:`_Retryable` wraps what :meth:`_command` may ask again."""
        timeout = self.timeout_s if timeout_s is None else timeout_s
        name = str(command)
        boots = self._boots
        with self._command_lock:
            if self._closed:
                raise BoothError(f"{self._name}: {name} on a closed booth; expected an open LedBooth")
            if self._link_error is not None:
                raise self._link_lost_error(name, self._link_error) from self._link_error
            self._drop_stale_replies()
            seq = next(self._seqs)
            self._send(protocol.encode_request(seq, name, *args), name, timeout)
            deadline = time.monotonic() + timeout
            while True:
                remaining = deadline - time.monotonic()
                try:
                    if remaining <= 0:
                        raise queue.Empty
                    item = self._replies.get(timeout=min(remaining, 0.05) if until_boot else remaining)
                except queue.Empty:
                    if until_boot and self._boots != boots:
                        raise _BootedMeanwhile from None
                    if remaining > 0.05 and until_boot:
                        continue
                    raise _Retryable(
                        BoothTimeoutError(
                            f"{self._name}: no reply to {name} within {timeout:g} s; expected "
                            f"'={seq:02X}:…'; check that the booth is powered and the port is right",
                            command=name,
                            timeout_s=timeout,
                        ),
                        f"no reply within {timeout:g} s",
                    ) from None
                if isinstance(item, _LinkLost):
                    raise self._link_lost_error(name, item.error) from item.error
                if isinstance(item, _Garbled):
                    err = item.error
                    garbled = BoothProtocolError(
                        f"{self._name}: bad reply to {name}: {err.raw[:80]!r}; expected "
                        f"{protocol.FRAME_FORM} (line noise? check the cable and baud rate)",
                        command=name,
                        expected=err.expected,
                        raw=err.raw,
                    )
                    garbled.__cause__ = err
                    raise _Retryable(garbled, f"a damaged reply {err.raw[:40]!r}")
                if item.seq == protocol.SEQ_FRAME_ERROR:
                    raise self._unread(name, seq, protocol.parse_reply(item, name, where=self._name), item.raw)
                if item.seq != seq:
                    # A late reply to an earlier command that timed out: not ours.
                    log.warning("%s: dropped stale reply %r while waiting for %s", self._name, item.raw, name)
                    continue
                reply = protocol.parse_reply(item, name, where=self._name)
                if not reply.ok:
                    if reply.code in protocol.FRAME_ERROR_CODES:
                        raise self._unread(name, seq, reply, item.raw)
                    raise BoothError(
                        f"{self._name}: booth refused {name} ({reply.code}: {reply.text}); expected 'OK {name}'"
                    )
                return reply, item.raw

    def _unread(self, name: str, seq: int, reply: protocol.Reply, raw: bytes) -> _Retryable:
        """The booth says it could not read the request (a framing error): nothing was done."""
        return _Retryable(
            BoothProtocolError(
                f"{self._name}: the booth could not read the {name} request "
                f"({reply.code} {reply.text}); expected a clean link (check the cable)",
                command=name,
                expected=f"'={seq:02X}:…'",
                raw=raw,
            ),
            f"the booth could not read it ({reply.code})",
        )

    def _drop_stale_replies(self, *, quietly: bool = False) -> None:
        """Empty the reply queue, but for a lost link (kept for the next request to report); logged unless ``quietly``."""
        while True:
            try:
                item = self._replies.get_nowait()
            except queue.Empty:
                return
            if isinstance(item, _LinkLost):
                self._replies.put(item)
                return
            if not quietly:
                raw = item.raw if isinstance(item, protocol.Frame) else item.error.raw
                log.warning("%s: dropped unclaimed reply %r", self._name, raw)

    def _send(self, frame: bytes, command: str, timeout: float) -> None:
        self._wire(">", frame)
        try:
            self._port.write(frame)
            self._port.flush()
        except serial.SerialTimeoutException as err:
            raise BoothTimeoutError(
                f"{self._name}: writing {command} blocked for {timeout:g} s; expected the booth to read its input",
                command=command,
                timeout_s=timeout,
            ) from err
        except (serial.SerialException, OSError, *_TERMIOS_ERRORS) as err:
            # termios.error: pyserial's flush (tcdrain) on a pty or USB port that was just hung up.
            self._link_error = err
            raise self._link_lost_error(command, err) from err

    def _link_lost_error(self, doing: str, cause: BaseException) -> BoothError:
        return BoothError(
            f"{self._name}: serial link lost during {doing} ({cause}); expected an open port; "
            "check the USB cable and the booth's power, then reopen"
        )

    def _wire(self, direction: str, data: bytes) -> None:
        """Log every byte on the wire (the one place where this happens) and record the transcript.

        ``direction`` is ``>`` for host to booth and ``<`` for booth to host; complete lines
        only, so the transcript reads back line by line.
        """
        log.debug("%s %s %r", self._name, direction, data)
        if self._transcript is None:
            return
        line = data.rstrip(b"\n").decode("ascii", errors="backslashreplace")
        mark = "!" if direction == "<" and line.startswith(protocol.MARK_EVENT) else direction
        with self._wire_lock:
            self._transcript.write(f"{mark} {line}\n")
            self._transcript.flush()

    def _read_loop(self) -> None:
        buffer = bytearray()
        discarding = False  # within an over-long line, already reported: dropped up to its terminator
        while not self._stop.is_set():
            try:
                waiting = self._port.in_waiting
                data = self._port.read(max(1, min(waiting, 4096)))
            except Exception as err:  # any failure of the transport means the link is gone
                if self._stop.is_set():
                    return
                log.error("%s: serial link lost: %s", self._name, err)
                self._link_error = err
                lost = _LinkLost(err)
                self._replies.put(lost)
                with self._events_cv:
                    self._events.append(lost)
                    self._events_cv.notify_all()
                return
            if not data:
                continue
            buffer += data
            while True:
                end = buffer.find(protocol.TERMINATOR)
                if discarding:
                    if end < 0:
                        buffer.clear()
                        break
                    del buffer[: end + 1]
                    discarding = False
                    continue
                if end < 0:
                    break
                line = bytes(buffer[:end])
                del buffer[: end + 1]
                if not line:
                    continue  # an empty line: the line end a booth sends before its boot banner
                self._wire("<", line + protocol.TERMINATOR)
                self._dispatch(line)
            if len(buffer) > protocol.MAX_LINE:
                # No frame is this long (docs/booth-protocol.md §2): one framing error for the line's
                # first MAX_LINE + 1 bytes, the rest dropped up to its terminator, never buffered.
                line = bytes(buffer[: protocol.MAX_LINE + 1])
                buffer.clear()
                discarding = True
                self._wire("<", line)
                self._dispatch(line)

    def _dispatch(self, line: bytes) -> None:
        try:
            frame = protocol.parse_frame(line, where=self._name)
        except BoothProtocolError as err:
            tail = _resynchronised(line, self._name)
            if tail is not None:  # a frame that lost its line end, then a whole frame: keep the whole one
                log.warning(
                    "%s: dropped a damaged frame %r (its line end was lost) before %r",
                    self._name,
                    line[: len(line) - len(tail)][:80],
                    tail[:40],
                )
                self._dispatch(tail)
                return
            if line.startswith(protocol.MARK_EVENT.encode()):
                self._push_event(_Garbled(err))
            else:
                self._replies.put(_Garbled(err))
            return
        if frame.mark == protocol.MARK_REPLY:
            self._replies.put(frame)
        elif frame.mark == protocol.MARK_EVENT:
            try:
                event = protocol.parse_event(frame, where=self._name)
            except BoothProtocolError as err:
                self._push_event(_Garbled(err))
                return
            self._check_event_seq(event)
            self._push_event(event)
        else:
            self._replies.put(
                _Garbled(
                    BoothProtocolError(
                        f"{self._name}: received a request frame {line[:80]!r}; expected replies and events "
                        "only (is echo on, or is another host on this port?)",
                        command=None,
                        expected="'=…' or '!…' frames",
                        raw=line,
                    )
                )
            )

    def _check_event_seq(self, event: BoothEvent) -> None:
        last = self._last_event_seq
        self._last_event_seq = event.seq
        if event.kind == protocol.Event.BOOT:
            self._boots += 1  # the firmware started: its event counter starts again
            return
        if last is None:
            return
        expected = last % 255 + 1
        if event.seq != expected:
            self._push_event(
                _Garbled(
                    BoothProtocolError(
                        f"{self._name}: event sequence jumped from {last} to {event.seq}; expected {expected} "
                        "(events were lost on the link)",
                        command=None,
                        expected=f"event seq {expected}",
                        raw=event.raw,
                    )
                )
            )

    def _push_event(self, item: BoothEvent | _Garbled) -> None:
        with self._events_cv:
            self._events.append(item)
            self._events_cv.notify_all()


def _resynchronised(line: bytes, where: str) -> bytes | None:
    """The whole frame at the end of a damaged ``line``, if one is there (a byte lost from a frame may be
    its line end: the next frame then follows it on the same line), else None."""
    marks = (protocol.MARK_REPLY.encode(), protocol.MARK_EVENT.encode())
    for start in range(1, len(line)):
        if line[start : start + 1] in marks:
            try:
                protocol.parse_frame(line[start:], where=where)
            except BoothProtocolError:
                continue
            return line[start:]
    return None
