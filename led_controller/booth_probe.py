"""Asking one named serial port who it is, in one booth protocol (``msflash doctor --port P``).

Only the port the user names is opened, and only the identity request of the protocol the user
names is sent (``ID`` framed for ``msflash``, ``ID?`` for ``text``): bytes sent to an unknown
serial device can upset it. The first reply line is read raw, so that what answered instead of
a booth — nothing, binary noise, an ``ERR`` line, the other protocol — is said in one line.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import serial

from msflash.led_controller.adapters.text_booth import parse_identity
from msflash.led_controller.booth_handshake import DEFAULT_BOOT_S
from msflash.led_controller.errors import BoothError, BoothTimeoutError
from msflash.led_controller.protocol import encode_request, frame_problem, parse_frame, parse_identify, parse_reply
from msflash.led_controller.serial_port import open_serial_port

PROBE_PROTOCOLS = ("msflash", "text")
"""The protocols :func:`probe_booth` can ask in."""

MAX_LINES = 8
"""Reply lines read before giving up (an msflash booth may send events before the ID reply)."""


@dataclass(frozen=True)
class ProbedBooth:
    """What a booth said it is when asked for its identity."""

    port: str
    protocol: str
    """The protocol it answered in."""
    firmware: str
    channels: int
    """Its number of LED channels."""
    names: tuple[str, ...]
    """One name per channel."""
    serial: str | None = None
    """The booth's own serial (``SERIAL=`` of an msflash booth; None: not set, or a text booth)."""


def describe_answer(raw: bytes) -> str:
    """What a reply line ``raw`` looks like, for a message saying what answered instead of a booth.

    >>> describe_answer(b"ERR unknown command")
    "an ERR line 'ERR unknown command' (a text booth? try --booth-protocol text)"
    >>> describe_answer(bytes([0xFF, 0x00, 0x13]))
    'binary noise ff 00 13 (another device, or the wrong baud rate)'
    >>> describe_answer(b"=00:01D:ERR - E_FRAME frame too short*234F")
    "an msflash frame '=00:01D:ERR - E_FRAME frame too short*234F' (an msflash booth? try --booth-protocol msflash)"
    """
    line = raw.rstrip(b"\r\n")
    if any(byte > 0x7E or (byte < 0x20 and byte != 0x09) for byte in line):
        return f"binary noise {line[:16].hex(' ')} (another device, or the wrong baud rate)"
    text = line.decode("ascii")
    if text.startswith("ERR"):
        return f"an ERR line {text[:80]!r} (a text booth? try --booth-protocol text)"
    if frame_problem(line) is None:
        return f"an msflash frame {text[:80]!r} (an msflash booth? try --booth-protocol msflash)"
    return f"the line {text[:80]!r}"


def await_boot_banner(link: serial.SerialBase, boot_s: float = DEFAULT_BOOT_S) -> bytes:
    """Read, sending nothing, until an msflash booth's ``BOOT`` banner or ``boot_s`` have passed.

    A stock Arduino Mega resets when its port is opened (``docs/booth-firmware.md`` §4); its
    bootloader must not be sent anything meanwhile. Returns every byte read up to and including the
    banner's line end (``b""`` when none came: a booth that does not reset, or old firmware).
    ``link.timeout`` is as it was on return (it polls with short reads meanwhile).
    """
    deadline = time.monotonic() + boot_s
    seen = bytearray()
    timeout = link.timeout
    try:
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return b""
            link.timeout = min(remaining, 0.1)
            seen += link.read_until(b"\n")
            if not seen.endswith(b"\n"):
                continue
            line = bytes(seen[seen.rstrip(b"\n").rfind(b"\n") + 1 :]).rstrip(b"\n")
            if line.startswith(b"!") and frame_problem(line) is None and line.split(b":", 2)[2].startswith(b"BOOT"):
                return bytes(seen)
    finally:
        link.timeout = timeout


