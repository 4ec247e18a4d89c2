"""An emulator of the plain-text booth (:mod:`led_controller.adapters.text_booth`) on a real pty.

Its parser is its own (it shares no code with the adapter, as a vendor's device would not).
Run it for a terminal or a ``--booth-protocol text`` capture::

    python -m msflash.lab.text_booth_emulator --channels 7

prints the pty path to open and serves until interrupted.
"""

from __future__ import annotations

import argparse
import logging
import math
import threading
import time
from collections.abc import Sequence

from msflash.led_controller.usb_link import MEGA_BOOTLOADER_S, Bootloader, TwinPort

log = logging.getLogger(__name__)


class TextBoothEmulator:
    """The text booth's state machine: one reply line per command line.

    Parameters
    ----------
    names : sequence of str
        One name per channel (no spaces or commas).
    firmware : str
        What ``ID?`` names the booth.

    Attributes
    ----------
    levels : tuple of float
        The levels held now.
    commands : list of str
        Every command line received, in order.

    >>> booth = TextBoothEmulator(["red", "blue"])
    >>> booth.reply("L 0.5 1"), booth.reply("L?"), booth.reply("L 2 0"), booth.reply("OFF"), booth.levels
    ('OK', 'L 0.5 1', 'ERR level 2 of channel 1 outside [0, 1]', 'OK', (0.0, 0.0))
    """

    def __init__(self, names: Sequence[str], firmware: str = "msflash text-booth emulator 1") -> None:
        if not names or any(not name or set(name) & set(" ,\t\r\n") for name in names):
            raise ValueError(
                f"text booth emulator: channel names {list(names)!r}; expected one or more names "
                "without spaces or commas"
            )
        self.names = tuple(names)
        self.firmware = firmware
        self.levels: tuple[float, ...] = (0.0,) * len(self.names)
        self.commands: list[str] = []

    def reply(self, line: str) -> str:
        """The reply to one command line (without its terminator)."""
        self.commands.append(line)
        words = line.strip().split()
        if not words:
            return "ERR empty line"
        command = words[0].upper()
        if command == "ID?" and len(words) == 1:
            return f"{self.firmware},channels={len(self.names)},names={' '.join(self.names)}"
        if command == "OFF" and len(words) == 1:
            self.levels = (0.0,) * len(self.names)
            return "OK"
        if command == "L?" and len(words) == 1:
            return "L " + " ".join(f"{level:g}" for level in self.levels)
        if command == "L":
            return self._set(words[1:])
        return f"ERR unknown command {words[0]!r}; expected ID?, L, L? or OFF"

    def _set(self, words: list[str]) -> str:
        if len(words) != len(self.names):
            return f"ERR {len(words)} levels; expected {len(self.names)}"
        levels = []
        for i, word in enumerate(words):
            try:
                level = float(word)
            except ValueError:
                return f"ERR level {word!r} of channel {i + 1} is not a number"
            if not (math.isfinite(level) and 0.0 <= level <= 1.0):
                return f"ERR level {word} of channel {i + 1} outside [0, 1]"
            levels.append(level)
        self.levels = tuple(levels)
        return "OK"


class TextBoothServer:
    """A :class:`TextBoothEmulator` served on a new pseudo-terminal (a thread on the master end).

    Open :attr:`port` (the slave's path) with :meth:`TextBooth.open`; close with :meth:`close` or
    ``with``.

    Like a text booth built on a stock Arduino (``led_controller/usb_link.py``), a host's open resets it
    unless ``auto_reset`` is False: levels off, the host's bytes swallowed for ``bootloader_s`` of
    wall-clock time, then the sketch starts and prints its greeting line, ``<firmware> ready``. What it
    sends while no host holds the port is lost.
    """

    def __init__(
        self, emulator: TextBoothEmulator, *, auto_reset: bool = True, bootloader_s: float = MEGA_BOOTLOADER_S
    ) -> None:
        self.emulator = emulator
        self._pty = TwinPort()
        self.port = self._pty.path
        self.auto_reset = auto_reset
        self.resets = 0
        self._bootloader = Bootloader(window_s=bootloader_s)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"text-booth-emulator {self.port}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        pending = b""
        while not self._stop.is_set():
            try:
                wait = (
                    None if self._bootloader.ends_at is None else max(0.0, self._bootloader.ends_at - time.monotonic())
                )
                data, changes = self._pty.wait(wait)
                for change in changes:
                    if change == "reset" and self.auto_reset:
                        self.resets += 1
                        self.emulator.levels = (0.0,) * len(self.emulator.names)  # reset: pins are inputs
                        self._bootloader.reset(time.monotonic())
                now = time.monotonic()
                if self._bootloader.running(now):
                    self._bootloader.swallow(data, now)
                    pending = b""
                    continue
                if self._bootloader.finished(now):
                    self._pty.write(f"{self.emulator.firmware} ready\n".encode("ascii"))  # the sketch's setup()
                pending += data
            except OSError as err:
                if not self._stop.is_set():
                    log.error("text booth emulator %s: pty failed: %s", self.port, err)
                return
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                text = line.rstrip(b"\r").decode("ascii", errors="replace")
                self._pty.write((self.emulator.reply(text) + "\n").encode("ascii"))

    def close(self) -> None:
        """Stop the thread and close the pty (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._pty.wake()
        self._thread.join(timeout=2.0)
        self._pty.close()

    def __enter__(self) -> TextBoothServer:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def serve_text_booth(
    channels: int = 7,
    names: Sequence[str] | None = None,
    *,
    auto_reset: bool = True,
    bootloader_s: float = MEGA_BOOTLOADER_S,
) -> TextBoothServer:
    """A text booth emulator with ``channels`` channels (named ``names``, or ``ch1`` … ``chN``) on a new pty,
    resetting when its port opens unless ``auto_reset`` is False (:class:`TextBoothServer`)."""
    emulator = TextBoothEmulator(names or [f"ch{i + 1}" for i in range(channels)])
    return TextBoothServer(emulator, auto_reset=auto_reset, bootloader_s=bootloader_s)


def main(argv: Sequence[str] | None = None) -> int:
    """Serve a text booth emulator on a pty until interrupted; print its path."""
    parser = argparse.ArgumentParser(
        prog="python -m msflash.lab.text_booth_emulator",
        description="Serve the plain-text booth emulator on a new pty.",
    )
    parser.add_argument("--channels", type=int, default=7, help="number of LED channels (default 7)")
    parser.add_argument(
        "--no-auto-reset", action="store_true", help="a board with auto-reset disabled: opening the port resets nothing"
    )
    args = parser.parse_args(argv)
    if not 1 <= args.channels <= 64:
        parser.error(f"--channels {args.channels}: expected 1–64")
    with serve_text_booth(args.channels, auto_reset=not args.no_auto_reset) as server:
        print(server.port, flush=True)
        try:
            threading.Event().wait()
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
