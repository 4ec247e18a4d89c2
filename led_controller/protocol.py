"""The msflash booth wire format: names, frame encoding and parsing, checksums. No I/O.

The full specification is ``docs/booth-protocol.md``. A frame is one ASCII line::

    <mark><seq:2 hex>:<len:3 hex>:<body>*<crc:4 hex>\\n

``mark`` is ``?`` (host request), ``=`` (booth reply) or ``!`` (booth event); ``len`` is the
body length in bytes; ``crc`` is CRC-16/CCITT-FALSE over everything before the ``*``.

Only the name constants here (:class:`Command`, :class:`Event`, :class:`Mode`,
:class:`ErrorCode`, the marks and limits) are shared with the emulator; the emulator parses
frames with its own code so that a parser bug cannot look consistent on both sides.
"""

from __future__ import annotations

import binascii
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

from msflash.led_controller.errors import BoothProtocolError

PROTOCOL_VERSION = 1
"""Version number the booth reports in its identify reply (``PROTO=``)."""

MARK_REQUEST = "?"
MARK_REPLY = "="
MARK_EVENT = "!"

SEQ_FRAME_ERROR = 0
"""Sequence number of the booth's reply to a frame it could not read (hosts use 1..255)."""

MAX_BODY = 1024
"""Largest body in bytes; longer frames are refused by both sides."""

MAX_LINE = MAX_BODY + 16
"""Longest line a receiver keeps, in bytes (a frame with the longest body is 1037 plus its
terminator; ``docs/booth-protocol.md`` §2): anything longer is a framing error, thrown away up to
the next terminator."""

WATCHDOG_POWER_UP_MS = 3000
"""The booth's watchdog period at power-up, in ms (``docs/booth-protocol.md`` §7)."""

LEVEL_BITS = 16
"""Bits per LED level on the wire (firmware may drive fewer, reported as ``BITS=``)."""

LEVEL_MAX = (1 << LEVEL_BITS) - 1

WATCHDOG_MIN_MS, WATCHDOG_MAX_MS = 50, 600_000
"""``WDOG`` periods the protocol allows besides 0 (off), in ms (``docs/booth-protocol.md``)."""


def watchdog_ms_allowed(ms: int) -> bool:
    """Whether ``WDOG ms`` is a period the protocol allows: 0 (off) or ``WATCHDOG_MIN_MS..WATCHDOG_MAX_MS``.

    >>> [watchdog_ms_allowed(ms) for ms in (0, 49, 50, 600_000, 600_001)]
    [True, False, True, True, False]
    """
    return ms == 0 or WATCHDOG_MIN_MS <= ms <= WATCHDOG_MAX_MS


TERMINATOR = b"\n"

SERIAL_MAX = 32
"""Longest booth serial (``SERIAL <text>``), in characters."""

SERIAL_UNSET = "-"
"""What ``SERIAL=`` says of a booth whose serial was never set."""

_SERIAL_RE = re.compile(r"[A-Za-z0-9._-]{1,32}")  # {1,32}: SERIAL_MAX


def serial_allowed(text: str) -> bool:
    """Whether ``text`` can be a booth serial: 1..32 of ``A-Z a-z 0-9 . _ -``, and not ``-`` alone.

    >>> [serial_allowed(t) for t in ("booth-A1", "", "-", "a b", "x" * 33)]
    [True, False, False, False, False]
    """
    return text != SERIAL_UNSET and _SERIAL_RE.fullmatch(text) is not None


class Command(StrEnum):
    """Request names (first word of a request body)."""

    IDENTIFY = "ID"
    SET = "SET"
    OFF = "OFF"
    PATTERN_CLEAR = "PCLR"
    PATTERN_ADD = "PADD"
    PATTERN_SET = "PSET"
    ARM = "ARM"
    START = "START"
    NEXT = "NEXT"
    COUNT = "CNT"
    STATUS = "STAT"
    WATCHDOG = "WDOG"
    PING = "PING"
    SERIAL = "SERIAL"
    ROLL = "ROLL"


HOLD_FLAG = "HOLD"
"""Trailing word of ``PADD <levels> HOLD``: the step is a placeholder the booth will not expose
until ``PSET`` gives its levels (``docs/booth-protocol.md`` §4–5)."""


