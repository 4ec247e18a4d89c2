"""The booth emulator served on a real pseudo-terminal, behind a stock Arduino Mega's unkind link.

:class:`PtyBoothServer` runs a :class:`~led_controller.emulator.BoothEmulator` on a thread at the
board's end of a pty (:class:`~led_controller.usb_link.TwinPort`): a host's open resets the board
into its bootloader (which answers avrdude, :class:`~led_controller.stk500v2.Stk500v2Bootloader`),
replies wait for the USB chip's latency timer, and what the booth sends while no host listens is
lost. :func:`serve_on_pty` builds one.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Any

from msflash.led_controller.emulator import BoothEmulator
from msflash.led_controller.stk500v2 import Stk500v2Bootloader
from msflash.led_controller.usb_link import (
    BOOTLOADER_BYTE_HOLD_S,
    FTDI_LATENCY_S,
    MEGA_BOOTLOADER_S,
    Bootloader,
    HeldReplies,
    TwinPort,
)

log = logging.getLogger(__name__)


class PtyBoothServer:
    """A :class:`BoothEmulator` served on a pseudo-terminal (a thread on the master end).

    Open :attr:`port` (the slave path) with :meth:`LedBooth.open`. Use as a context manager
    or call :meth:`close`.

    The thread wakes for input, for the emulator's next timed action (:meth:`BoothEmulator.next_due_s`:
    booth-master steps, delayed replies, the watchdog) and otherwise every ``poll_s``. On the real
    clock every timed action is known in advance, so it polls only every ``idle_poll_s`` (for a
    ``close`` fault), so that an in-process emulator does not take the GIL from the capture loop it
    serves (docs/decisions/docstring-history.md). A test's manual clock moves on its own, so it is polled every
    ``poll_s``.

    The link is as unkind as a stock Arduino Mega's (``led_controller/usb_link.py``):

    - ``auto_reset`` (default on): a host opening the port (the first open while none holds it:
      inotify ``IN_OPEN`` on the slave node) resets the board. The LEDs go off at once, the bytes the
      host sends for ``bootloader_s`` of wall-clock time (and :data:`BOOTLOADER_BYTE_HOLD_S` after
      each of them) are swallowed by the bootloader, then the firmware boots: power-up state (the
      serial kept, as in EEPROM) and the boot banner, a line end and the ``BOOT`` event. Every re-open
      resets again. ``auto_reset=False`` is a board with auto-reset disabled (10 µF RESET–GND or the
      ``RESET-EN`` jumper cut): it boots once, when the server starts.
    - ``latency_s`` (default 16 ms, an FTDI chip's latency timer): what the booth sends reaches the
      host in full packets at once and otherwise on the next tick of that timer (0: at once).
    - What the booth sends while no host holds the port open is lost, as a real USB-serial chip's
      (the power-up banner of a board nobody listens to), and a host's close drops what it did not read.
    """

    def __init__(
        self,
        emulator: BoothEmulator,
        *,
        poll_s: float = 0.002,
        idle_poll_s: float = 0.05,
        auto_reset: bool = True,
        bootloader_s: float = MEGA_BOOTLOADER_S,
        latency_s: float = FTDI_LATENCY_S,
    ) -> None:
        if not (0 <= bootloader_s < math.inf):
            raise ValueError(f"PtyBoothServer: bootloader_s {bootloader_s!r}; expected a finite number of seconds ≥ 0")
        self.emulator = emulator
        self._poll_s = idle_poll_s if emulator.real_time else poll_s
        self._pty = TwinPort()
        self.port = self._pty.path
        self.auto_reset = bool(auto_reset)
        self.resets = 0
        """Times a host's open reset the board."""
        self._bootloader = Bootloader(window_s=float(bootloader_s))
        self.programmer = Stk500v2Bootloader()
        """The bootloader's STK500v2 side: what avrdude flashed while the board was in its bootloader."""
        self._held = HeldReplies(latency_s, time.monotonic())
        self._stop = threading.Event()
        self._closed = False
        self._close_lock = threading.Lock()
        emulator.connect_output(self._write)
        emulator.boot()  # powered up: the banner goes nowhere, no host has the port open yet
        self._thread = threading.Thread(target=self._run, name=f"booth-emulator {self.port}", daemon=True)
        self._thread.start()
        log.info("booth emulator serving on %s", self.port)

    @property
    def host_open(self) -> bool:
        """Get whether a host holds the port open."""
        return self._pty.host_open

    def _port_event(self, change: str) -> None:
        self._held.clear()  # a reset, or the host's last close: what it did not read is gone
        if change == "reset" and self.auto_reset:
            self.resets += 1
            self.emulator.hold_in_reset()
            self.programmer.reset()
            self._bootloader.reset(time.monotonic())
            log.debug("booth emulator %s: reset by the port's open", self.port)

    def _wait_s(self) -> float:
        """How long the thread may sleep: until the next poll, bootloader exit, timed action or held reply."""
        now = time.monotonic()
        waits = [self._poll_s]
        if self._bootloader.ends_at is not None:
            waits.append(self._bootloader.ends_at - now)
        else:
            due = self.emulator.next_due_s()
            if due is not None:
                waits.append(due)
        flush = self._held.next_due()
        if flush is not None:
            waits.append(flush - now)
        return max(0.0, min(waits))

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, changes = self._pty.wait(self._wait_s())
                for change in changes:
                    self._port_event(change)
                now = time.monotonic()
                if data and self._bootloader.running(now):
                    self._bootloader.swallow(data, now)
                    self._answer_programmer(data, now)
                elif data:
                    self.emulator.receive(data)
                if self._bootloader.finished(time.monotonic()):
                    self.emulator.boot()
                self._flush_held()
            except OSError as err:
                if not self._stop.is_set():
                    log.error("booth emulator %s: pty failed: %s", self.port, err)
                break
            if self._bootloader.ends_at is None:
                self.emulator.tick()
            if self.emulator.hangup_requested.is_set():
                self._shutdown(from_thread=True)
                return

    def _answer_programmer(self, data: bytes, now: float) -> None:
        """Bytes in the bootloader's window: STK500v2 messages (avrdude) are answered; the rest is lost."""
        answer = self.programmer.feed(data)
        if answer:
            self._write(answer)
        if self.programmer.left:
            self._bootloader.ends_at = now  # CMD_LEAVE_PROGMODE_ISP: the bootloader starts the firmware
        elif self.programmer.active:
            self._bootloader.ends_at = max(self._bootloader.ends_at or now, now + BOOTLOADER_BYTE_HOLD_S)

    def _write(self, data: bytes) -> None:
        if not self._pty.host_open:
            return  # nobody has the port open: a USB-serial chip drops what the board sends
        if self._held.latency_s > 0:
            self._held.hold(data, time.monotonic())
            if threading.current_thread() is not self._thread:
                self._pty.wake()  # the serving thread sends it on the timer's tick
            return
        self._pty.write(data)

    def _flush_held(self) -> None:
        data = self._held.take(time.monotonic())
        if data:
            self._pty.write(data)

    def close(self) -> None:
        """Stop serving and close the pty, as an unplugged booth would (the host's next read fails); the
        emulator's LEDs go off."""
        self._shutdown(from_thread=False)

    def _shutdown(self, *, from_thread: bool) -> None:
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        self._stop.set()
        self._pty.wake()
        if not from_thread:
            self._thread.join(timeout=2.0)
        self.emulator.connect_output(None)
        self.emulator.host_lost()
        self._pty.close()

    @property
    def closed(self) -> bool:
        """Get whether the pty has been closed (bool)."""
        return self._closed

    def __enter__(self) -> PtyBoothServer:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def serve_on_pty(
    emulator: BoothEmulator | None = None,
    *,
    auto_reset: bool = True,
    bootloader_s: float = MEGA_BOOTLOADER_S,
    latency_s: float = FTDI_LATENCY_S,
    **kwargs: Any,
) -> PtyBoothServer:
    """Serve a booth emulator on a new pseudo-terminal, behind a Mega's unkind link (:class:`PtyBoothServer`).

    ``emulator`` None: a new one is built from ``kwargs``. The link resets on every open
    (``auto_reset``) with its bootloader window, and holds replies for the USB latency timer. The
    server has ``.port`` (the path to open), ``.emulator`` and ``.close()``.
    """
    if emulator is None:
        emulator = BoothEmulator(**kwargs)
    elif kwargs:
        raise ValueError("serve_on_pty: got an emulator and emulator arguments; expected one or the other")
    return PtyBoothServer(emulator, auto_reset=auto_reset, bootloader_s=bootloader_s, latency_s=latency_s)