def probe_booth(
    port: str, protocol: str, *, timeout_s: float = 1.0, baudrate: int = 115200, boot_s: float = DEFAULT_BOOT_S
) -> ProbedBooth:
    """Open ``port``, send ``protocol``'s identity request, and parse the answer.

    Parameters
    ----------
    protocol
        ``msflash`` (``docs/booth-protocol.md``) or ``text`` (``docs/booth-adapters.md`` §2).
    boot_s
        How long to wait, silent, for the booth to boot after the open reset it (``--booth-boot-s``): an
        msflash booth's ``BOOT`` banner ends the wait, a text booth's first line of its own too.

    Raises
    ------
    BoothError
        One line: the port did not open, or what answered instead and what was expected.
    """
    if protocol not in PROBE_PROTOCOLS:
        raise ValueError(f"--booth-protocol {protocol!r}: unknown; expected one of {', '.join(PROBE_PROTOCOLS)}")
    link = open_serial_port(port, baudrate, timeout_s, timeout_s)
    where = f"booth {port}"
    request = b"ID?\n" if protocol == "text" else encode_request(1, "ID")
    expected = (
        "'<firmware>,channels=<n>[,names=…]' (a text booth)"
        if protocol == "text"
        else "an msflash ID reply frame (our firmware)"
    )
    try:
        start = time.monotonic()
        _await_boot(link, protocol, boot_s)
        waited = time.monotonic() - start
        link.timeout = timeout_s
        link.reset_input_buffer()  # bootloader noise, a text booth's greeting
        link.write(request)
        link.flush()
        deadline = time.monotonic() + timeout_s
        for _ in range(MAX_LINES):
            raw = link.read_until(b"\n")
            if not raw.endswith(b"\n"):
                got = f"; got {describe_answer(raw)} without a line end" if raw else ""
                booted = (
                    f" (after {min(waited, boot_s):.2g} s waiting for it to boot; a board that resets when its port opens "
                    "may need a longer --booth-boot-s)"
                    if boot_s > 0
                    else " (--booth-boot-s 0: if it resets when its port opens, an Arduino's auto-reset, "
                    f"let it boot: --booth-boot-s {DEFAULT_BOOT_S:g})"
                )
                raise BoothTimeoutError(
                    f"{where}: nothing answered {request.strip().decode()} within {timeout_s:g} s{got}{booted}; "
                    f"expected {expected}",
                    command="ID",
                    timeout_s=timeout_s,
                )
            line = raw.rstrip(b"\r\n")
            if protocol == "msflash" and line.startswith(b"!") and frame_problem(line) is None:
                if time.monotonic() > deadline:
                    break
                continue  # an event left over from a sequence: the ID reply follows
            return _parse(port, protocol, line, expected)
        raise BoothTimeoutError(
            f"{where}: only events within {timeout_s:g} s, no ID reply; expected {expected}",
            command="ID",
            timeout_s=timeout_s,
        )
    except (OSError, serial.SerialException) as err:
        if isinstance(err, BoothError):
            raise
        raise BoothError(
            f"{where}: link lost while asking its identity ({err}); expected the device connected"
        ) from err
    finally:
        link.close()


def _await_boot(link: serial.SerialBase, protocol: str, boot_s: float) -> None:
    """The silent wait after the open: until the msflash banner, a text booth's first line, or ``boot_s``."""
    if boot_s <= 0:
        return
    if protocol == "msflash":
        await_boot_banner(link, boot_s)
        return
    deadline = time.monotonic() + boot_s
    while (remaining := deadline - time.monotonic()) > 0:
        link.timeout = min(remaining, 0.1)
        if link.read_until(b"\n").endswith(b"\n"):
            return  # the firmware runs: it said something of its own


def _parse(port: str, protocol: str, line: bytes, expected: str) -> ProbedBooth:
    where = f"booth {port}"
    instead = f"{where}: answered {describe_answer(line)}; expected {expected}"
    try:
        if protocol == "text":
            if line.startswith(b"ERR") or frame_problem(line) is None:
                raise BoothError(instead)
            text_info = parse_identity(line.decode("ascii"), where)
            return ProbedBooth(port, protocol, text_info.firmware, text_info.channels, text_info.names)
        if frame_problem(line) is not None:
            raise BoothError(instead)
        info = parse_identify(
            parse_reply(parse_frame(line, where=where, command="ID"), "ID", where=where), line, where=where
        )
    except UnicodeDecodeError:
        raise BoothError(instead) from None
    return ProbedBooth(port, protocol, info.firmware, info.channels, tuple(info.names), info.serial)