class Event(StrEnum):
    """Event names (first word of an event body)."""

    TRIGGER = "TRIG"
    DONE = "DONE"
    WATCHDOG = "WDOG"
    BOOT = "BOOT"


class Mode(StrEnum):
    """Synchronisation modes of ``ARM`` (docs/architecture.md §4)."""

    HOST = "HOST"
    BOOTH = "BOOTH"
    CAMERA = "CAMERA"


class ErrorCode(StrEnum):
    """Error codes of ``ERR`` replies."""

    CRC = "E_CRC"
    LENGTH = "E_LEN"
    FRAME = "E_FRAME"
    COMMAND = "E_CMD"
    ARGUMENT = "E_ARG"
    RANGE = "E_RANGE"
    STATE = "E_STATE"
    FULL = "E_FULL"


FRAME_ERROR_CODES = frozenset({ErrorCode.CRC, ErrorCode.LENGTH, ErrorCode.FRAME})
"""Codes meaning the booth could not read the host's frame (line noise, not a refusal)."""

FRAME_FORM = "<mark><seq:2 hex>:<len:3 hex>:<body>*<crc16:4 hex>"

_FRAME_RE = re.compile(rb"([?=!])([0-9A-F]{2}):([0-9A-F]{3}):([\x20-\x29\x2b-\x7e]*)\*([0-9A-F]{4})")


@dataclass(frozen=True)
class Frame:
    """One checked frame."""

    mark: str
    """``?`` request, ``=`` reply or ``!`` event."""
    seq: int
    """Sequence number 0..255 (requests and replies share it; events count on their own)."""
    body: str
    """The body text (printable ASCII, no ``*``)."""
    raw: bytes
    """The frame as on the wire, without the terminator."""


@dataclass(frozen=True)
class Reply:
    """A parsed reply body: ``OK <command> args…`` or ``ERR <command> <code> text``."""

    ok: bool
    """True for ``OK``."""
    command: str
    """The command name echoed by the booth (``-`` for unreadable frames)."""
    args: tuple[str, ...]
    """Words after the command name (for ``OK``)."""
    code: str | None
    """Error code for ``ERR``, else None."""
    text: str
    """Error text for ``ERR``, else empty."""


@dataclass(frozen=True)
class BoothInfo:
    """What a booth is: firmware, channels and their LEDs."""

    firmware: str
    protocol: int
    channels: int
    names: tuple[str, ...]
    """Channel names, one per channel."""
    peaks_nm: tuple[float, ...]
    """Nominal peak wavelength of each channel in nm."""
    level_bits: int
    """Resolution of the firmware's LED drive in bits (the wire always carries 16)."""
    max_steps: int
    """Capacity of the pattern table in steps."""
    serial: str | None = None
    """The booth's own serial (``SERIAL=``, set with the ``SERIAL`` command and kept in its EEPROM);
    None when the booth does not report one or it was never set (``SERIAL=-``)."""

    dimming: str | None = None
    """``DIM=``: ``PULSE`` (exposure-synchronous pulses in booth and camera master for steps given
    their exposure, PWM otherwise) or ``PWM``; None for a booth that does not say (PWM)."""
    pwm_hz: float | None = None
    """``PWMHZ=``: the PWM frequency the LEDs are dimmed at where they are not pulsed, or None."""

    @property
    def pulse_dimming(self) -> bool:
        """Whether the booth pulses steps given their exposure (``PADD``/``PSET … EXP=``)."""
        return self.dimming == "PULSE"


@dataclass(frozen=True)
class BoothStatus:
    """A snapshot of the booth's state."""

    state: str
    """``IDLE``, ``ARMED``, ``RUNNING`` or ``DONE``."""
    mode: str | None
    """Armed synchronisation mode (``HOST``, ``BOOTH``, ``CAMERA``) or None."""
    step: int
    """Current pattern step, -1 before the first."""
    steps: int
    """Steps in the pattern table."""
    trigger_count: int
    """Triggers since the last ``ARM``."""
    watchdog_s: float
    """Watchdog timeout in seconds (0 means disabled)."""
    levels: tuple[float, ...]
    """LED levels now, each in [0, 1]."""
    last_error: str | None
    """Last error code the booth reported, or None."""
    bad_frames: int
    """Frames the booth rejected since power-up."""


