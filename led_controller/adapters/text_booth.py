"""A host-paced booth speaking a plain-text line protocol, over pyserial (``docs/booth-adapters.md``).

The protocol is one a person can type into a serial terminal: one ASCII command per line
(``\\n``-terminated; a ``\\r`` before it is ignored), one reply line each::

    ID?              ->  <firmware>,channels=<n>[,names=<name> <name> …]
    L <v1> … <vn>    ->  OK          (exactly n levels, each a decimal number in [0, 1])
    L?               ->  L <v1> … <vn>
    OFF              ->  OK
    (anything wrong) ->  ERR <reason>

``L`` replies once the levels are applied. There is no pattern table and no trigger line, so the
booth is host-paced only (:data:`~led_controller.booth_interface.HOST_PACED_ONLY`). The LEDs are
switched off when the booth is opened (leftovers of a run that did not finish), when it is closed,
and after every failed command before the error is raised.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import serial

from msflash.led_controller.booth_handshake import DEFAULT_BOOT_S
from msflash.led_controller.booth_interface import HOST_PACED_ONLY, BoothCapabilities
from msflash.led_controller.errors import BoothError, BoothProtocolError, BoothTimeoutError
from msflash.led_controller.serial_port import open_driver, open_transcript

log = logging.getLogger(__name__)

LEVEL_DIGITS = 5
"""Decimals of each level on the wire (1e-5, finer than a 16-bit drive)."""


@dataclass(frozen=True)
class TextBoothInfo:
    """What a text booth says it is (its ``ID?`` reply)."""

    firmware: str
    """The name before the first comma."""
    channels: int
    """``channels=``: the number of levels ``L`` takes."""
    names: tuple[str, ...]
    """``names=``, or ``ch1`` … ``chN`` when the booth gives none."""


def parse_identity(reply: str, where: str) -> TextBoothInfo:
    """The ``ID?`` reply ``reply`` as a :class:`TextBoothInfo`.

    >>> parse_identity("acme 2,channels=3,names=red green blue", "booth x")
    TextBoothInfo(firmware='acme 2', channels=3, names=('red', 'green', 'blue'))
    >>> parse_identity("acme", "booth x")
    Traceback (most recent call last):
    ...
    msflash.led_controller.errors.BoothError: booth x: ID? reply 'acme' has no channels=N; expected '<name>,channels=<n>[,names=…]'
    """
    expected = "expected '<name>,channels=<n>[,names=…]'"
    firmware, *fields = reply.split(",")
    values = dict(field.split("=", 1) for field in fields if "=" in field)
    if not firmware.strip() or "channels" not in values:
        raise BoothError(f"{where}: ID? reply {reply!r} has no channels=N; {expected}")
    try:
        channels = int(values["channels"])
    except ValueError:
        channels = 0
    if not 1 <= channels <= 64:
        raise BoothError(f"{where}: ID? reply {reply!r}: channels={values['channels']}; expected 1–64")
    names = tuple(values.get("names", "").split()) or tuple(f"ch{i + 1}" for i in range(channels))
    if len(names) != channels:
        raise BoothError(
            f"{where}: ID? reply {reply!r} names {len(names)} channels but says channels={channels}; "
            "expected one name per channel"
        )
    return TextBoothInfo(firmware.strip(), channels, names)


def format_levels(levels: Sequence[float], channels: int, where: str) -> str:
    """The ``L`` command for ``levels``, checked: one finite level in [0, 1] per channel.

    >>> format_levels([0.5, 0, 1], 3, "booth x")
    'L 0.50000 0.00000 1.00000'
    """
    if len(levels) != channels:
        raise ValueError(f"{where}: {len(levels)} levels; expected one per channel ({channels})")
    for i, level in enumerate(levels):
        if not (math.isfinite(level) and 0.0 <= level <= 1.0):
            raise ValueError(f"{where}: level {level!r} of channel {i + 1}; expected a number in [0, 1]")
    return "L " + " ".join(f"{float(level):.{LEVEL_DIGITS}f}" for level in levels)


def parse_levels(reply: str, channels: int, where: str) -> tuple[float, ...]:
    """The ``L?`` reply ``reply`` (``L <v1> … <vn>``) as levels.

    >>> parse_levels("L 0.5 0 1", 3, "booth x")
    (0.5, 0.0, 1.0)
    """
    words = reply.split()
    try:
        levels = tuple(float(word) for word in words[1:])
    except ValueError:
        levels = ()
    if not words or words[0] != "L" or len(levels) != channels:
        raise BoothProtocolError(
            f"{where}: L? reply {reply!r}; expected 'L' and {channels} levels",
            command="L?",
            expected=f"L and {channels} levels",
            raw=reply.encode(),
        )
    return levels


class TextBooth:
    """A host-paced booth speaking the plain-text line protocol (see the module docstring).

    Use :meth:`open`; it implements :class:`led_controller.booth_interface.Booth`. The open
    ``port``'s read timeout is the reply timeout; ``log_serial`` is a transcript file of
    ``> request`` / ``< reply`` lines.
    """

    def __init__(self, port: Any, *, name: str, log_serial: str | Path | None = None) -> None:
        self._port = port
        self._name = name
        self._closed = False
        self._info: TextBoothInfo | None = None
        self._transcript = open_transcript(log_serial, name, "text booth")

    @classmethod
    def open(
        cls,
        url: str,
        *,
        timeout_s: float = 1.0,
        log_serial: str | Path | None = None,
        baudrate: int = 115200,
        boot_s: float = DEFAULT_BOOT_S,
    ) -> TextBooth:
        """Open the text booth at ``url`` (device path, pty, pyserial URL), identify it, switch its LEDs off.

        A board that resets when its port opens (an Arduino's auto-reset) is given ``boot_s`` to boot,
        sending nothing: the wait ends at the first line the booth sends of its own (a sketch's greeting),
        what came before is flushed, then ``ID?`` is asked. 0: ask at once.

        Raises
        ------
        BoothNotFoundError
            The port does not exist (:func:`led_controller.serial_port.open_serial_port`).
        BoothError
            The port cannot be opened or does not answer as a text booth (its LEDs are sent ``OFF``).
        """
        booth = open_driver(
            url,
            baudrate,
            (timeout_s, timeout_s),  # missing, no permission, busy: as for LedBooth
            lambda port: cls(port, name=url, log_serial=log_serial),
            lambda booth: booth._identify_after_boot(boot_s),
        )
        info = booth.info
        log.info("%s: text booth %s, %d channels %s", url, info.firmware, info.channels, ",".join(info.names))
        return booth

    def _identify_after_boot(self, boot_s: float) -> None:
        """Wait for the booth to boot (:meth:`_await_boot`), ask ``ID?``, switch the LEDs off."""
        start = time.monotonic()
        self._await_boot(boot_s)
        try:
            reply = self._ask("ID?")
        except BoothTimeoutError as err:
            hint = (
                f"a board that resets when its port opens (Arduino auto-reset) needs --booth-boot-s longer than "
                f"its bootloader (now {boot_s:g} s)"
                if boot_s > 0
                else f"if it resets when its port opens (Arduino auto-reset), let it boot: --booth-boot-s {DEFAULT_BOOT_S:g}"
            )
            raise BoothTimeoutError(
                f"{err} ({time.monotonic() - start:.3g} s after opening the port; {hint})",
                command="ID?",
                timeout_s=err.timeout_s,
            ) from err
        self._info = parse_identity(reply, f"booth {self._name}")
        self.all_off()  # leftovers of a run that did not finish

    def _await_boot(self, boot_s: float) -> None:
        """Send nothing until the booth's first line of its own or ``boot_s``; the bytes so far are dropped."""
        if boot_s <= 0:
            return
        timeout = self._port.timeout
        deadline = time.monotonic() + boot_s
        try:
            while (remaining := deadline - time.monotonic()) > 0:
                self._port.timeout = min(remaining, 0.1)
                line = self._port.read_until(b"\n")
                if line.endswith(b"\n"):
                    self._wire("<", line.rstrip(b"\r\n").decode("ascii", errors="backslashreplace"))
                    break
        except (OSError, serial.SerialException) as err:
            raise BoothError(
                f"booth {self._name}: link lost while it booted ({err}); expected the booth connected"
            ) from err
        finally:
            self._port.timeout = timeout

    # -- the Booth interface ------------------------------------------------------------------

    @property
    def name(self) -> str:
        """Get the port name used in messages."""
        return self._name

    @property
    def info(self) -> TextBoothInfo:
        """Get what the booth said it is (``ID?``)."""
        if self._info is None:
            raise BoothError(f"booth {self._name}: not identified; expected TextBooth.open")
        return self._info

    @property
    def capabilities(self) -> BoothCapabilities:
        """Get the sync modes: host pacing only (no pattern table, no trigger line)."""
        return HOST_PACED_ONLY

    def set_levels(self, levels: Sequence[float]) -> None:
        """Set every channel's level (``L``); returns once the booth replied ``OK``."""
        try:
            line = format_levels(levels, self.info.channels, f"booth {self._name}")
        except ValueError:
            self._off_after_error()
            raise
        self._expect_ok(line)

    def all_off(self) -> None:
        """Switch every channel off (``OFF``)."""
        self._expect_ok("OFF", off_on_error=False)

    def reported_levels(self) -> tuple[float, ...]:
        """Get the levels the booth holds now (``L?``)."""
        try:
            return parse_levels(self._ask("L?"), self.info.channels, f"booth {self._name}")
        except BoothError:
            self._off_after_error()
            raise

    def watchdog_covering(self, silence_s: float) -> contextlib.AbstractContextManager[None]:
        """Nothing to cover: the text protocol has no watchdog."""
        return contextlib.nullcontext()

    def watchdog_fired(self) -> bool:
        """Never: the text protocol has no watchdog."""
        return False

    def close(self) -> None:
        """Switch the LEDs off (best effort) and close the port (idempotent)."""
        if self._closed:
            return
        with contextlib.suppress(BoothError):
            self.all_off()
        self._closed = True
        with contextlib.suppress(OSError, serial.SerialException):
            self._port.close()
        if self._transcript is not None:
            self._transcript.close()

    def __enter__(self) -> TextBooth:
        return self

    def __exit__(self, *_exc: object) -> Literal[False]:
        self.close()
        return False

    # -- by hand (``msflash booth console PORT --booth-protocol text``) -------------------------

    def identify(self) -> TextBoothInfo:
        """Ask ``ID?`` again and return (and keep) what the booth says it is."""
        self._info = parse_identity(self._ask("ID?"), f"booth {self._name}")
        return self._info

    def exchange(self, line: str) -> str:
        """Send one typed command line as it is and return the reply line.

        Raises
        ------
        BoothError
            An ``ERR`` reply (its reason in the message), silence, or a lost link; the LEDs are sent
            ``OFF`` first, as after every failed command.
        ValueError
            ``line`` is empty or not printable ASCII (nothing sent).
        """
        if not line.strip() or not line.isascii() or not line.isprintable():
            raise ValueError(f"booth {self._name}: line {line!r}; expected a printable ASCII command")
        try:
            return self._ask(line.strip())
        except BoothError:
            self._off_after_error()
            raise

    # -- the wire -------------------------------------------------------------------------------

    def _expect_ok(self, line: str, *, off_on_error: bool = True) -> None:
        try:
            reply = self._ask(line)
            if reply != "OK":
                raise BoothProtocolError(
                    f"booth {self._name}: {line.split()[0]} reply {reply!r}; expected 'OK'",
                    command=line.split()[0],
                    expected="OK",
                    raw=reply.encode(),
                )
        except BoothError:
            if off_on_error:
                self._off_after_error()
            raise

    def _off_after_error(self) -> None:
        """After a failed command: ``OFF``, best effort (the error raised is the command's)."""
        try:
            self._expect_ok("OFF", off_on_error=False)
        except BoothError as err:
            log.warning("booth %s: LEDs not confirmed off after an error: %s", self._name, err)

    def _ask(self, line: str) -> str:
        """Send ``line``, return the reply line; an ``ERR`` reply, silence or a lost link raise :class:`BoothError`."""
        command = line.split()[0]
        if self._closed:
            raise BoothError(f"booth {self._name}: {command} after close; expected an open booth")
        try:
            self._port.reset_input_buffer()  # a late reply to a command that timed out
            self._port.write(line.encode("ascii") + b"\n")
            self._port.flush()
            self._wire(">", line)
            raw = self._port.read_until(b"\n")
        except (OSError, serial.SerialException) as err:
            raise BoothError(
                f"booth {self._name}: link lost during {command} ({err}); expected the booth connected"
            ) from err
        if not raw.endswith(b"\n"):
            timeout = float(self._port.timeout or 0)
            raise BoothTimeoutError(
                f"booth {self._name}: no reply to {command} within {timeout:g} s"
                f"{f' (got {raw!r})' if raw else ''}; expected a line",
                command=command,
                timeout_s=timeout,
            )
        try:
            reply = raw.rstrip(b"\r\n").decode("ascii")
        except UnicodeDecodeError as err:
            raise BoothProtocolError(
                f"booth {self._name}: reply to {command} {raw!r} is not ASCII; expected a text line",
                command=command,
                expected="an ASCII line",
                raw=raw,
            ) from err
        self._wire("<", reply)
        if reply.startswith("ERR"):
            raise BoothError(f"booth {self._name}: refused {command}: {reply[3:].strip() or 'ERR'}")
        return reply

    def _wire(self, direction: str, line: str) -> None:
        log.debug("%s %s %s", self._name, direction, line)
        if self._transcript is not None:
            self._transcript.write(f"{direction} {line}\n")
            self._transcript.flush()
