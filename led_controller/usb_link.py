"""What the USB-serial link of a real booth does to the bytes, for the twins served on a pty.

A stock Arduino Mega 2560 resets whenever its serial port is opened: Linux asserts DTR on every
open of a tty (``tty_port_block_til_ready`` raises DTR/RTS unless the baud rate is 0), the board
turns that edge into a RESET pulse through a 100 nF capacitor, and the stk500v2 bootloader then
owns the UART for a while before it starts the firmware. A USB-serial chip also holds the board's
replies back: an FTDI chip sends a short packet only when its latency timer expires (16 ms by
default), a 16U2 running Arduino's USB-serial firmware on its own, shorter, timer.

:class:`PortOpenWatch` sees a host open the pty's slave (inotify ``IN_OPEN`` on the ``/dev/pts/N``
node — pyserial's open is such an open); :class:`Bootloader` is the wall-clock window in which a
reset board swallows what the host sends; :class:`HeldReplies` is the latency timer; :class:`TwinPort`
is the board's end of the pty. The Python twins' servers (:class:`~led_controller.emulator_pty.PtyBoothServer`,
``lab/text_booth_emulator.py``) use them; the simavr
bridge (``firmware/sim/booth_sim.c``) has the same model in C. What cannot be simulated here (the
16U2 itself, DTR as a voltage, the capacitor) is listed in ``docs/booth-firmware.md`` §4.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import math
import os
import select
import struct
import termios
import threading
import tty
from dataclasses import dataclass

MEGA_BOOTLOADER_S = 1.6
"""How long a Mega 2560 reset by the port's open swallows the host's bytes before the firmware runs,
in seconds: within what a stock board takes (docs/booth-firmware.md); the Arduino stk500v2 bootloader's
own first wait is "about 1 second" (``boot_timeout``), the rest is the reset and the 16U2."""

BOOTLOADER_BYTE_HOLD_S = 1.0
"""How long the bootloader stays after the last byte it received, in seconds (the twins' figure).

The stk500v2 bootloader leaves for the firmware only once nothing arrived for ``F_CPU / 2`` turns of
its receive loop (``recchar_timeout``), several seconds at 16 MHz: a host that keeps sending while
the board boots keeps it in the bootloader. The twins hold 1 s after each byte, less than a real
board, so a host that sends too early is seen to fail without slowing the tests much."""

FTDI_LATENCY_S = 0.016
"""An FTDI chip's default latency timer: a reply shorter than a USB packet waits up to this long."""

USB_PACKET_PAYLOAD = 62
"""Bytes of serial data in one full-speed FTDI packet (64 minus 2 status bytes): a full packet is sent
at once, a shorter one waits for the latency timer."""

_IN_OPEN = 0x00000020
_IN_CLOSE_WRITE = 0x00000008
_IN_CLOSE_NOWRITE = 0x00000010
_IN_NONBLOCK = os.O_NONBLOCK
_IN_CLOEXEC = os.O_CLOEXEC
_EVENT = struct.Struct("iIII")


class PortOpenWatch:
    """Opens and closes of a device node by anyone, seen with inotify (Linux).

    The watch is set up before the path is handed to a host, so every open a host makes is seen,
    and only those: reading the node's attributes (``stat``, pyserial's port listing) is no open.

    Raises
    ------
    OSError
        inotify is not available (not Linux) or the node cannot be watched.
    """

    def __init__(self, path: str) -> None:
        name = ctypes.util.find_library("c")
        libc = ctypes.CDLL(name, use_errno=True)
        fd = libc.inotify_init1(_IN_NONBLOCK | _IN_CLOEXEC)
        if fd < 0:
            err = ctypes.get_errno()
            raise OSError(err, f"inotify_init1: {os.strerror(err)}")
        if libc.inotify_add_watch(fd, os.fsencode(path), _IN_OPEN | _IN_CLOSE_WRITE | _IN_CLOSE_NOWRITE) < 0:
            err = ctypes.get_errno()
            os.close(fd)
            raise OSError(err, f"inotify_add_watch {path}: {os.strerror(err)}")
        self._fd = fd
        self.path = path

    def fileno(self) -> int:
        """The inotify descriptor (readable when an open or close happened)."""
        return self._fd

    def changes(self) -> list[int]:
        """The opens (+1) and closes (-1) since the last call, in order (non-blocking)."""
        out: list[int] = []
        while True:
            try:
                data = os.read(self._fd, 4096)
            except BlockingIOError:
                return out
            offset = 0
            while offset + _EVENT.size <= len(data):
                _wd, mask, _cookie, length = _EVENT.unpack_from(data, offset)
                offset += _EVENT.size + length
                if mask & _IN_OPEN:
                    out.append(+1)
                if mask & (_IN_CLOSE_WRITE | _IN_CLOSE_NOWRITE):
                    out.append(-1)

    def close(self) -> None:
        """Stop watching (idempotent)."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


@dataclass
class Bootloader:
    """The window after a reset in which the board's bootloader, not the firmware, owns the UART.

    Bytes from the host are swallowed (the stk500v2 bootloader waits for its own ``0x1B`` message
    start) and each one keeps the bootloader ``byte_hold_s`` longer. All times are the wall clock's
    (``time.monotonic``): a real bootloader's timeout is real time, whatever a simulator's pace.
    """

    window_s: float = MEGA_BOOTLOADER_S
    byte_hold_s: float = BOOTLOADER_BYTE_HOLD_S
    ends_at: float | None = None
    swallowed: int = 0

    def reset(self, now: float) -> None:
        """The board was reset at ``now``: the bootloader runs until ``now + window_s``."""
        self.ends_at = now + self.window_s

    def running(self, now: float) -> bool:
        """Whether the bootloader still owns the UART at ``now``."""
        return self.ends_at is not None and now < self.ends_at

    def swallow(self, data: bytes, now: float) -> None:
        """Host bytes that reached the bootloader: lost, and the bootloader stays longer."""
        self.swallowed += len(data)
        if self.ends_at is not None and data:
            self.ends_at = max(self.ends_at, now + self.byte_hold_s)

    def finished(self, now: float) -> bool:
        """Whether the window ended by ``now`` (once: the caller then boots the firmware)."""
        if self.ends_at is not None and now >= self.ends_at:
            self.ends_at = None
            return True
        return False


class HeldReplies:
    """A USB-serial chip's latency timer: what the board sends reaches the host in packets.

    A full packet (:data:`USB_PACKET_PAYLOAD` bytes) goes at once; the rest waits for the next tick
    of a free-running timer of period ``latency_s`` (an FTDI chip's latency timer), so a short reply
    arrives 0 to ``latency_s`` late. Thread-safe: any thread may :meth:`hold`, one thread takes.
    """

    def __init__(self, latency_s: float, start: float) -> None:
        if not (latency_s >= 0 and math.isfinite(latency_s)):
            raise ValueError(f"latency {latency_s!r} s; expected a finite number ≥ 0")
        self.latency_s = float(latency_s)
        self._start = start
        self._buffer = bytearray()
        self._due = start
        self._lock = threading.Lock()

    def _tick_at_or_after(self, now: float) -> float:
        if self.latency_s == 0:
            return now
        return self._start + math.ceil((now - self._start) / self.latency_s) * self.latency_s

    def hold(self, data: bytes, now: float) -> None:
        """Bytes the board wrote at ``now``."""
        with self._lock:
            if not self._buffer:
                self._due = self._tick_at_or_after(now)
            self._buffer += data

    def clear(self) -> None:
        """Forget what is held (the host closed the port: a real chip's buffer is dropped too)."""
        with self._lock:
            self._buffer.clear()

    def next_due(self) -> float | None:
        """When held bytes go out next (None: nothing held; ``-inf``: a full packet, at once)."""
        with self._lock:
            if not self._buffer:
                return None
            return -math.inf if len(self._buffer) >= USB_PACKET_PAYLOAD else self._due

    def take(self, now: float) -> bytes:
        """The bytes that reach the host at ``now``: every full packet, and all of them once the timer ticked."""
        with self._lock:
            if now >= self._due:
                size = len(self._buffer)
            else:
                size = len(self._buffer) // USB_PACKET_PAYLOAD * USB_PACKET_PAYLOAD
            out = bytes(self._buffer[:size])
            del self._buffer[:size]
            return out


class TwinPort:
    """The board's end of a pseudo-terminal, for a twin served by a Python thread.

    :attr:`path` is the slave a host opens (raw: no echo, no line editing, no CR/LF mapping). The
    slave node is watched (:class:`PortOpenWatch`) before its path is handed out, so every host's
    open is seen; :meth:`wait` reports a host's first open (the DTR edge that resets a stock Mega)
    and its last close (the kernel then frees what the host did not read). What the board writes
    while no host holds the port is lost, as a USB-serial chip's. Linux only.
    """

    def __init__(self) -> None:
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self._watch = PortOpenWatch(self.path)
        self._wake_r, self._wake_w = os.pipe()
        self._opens = 0
        self._lock = threading.Lock()

    @property
    def host_open(self) -> bool:
        """Get whether a host holds the port open."""
        with self._lock:
            return self._opens > 0

    def wait(self, timeout_s: float | None) -> tuple[bytes, list[str]]:
        """Wait up to ``timeout_s`` (None: for ever) for the host's bytes, an open or close, or :meth:`wake`.

        Returns the bytes read (maybe none) and, in order, ``"reset"`` for each first open and
        ``"closed"`` for each last close. Raises OSError when the pty is gone.
        """
        ready, _, _ = select.select([self.master, self._wake_r, self._watch.fileno()], [], [], timeout_s)
        if self._wake_r in ready:
            os.read(self._wake_r, 4096)
        changes = []
        if self._watch.fileno() in ready:
            for change in self._watch.changes():
                with self._lock:
                    was, self._opens = self._opens, max(0, self._opens + change)
                if change > 0 and was == 0:  # a second open finds DTR already up: no reset
                    changes.append("reset")
                elif change < 0 and was == 1:
                    changes.append("closed")
                    with contextlib.suppress(termios.error, OSError):
                        termios.tcflush(self._slave, termios.TCIFLUSH)
        data = os.read(self.master, 4096) if self.master in ready else b""
        return data, changes

    def wake(self) -> None:
        """Make a :meth:`wait` on the serving thread return now."""
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"w")

    def write(self, data: bytes) -> None:
        """Send ``data`` to the host, all of it; lost if no host holds the port or the pty is gone."""
        if not self.host_open:
            return
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.master, view) :]
            except OSError:
                return  # the pty is gone: the host sees a dead link, as with an unplugged board

    def close(self) -> None:
        """Close the pty, the watch and the wake-up pipe (the host's next read fails)."""
        self._watch.close()
        for fd in (self.master, self._slave, self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