@dataclass(frozen=True)
class BoothEvent:
    """An unsolicited event line from the booth."""

    kind: str
    """Event name (see :class:`Event`)."""
    seq: int
    """Event sequence number (1..255, wrapping; gaps mean lost events)."""
    args: tuple[str, ...]
    """Words after the event name."""
    raw: bytes
    """The frame as on the wire."""


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) of ``data``.

    Examples
    --------
    >>> hex(crc16(b"123456789"))
    '0x29b1'
    """
    return binascii.crc_hqx(data, 0xFFFF)


def encode_frame(mark: str, seq: int, body: str) -> bytes:
    """Encode one frame with its terminator.

    Raises
    ------
    ValueError
        If the mark, sequence number or body cannot be framed.
    """
    if mark not in (MARK_REQUEST, MARK_REPLY, MARK_EVENT):
        raise ValueError(f"encode_frame: mark {mark!r} unknown; expected '?', '=' or '!'")
    if not 0 <= seq <= 0xFF:
        raise ValueError(f"encode_frame: seq {seq} out of range; expected 0..255")
    data = body.encode("ascii", errors="strict")
    if len(data) > MAX_BODY or any(b < 0x20 or b > 0x7E or b == 0x2A for b in data):
        raise ValueError(
            f"encode_frame: body {body[:40]!r} not frameable; expected at most {MAX_BODY} "
            "printable ASCII bytes without '*'"
        )
    head = f"{mark}{seq:02X}:{len(data):03X}:".encode("ascii") + data
    return head + f"*{crc16(head):04X}".encode("ascii") + TERMINATOR


def frame_problem(line: bytes) -> str | None:
    """Why ``line`` (without terminator) is not a valid frame, or None if it is."""
    match = _FRAME_RE.fullmatch(line)
    if match is None:
        if len(line) > MAX_LINE:
            return f"line of {len(line)} bytes is longer than {MAX_LINE}"
        return "not in frame form"
    if int(match.group(3), 16) != len(match.group(4)):
        return f"length field {int(match.group(3), 16)} but body has {len(match.group(4))} bytes"
    if len(match.group(4)) > MAX_BODY:
        # Three hex digits could say up to 4095: the protocol's limit is what counts.
        return f"body of {len(match.group(4))} bytes is longer than {MAX_BODY}"
    crc_sent = int(match.group(5), 16)
    crc_calc = crc16(line[: match.start(5) - 1])
    if crc_sent != crc_calc:
        return f"checksum {crc_sent:04X} but frame sums to {crc_calc:04X}"
    return None


def parse_frame(line: bytes, *, where: str = "booth", command: str | None = None) -> Frame:
    """Check and split one frame (``line`` without its terminator).

    Raises
    ------
    BoothProtocolError
        If the line is malformed, its length field is wrong or its checksum does not match.
    """
    problem = frame_problem(line)
    if problem is not None:
        about = f"reply to {command}" if command else "line"
        raise BoothProtocolError(
            f"{where}: bad {about} ({problem}): {line[:80]!r}; expected {FRAME_FORM}; "
            "check the cable, baud rate and that the port is an msflash booth",
            command=command,
            expected=FRAME_FORM,
            raw=line,
        )
    match = _FRAME_RE.fullmatch(line)
    assert match is not None  # frame_problem returned None, so it matched
    return Frame(
        mark=match.group(1).decode("ascii"),
        seq=int(match.group(2), 16),
        body=match.group(4).decode("ascii"),
        raw=line,
    )


def encode_request(seq: int, command: str, *args: object) -> bytes:
    """Encode a host request ``<command> <args…>`` with sequence number ``seq`` (1..255)."""
    if not 1 <= seq <= 0xFF:
        raise ValueError(f"encode_request: seq {seq} out of range; expected 1..255")
    body = " ".join([str(command), *(str(a) for a in args)])
    return encode_frame(MARK_REQUEST, seq, body)


def _bad_reply(where: str, command: str, expected: str, raw: bytes, what: str) -> BoothProtocolError:
    return BoothProtocolError(
        f"{where}: reply to {command} {what}: {raw[:80]!r}; expected {expected}",
        command=command,
        expected=expected,
        raw=raw,
    )


def parse_reply(frame: Frame, command: str, *, where: str = "booth") -> Reply:
    """Split a reply body and check that it answers ``command``.

    Raises
    ------
    BoothProtocolError
        If the body is neither ``OK <command> …`` nor ``ERR <command> <code> …``.
    """
    expected = f"'OK {command} …' or 'ERR {command} <code> <text>'"
    words = frame.body.split(" ")
    if len(words) >= 2 and words[0] == "OK" and words[1] == command:
        return Reply(ok=True, command=command, args=tuple(words[2:]), code=None, text="")
    if len(words) >= 3 and words[0] == "ERR" and words[1] in (command, "-"):
        return Reply(ok=False, command=words[1], args=(), code=words[2], text=" ".join(words[3:]))
    raise _bad_reply(where, command, expected, frame.raw, "has the wrong form")


def parse_event(frame: Frame, *, where: str = "booth") -> BoothEvent:
    """Turn an event frame into a :class:`BoothEvent`.

    Raises
    ------
    BoothProtocolError
        If the frame is not an event or has no name.
    """
    words = frame.body.split(" ")
    if frame.mark != MARK_EVENT or not words[0] or frame.seq == 0:
        raise BoothProtocolError(
            f"{where}: bad event {frame.raw[:80]!r}; expected '!<seq 01..FF>:…:<NAME> args…'",
            command=None,
            expected="!<seq>:<len>:<NAME> args…*<crc>",
            raw=frame.raw,
        )
    return BoothEvent(kind=words[0], seq=frame.seq, args=tuple(words[1:]), raw=frame.raw)


def level_to_code(level: float, *, index: int = 0) -> int:
    """Quantise an LED level in [0, 1] to a wire code 0..65535 (round to nearest).

    Raises
    ------
    ValueError
        If the level is not a finite number in [0, 1]; levels are never clipped silently.

    Examples
    --------
    >>> level_to_code(1.0), level_to_code(0.5), level_to_code(0.0)
    (65535, 32768, 0)
    """
    value = float(level)
    if not math.isfinite(value) or not 0.0 <= value <= 1.0:
        raise ValueError(f"LED level {index}: {level!r} out of range; expected a number in [0, 1]")
    return int(round(value * LEVEL_MAX))


def code_to_level(code: int) -> float:
    """The level in [0, 1] of a wire code 0..65535."""
    return code / LEVEL_MAX


def encode_levels(levels: Sequence[float], channels: int) -> list[str]:
    """Wire words (4 hex digits each) for one level per channel.

    Raises
    ------
    ValueError
        If the count differs from ``channels`` or a level is outside [0, 1].
    """
    if isinstance(levels, (str, bytes)) or len(levels) != channels:
        raise ValueError(f"LED levels: got {len(levels)} values; expected one per channel ({channels})")
    return [f"{level_to_code(x, index=i):04X}" for i, x in enumerate(levels)]


def _fields(args: Sequence[str], where: str, command: str, raw: bytes, required: Sequence[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for word in args:
        key, sep, value = word.partition("=")
        if not sep or not key:
            raise _bad_reply(where, command, "KEY=VALUE words", raw, f"has a word {word!r} without '='")
        out[key] = value
    missing = [k for k in required if k not in out]
    if missing:
        raise _bad_reply(where, command, f"fields {', '.join(required)}", raw, f"lacks {', '.join(missing)}")
    return out


def _decode_code(word: str) -> int:
    if len(word) != 4 or any(c not in "0123456789ABCDEF" for c in word):
        raise ValueError(word)
    return int(word, 16)


def parse_identify(reply: Reply, raw: bytes, *, where: str = "booth") -> BoothInfo:
    """Parse ``OK ID FW=… PROTO=… CH=… NAMES=a,b PEAKS=440,480 BITS=… STEPS=…``.

    Raises
    ------
    BoothProtocolError
        If a field is missing or malformed, or names/peaks do not match the channel count.
    """
    cmd = Command.IDENTIFY.value
    f = _fields(reply.args, where, cmd, raw, ("FW", "PROTO", "CH", "NAMES", "PEAKS", "BITS", "STEPS"))
    try:
        channels = int(f["CH"])
        names = tuple(f["NAMES"].split(","))
        peaks = tuple(float(p) for p in f["PEAKS"].split(","))
        info = BoothInfo(
            firmware=f["FW"],
            protocol=int(f["PROTO"]),
            channels=channels,
            names=names,
            peaks_nm=peaks,
            level_bits=int(f["BITS"]),
            max_steps=int(f["STEPS"]),
            serial=None if f.get("SERIAL", "-") == "-" else f["SERIAL"],
            dimming=f.get("DIM"),
            pwm_hz=float(f["PWMHZ"]) if "PWMHZ" in f else None,
        )
    except ValueError as err:
        raise _bad_reply(where, cmd, "integer CH/PROTO/BITS/STEPS and numeric PEAKS", raw, "has a bad number") from err
    if info.pwm_hz is not None and not (math.isfinite(info.pwm_hz) and info.pwm_hz > 0):
        raise _bad_reply(where, cmd, "PWMHZ a positive frequency", raw, "has a bad PWMHZ")
    if not 1 <= channels <= 64 or len(names) != channels or len(peaks) != channels:
        raise _bad_reply(
            where,
            cmd,
            "1..64 channels with one name and one peak each",
            raw,
            f"is inconsistent ({channels} channels, {len(names)} names, {len(peaks)} peaks)",
        )
    if not 12 <= info.level_bits <= LEVEL_BITS or info.max_steps < 1:
        raise _bad_reply(where, cmd, "BITS in 12..16 and STEPS >= 1", raw, "has out-of-range limits")
    return info


def parse_status(reply: Reply, raw: bytes, *, where: str = "booth") -> BoothStatus:
    """Parse ``OK STAT STATE=… MODE=… STEP=… STEPS=… TRIG=… WDOG=… ERR=… BAD=… LEVELS=…``.

    Raises
    ------
    BoothProtocolError
        If a field is missing or malformed.
    """
    cmd = Command.STATUS.value
    required = ("STATE", "MODE", "STEP", "STEPS", "TRIG", "WDOG", "ERR", "BAD", "LEVELS")
    f = _fields(reply.args, where, cmd, raw, required)
    try:
        levels = tuple(code_to_level(_decode_code(w)) for w in f["LEVELS"].split(","))
        status = BoothStatus(
            state=f["STATE"],
            mode=None if f["MODE"] == "-" else f["MODE"],
            step=int(f["STEP"]),
            steps=int(f["STEPS"]),
            trigger_count=int(f["TRIG"]),
            watchdog_s=int(f["WDOG"]) / 1000.0,
            levels=levels,
            last_error=None if f["ERR"] == "-" else f["ERR"],
            bad_frames=int(f["BAD"]),
        )
    except ValueError as err:
        raise _bad_reply(where, cmd, "integer fields and 4-hex-digit LEVELS", raw, "has a bad number") from err
    if status.state not in ("IDLE", "ARMED", "RUNNING", "DONE"):
        raise _bad_reply(where, cmd, "STATE one of IDLE, ARMED, RUNNING, DONE", raw, "has an unknown state")
    return status


EXPOSURE_FLAG = "EXP="
"""``PADD … EXP=<us>``, ``PSET … EXP=<us>``: the step's exposure, for pulse dimming (``docs/booth-protocol.md`` §4)."""
ON_FIELD = "ON="


def parse_on_times(
    args: Sequence[str], channels: int, raw: bytes, *, command: str, where: str = "booth"
) -> tuple[float, ...] | None:
    """The ``ON=<us>,…`` word of a ``PADD``/``PSET`` reply: each LED's on-time per exposure, or None.

    Raises
    ------
    BoothProtocolError
        If the word is there but not one non-negative number per channel.
    """
    words = [w for w in args if w.startswith(ON_FIELD)]
    if not words:
        return None
    try:
        values = tuple(float(v) for v in words[0][len(ON_FIELD) :].split(","))
    except ValueError:
        values = ()
    if len(values) != channels or not all(math.isfinite(v) and v >= 0 for v in values):
        raise _bad_reply(where, command, f"ON= with {channels} on-times in µs", raw, "has a bad ON=")
    return values


def parse_count(reply: Reply, raw: bytes, *, command: str, where: str = "booth") -> int:
    """Parse the single non-negative integer of a reply such as ``OK CNT 12``.

    Raises
    ------
    BoothProtocolError
        If the reply does not carry exactly one non-negative integer.
    """
    args = [a for a in reply.args if not a.startswith(ON_FIELD)]
    if len(args) != 1 or not args[0].isdigit():
        raise _bad_reply(where, command, f"'OK {command} <integer>'", raw, "lacks one integer")
    return int(args[0])
