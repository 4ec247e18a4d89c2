"""``BoothEmulator``: the booth firmware in Python, written from ``docs/booth-protocol.md``.

It parses frames with its own code (its own CRC table too) and shares only the name
constants with the driver, so a parser bug cannot look consistent on both sides. It models
the trigger line (``on_trigger_out`` for booth-master pulses, :meth:`exposure_active` for the
camera's ExposureActive line), a watchdog and timed sequences on an injectable clock, and
offers fault injection for tests. :func:`serve_on_pty` serves it on a real pseudo-terminal.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import random
import select
import termios
import threading
import time
import tty
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any

from msflash.led_controller.drive_waveform import (
    CLOCK_HZ,
    EXPOSURE_MAX_US,
    PULSE_FULL,
    Drive,
    DriveTrace,
    PulsePlan,
    exposure_code,
    on_time_text,
    pulse_plan,
    pwm_hz_text,
)
from msflash.led_controller.protocol import (
    EXPOSURE_FLAG,
    HOLD_FLAG,
    MARK_EVENT,
    MARK_REPLY,
    MARK_REQUEST,
    MAX_BODY,
    MAX_LINE,
    PROTOCOL_VERSION,
    SERIAL_MAX,
    SERIAL_UNSET,
    WATCHDOG_MAX_MS,
    WATCHDOG_MIN_MS,
    Command,
    ErrorCode,
    Event,
    Mode,
    serial_allowed,
    watchdog_ms_allowed,
)
from msflash.led_controller.stk500v2 import Stk500v2Bootloader
from msflash.led_controller.usb_link import (
    BOOTLOADER_BYTE_HOLD_S,
    FTDI_LATENCY_S,
    MEGA_BOOTLOADER_S,
    Bootloader,
    HeldReplies,
    PortOpenWatch,
)

log = logging.getLogger(__name__)

DEFAULT_NAMES = ("led440", "led480", "led500", "led520", "led596", "led636", "led660")
DEFAULT_PEAKS_NM = (440.0, 480.0, 500.0, 520.0, 596.0, 636.0, 660.0)
FULL_SCALE = 0xFFFF
_NOW_FLAG = "NOW"
"""``PSET … NOW``: start the step at once once the previous one was triggered (booth-protocol.md §5)."""
FIRE_LATENCY_US = (2.0, 8.0)
"""Camera master: how late the firmware's pulses start after ExposureActive rises (its interrupt
latency: 2.4 µs measured with the main loop asleep, more while it serves another interrupt;
docs/flash-energy.md). The emulator draws each fire's delay from this range."""
TRIGGER_FIRE_US = 0.25
"""Booth master: the firmware starts the pulse timers this long after raising the trigger output."""

Clock = Callable[[], float]


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def firmware_crc(data: bytes) -> int:
    """CRC-16/CCITT-FALSE, table-driven as the firmware computes it (independent of the driver's)."""
    crc = 0xFFFF
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]
    return crc


class ManualClock:
    """A clock that only moves when told to (inject into :class:`BoothEmulator` in tests)."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._now = float(start_s)
        self._lock = threading.Lock()

    def __call__(self) -> float:
        with self._lock:
            return self._now

    def advance(self, seconds: float) -> None:
        """Move the clock forward by ``seconds``."""
        if seconds < 0:
            raise ValueError(f"ManualClock.advance: {seconds} s; expected a non-negative duration")
        with self._lock:
            self._now += seconds


class _Refused(Exception):
    def __init__(self, code: ErrorCode, text: str) -> None:
        super().__init__(text)
        self.code = code
        self.text = text


@dataclass(frozen=True)
class EmulatorFault:
    """A pending fault: ``kind`` is drop, flip, garble_input or stall."""

    kind: str
    count: int = 1


FAULT_KINDS = ("drop", "drop_end", "flip", "garble_input", "stall", "close")


class BoothEmulator:
    """The msflash booth firmware, emulated.

    Parameters
    ----------
    names : sequence of str
        Channel names (their number is the channel count).
    peaks_nm : sequence of float
        Peak wavelength of each channel in nm.
    clock : callable returning float
        Monotonic seconds; inject a :class:`ManualClock` in tests.
    watchdog_s : float
        Host-silence timeout after which LEDs go off (0 disables); the host can change it.
    firmware : str
        Firmware name reported by ``ID`` (no spaces).
    max_steps : int
        Pattern table capacity.
    level_bits : int
        Reported drive resolution (12..16); levels are quantised to it.
    protocol : int
        Protocol version reported by ``ID`` (``PROTO=``); another than this emulator's own
        (:data:`~led_controller.protocol.PROTOCOL_VERSION`) plays a firmware the host must refuse.
    serial : str or None
        The serial in the board's EEPROM (``SERIAL=`` in ``ID``; None: never set, ``SERIAL=-``).
        ``SERIAL <text>`` changes it; resets keep it.
    seed : int
        Seed of the unkind parts of the drive model (the interrupt latency of a camera-master
        pulse, the timer prescaler's phase).

    Attributes
    ----------
    on_trigger_out : callable or None
        Called with the trigger count each time the booth pulses the camera's trigger line
        (booth-master mode). Runs on the emulator's thread with the booth's state consistent,
        so :attr:`levels` already holds the step being exposed; keep it short.
    """

    def __init__(
        self,
        *,
        names: Sequence[str] = DEFAULT_NAMES,
        peaks_nm: Sequence[float] = DEFAULT_PEAKS_NM,
        clock: Clock = time.monotonic,
        watchdog_s: float = 3.0,
        firmware: str = "msflash-emulator-0.1",
        max_steps: int = 256,
        level_bits: int = 16,
        protocol: int = PROTOCOL_VERSION,
        serial: str | None = None,
        seed: int = 0,
    ) -> None:
        if len(names) != len(peaks_nm) or not 1 <= len(names) <= 64:
            raise ValueError(
                f"BoothEmulator: {len(names)} names and {len(peaks_nm)} peaks; expected 1..64 of each, as many names as peaks"
            )
        if any(not n or " " in n or "," in n or "*" in n for n in names):
            raise ValueError(f"BoothEmulator: names {list(names)!r}; expected words without spaces, commas or '*'")
        if not 12 <= level_bits <= 16:
            raise ValueError(f"BoothEmulator: level_bits {level_bits}; expected 12..16")
        watchdog_ms = int(round(watchdog_s * 1000))
        if not watchdog_ms_allowed(watchdog_ms):  # what its own WDOG command accepts
            raise ValueError(f"BoothEmulator: watchdog_s {watchdog_s:g}; expected 0 (off) or 0.05..600 s")
        self.names = tuple(names)
        self.peaks_nm = tuple(float(p) for p in peaks_nm)
        self.channels = len(self.names)
        self.firmware = firmware
        self.max_steps = max_steps
        self.level_bits = level_bits
        self.protocol = int(protocol)
        self.on_trigger_out: Callable[[int], None] | None = None
        self._clock = clock
        self._lock = threading.RLock()
        self._out_lock = threading.Lock()
        self._output: Callable[[bytes], None] | None = None
        self._power_up_watchdog_ms = watchdog_ms
        if serial is not None and not serial_allowed(serial):
            raise ValueError(f"BoothEmulator: serial {serial!r}; expected 1..{SERIAL_MAX} of A-Z a-z 0-9 . _ -")
        self._serial = serial  # the board's EEPROM: kept across resets
        self.boots = 0
        """Times the firmware started since the emulator was made (:meth:`boot`)."""
        self.drive_trace = DriveTrace(self.channels)
        """What each LED pin does over time (PWM, pulses, on, off), on this emulator's clock; kept
        across resets (a reset shows as every LED off)."""
        self._rng = random.Random(seed)
        self._power_up_state()
        self._faults: list[EmulatorFault] = []
        self._stalled = False
        self._watchdog_fires = 0
        self.hangup_requested = threading.Event()
        self.fault_hook: Callable[[str], None] | None = None
        """Called with ``"request"`` for each line from the host (before it is read) and ``"send"``
        before each outgoing frame, on the emulator's thread with its lock held; it may call
        :meth:`inject_fault` (``led_controller.emulator_faults`` draws random faults this way)."""
        identify = self._cmd_identify([])
        if len(f"OK {Command.IDENTIFY} {identify}") + SERIAL_MAX - len(self._serial or SERIAL_UNSET) > MAX_BODY:
            raise ValueError(
                f"BoothEmulator: its ID reply would be {len(identify) + 6} bytes, over the protocol's "
                f"{MAX_BODY}; expected shorter or fewer names"
            )

    def _power_up_state(self) -> None:
        """Everything the firmware holds in RAM, as at power-up (LEDs off, no table, power-up watchdog)."""
        self._inbuf = bytearray()
        self._codes = [0] * self.channels
        self._pattern: list[list[int]] = []
        self._exposures: list[int] = []
        self._roll_us = 0
        self._armed: tuple[PulsePlan, str] | None = None
        self._stamp_at: float | None = None
        self._horizon = -math.inf
        self.last_trigger_s: float | None = None
        """Clock time of the last booth-master trigger pulse (its scheduled time), for the camera wired to it."""
        self._held: list[bool] = []
        self._holding = False
        self._state = "IDLE"
        self._mode: Mode | None = None
        self._settle_us = self._pulse_us = self._period_us = 0
        self._step = -1
        self._triggers = 0
        self._event_seq = 0
        self._watchdog_ms = self._power_up_watchdog_ms
        self._last_host = self._clock()
        self._watchdog_tripped = False
        self._last_error: str | None = None
        self._bad_frames = 0
        self._t0 = 0.0
        self._next_action: tuple[float, str] | None = None
        self._deferred: list[tuple[float, int, str]] = []
        self._discarding = False
        self._record_drive(None)  # pins are inputs at reset: every LED off from now

    # -- reset and boot (the board around the firmware: led_controller/usb_link.py) ------------

    def hold_in_reset(self) -> None:
        """The board is reset (its port was opened): pins are inputs, so the LEDs are off at once,
        and everything in RAM is lost. Nothing runs until :meth:`boot`."""
        with self._lock:
            self._power_up_state()

    def boot(self) -> None:
        """The firmware starts: power-up state (the serial, in EEPROM, is kept) and the boot banner,
        a line end then the ``BOOT`` event (``docs/booth-protocol.md`` §6)."""
        with self._lock:
            self._power_up_state()
            self.boots += 1
            self._event_seq = self._event_seq % 255 + 1
            self._send(b"\n" + _frame(MARK_EVENT, self._event_seq, self._boot_banner()))

    def _boot_banner(self) -> str:
        return f"{Event.BOOT} FW={self.firmware} PROTO={self.protocol}"

    @property
    def serial(self) -> str | None:
        """Get the serial set with ``SERIAL`` (None: never set)."""
        with self._lock:
            return self._serial

    # -- the camera side and observers ------------------------------------------------------

    @property
    def levels(self) -> tuple[float, ...]:
        """Get the LED levels now (tuple of float in [0, 1], one per channel); thread-safe."""
        with self._lock:
            return tuple(c / FULL_SCALE for c in self._codes)

    @property
    def state(self) -> str:
        """Get the sequencer state: IDLE, ARMED, RUNNING or DONE."""
        with self._lock:
            return self._state

    @property
    def trigger_count(self) -> int:
        """Get the triggers counted since the last ARM."""
        with self._lock:
            return self._triggers

    @property
    def holding(self) -> int | None:
        """Get the step the sequence is waiting at for its ``PSET`` (LEDs off), or None."""
        with self._lock:
            return self._step if self._holding else None

    @property
    def held_steps(self) -> tuple[int, ...]:
        """Get the table steps still held (loaded with ``PADD … HOLD`` and not yet ``PSET``)."""
        with self._lock:
            return tuple(i for i, held in enumerate(self._held) if held)

    def snapshot(self) -> dict:
        """The booth's state for an observer outside the link (``msflash booth-emulator --state-file``).

        Keys: ``state``, ``levels`` (in [0, 1]), ``leds_on``, ``watchdog_ms``, ``watchdog_fired`` (times
        the watchdog switched the LEDs off), ``bad_frames``, ``stalled``.
        """
        with self._lock:
            return {
                "state": self._state,
                "levels": [c / FULL_SCALE for c in self._codes],
                "leds_on": any(self._codes),
                "watchdog_ms": self._watchdog_ms,
                "watchdog_fired": self._watchdog_fires,
                "bad_frames": self._bad_frames,
                "stalled": self._stalled,
            }

    def next_due_s(self) -> float | None:
        """Seconds until the next timed action (booth-master step, delayed reply, watchdog), or None."""
        with self._lock:
            times = [d[0] for d in self._deferred]
            if self._next_action is not None:
                times.append(self._next_action[0])
            if self._watchdog_ms > 0 and not self._watchdog_tripped:
                times.append(self._last_host + self._watchdog_ms / 1000.0)
            return max(0.0, min(times) - self._clock()) if times else None

    def clock_s(self) -> float:
        """The emulator's clock now, seconds (its drive trace's time base)."""
        return self._clock()

    @property
    def real_time(self) -> bool:
        """Whether the emulator runs on the real monotonic clock (not a test's manual clock)."""
        return self._clock is time.monotonic

    @property
    def pattern(self) -> tuple[tuple[float, ...], ...]:
        """Get the loaded pattern table (levels in [0, 1])."""
        with self._lock:
            return tuple(tuple(c / FULL_SCALE for c in step) for step in self._pattern)

    def mean_levels(self, starts_s: Sequence[float], duration_s: float) -> list[list[float]]:
        """``[row][channel]``: each LED's mean level over ``[start, start + duration_s]`` (clock seconds).

        What a camera row exposed then collects from each LED, as a fraction of the LED on
        throughout: the PWM waveform with its phase, the pulses, the level changes in between
        (:class:`~led_controller.drive_waveform.DriveTrace`). Windows in the future assume the
        drive stays as it is now.
        """
        with self._lock:
            return self.drive_trace.mean_levels(starts_s, duration_s)

    def exposure_active(self, edge: bool, at_s: float | None = None) -> None:
        """Drive the camera's ExposureActive line (camera-master mode).

        A rising edge (``True``) counts a trigger and reports ``TRIG``; a falling edge
        (``False``, exposure ended) loads the next step, or switches off and reports ``DONE``
        after the last. Edges outside a running camera-master sequence are ignored. ``at_s`` dates
        the edge on the emulator's clock (a simulated camera's exposure starts and ends when it
        says, not when it calls); the drive changes it causes are dated from it.
        """
        with self._lock:
            if self._state != "RUNNING" or self._mode != Mode.CAMERA:
                return
            when = self._clock() if at_s is None else float(at_s)
            self._horizon = max(self._horizon, when)
            if edge and self._armed is not None and self._armed[1] == "exposure":
                self._fire(when + self._rng.uniform(*FIRE_LATENCY_US) * 1e-6)
            if edge:
                self._triggers += 1
                # An exposure during a held step (LEDs off, levels not given yet) is reported as
                # such, never as that step: the host must not take it for the step's frame.
                step = HOLD_FLAG if self._holding else str(self._step)
                self._event(f"{Event.TRIGGER} {self._triggers} {step}")
            elif self._roll_us:
                # A rolling shutter's flash window ends with its first row: the last row still exposes.
                self._next_action = (when + self._roll_us / 1e6, "advance")
            else:
                self._stamp_at = when
                try:
                    self._advance()
                finally:
                    self._stamp_at = None

    def camera_strobe(self) -> None:
        """One whole exposure on the ExposureActive line: a rising then a falling edge."""
        self.exposure_active(True)
        self.exposure_active(False)

    # -- faults -------------------------------------------------------------------------

    def inject_fault(self, kind: str, count: int = 1) -> None:
        """Arrange a fault on the link.

        ``drop``: drop one byte from each of the next ``count`` outgoing frames (``drop_end``: its
        line end, so the frame runs into the next one); ``flip``:
        flip one bit in each; ``garble_input``: flip one bit in the next ``count`` incoming
        frames; ``stall``: neither read nor answer until :meth:`resume` (the firmware keeps
        running, so its watchdog fires); ``close``: ask the transport to hang up.
        """
        if kind not in FAULT_KINDS:
            raise ValueError(f"inject_fault: kind {kind!r} unknown; expected one of {', '.join(FAULT_KINDS)}")
        with self._lock:
            if kind == "stall":
                self._stalled = True
            elif kind == "close":
                self.hangup_requested.set()
            else:
                self._faults.extend(EmulatorFault(kind) for _ in range(count))

    def resume(self) -> None:
        """End a stall; bytes that arrived meanwhile are lost (as on a stuck USB link)."""
        with self._lock:
            self._stalled = False

    def host_lost(self) -> None:
        """The link to the host is gone (unplug, hang-up): LEDs off, sequence aborted."""
        with self._lock:
            self._all_off()

    # -- the transport side -----------------------------------------------------------------

    def connect_output(self, write: Callable[[bytes], None] | None) -> None:
        """Set where outgoing bytes (replies and events) go."""
        with self._out_lock:
            self._output = write

    def receive(self, data: bytes) -> None:
        """Feed bytes from the host; complete frames are answered through the output."""
        with self._lock:
            if self._stalled:
                return
            self._inbuf += data
            while True:
                end = self._inbuf.find(b"\n")
                if end < 0:
                    break
                line = bytes(self._inbuf[:end])
                del self._inbuf[: end + 1]
                if self._discarding:  # the end of an over-long line, already answered
                    self._discarding = False
                    continue
                if len(line) > MAX_LINE:
                    self._reject(ErrorCode.LENGTH, "line too long")
                    continue
                if self.fault_hook is not None:
                    self.fault_hook("request")
                    if self._stalled or self.hangup_requested.is_set():
                        self._inbuf.clear()  # the firmware hung or the link went with this request
                        return
                line = self._apply_input_fault(line)
                self._handle_line(line)
            if len(self._inbuf) > MAX_LINE:
                # Too long to be a frame: throw it away up to its terminator and say so once.
                self._inbuf.clear()
                if not self._discarding:
                    self._discarding = True
                    self._reject(ErrorCode.LENGTH, "line too long")
            self.tick()

    def tick(self) -> None:
        """Run what is due on the clock: watchdog, booth-master steps, delayed replies."""
        with self._lock:
            now = self._clock()
            for entry in [d for d in self._deferred if d[0] <= now]:
                self._deferred.remove(entry)
                self._reply(entry[1], entry[2])
            while self._next_action is not None and self._next_action[0] <= now:
                self._run_action()
            if (
                self._watchdog_ms > 0
                and not self._watchdog_tripped
                and now - self._last_host >= self._watchdog_ms / 1000.0
            ):
                self._watchdog_tripped = True
                if any(self._codes) or self._state in ("ARMED", "RUNNING"):
                    self._all_off()
                    self._watchdog_fires += 1
                    self._event(str(Event.WATCHDOG))

    # -- parsing (the firmware's own) --------------------------------------------------

    def _apply_input_fault(self, line: bytes) -> bytes:
        for fault in self._faults:
            if fault.kind == "garble_input" and line:
                self._faults.remove(fault)
                flipped = bytearray(line)
                flipped[len(flipped) // 2] ^= 0x04
                return bytes(flipped)
        return line

    def _reject(self, code: ErrorCode, text: str) -> None:
        self._bad_frames += 1
        self._last_error = code.value
        self._reply(0, f"ERR - {code} {text}")

    def _handle_line(self, line: bytes) -> None:
        # Layout: '?' SS ':' LLL ':' body '*' CCCC — checked field by field, the way a
        # microcontroller would walk the buffer.
        if len(line) < 13:
            self._reject(ErrorCode.FRAME, "frame too short")
            return
        star = len(line) - 5
        if line[star] != ord("*"):
            self._reject(ErrorCode.FRAME, "no checksum field")
            return
        head, crc_text = line[:star], line[star + 1 :]
        if not _is_hex(crc_text):
            self._reject(ErrorCode.FRAME, "checksum not hex")
            return
        if firmware_crc(head) != int(crc_text, 16):
            self._reject(ErrorCode.CRC, "checksum mismatch")
            return
        if head[0] != ord(MARK_REQUEST) or head[3] != ord(":") or head[7] != ord(":"):
            self._reject(ErrorCode.FRAME, "bad header")
            return
        seq_text, len_text, body = head[1:3], head[4:7], head[8:]
        if not _is_hex(seq_text) or not _is_hex(len_text):
            self._reject(ErrorCode.FRAME, "header not hex")
            return
        if int(len_text, 16) != len(body) or len(body) > MAX_BODY:
            self._reject(ErrorCode.LENGTH, "length mismatch")
            return
        if any(b < 0x20 or b > 0x7E or b == 0x2A for b in body):
            self._reject(ErrorCode.FRAME, "body not printable")
            return
        seq = int(seq_text, 16)
        if seq == 0:
            self._reject(ErrorCode.FRAME, "sequence 00 is reserved")
            return
        # A valid frame from the host: feed the watchdog.
        self._last_host = self._clock()
        self._watchdog_tripped = False
        words = body.decode("ascii").split(" ")
        name, args = words[0], words[1:]
        handler = self._handlers().get(name)
        if handler is None:
            self._refuse(seq, name, ErrorCode.COMMAND, "unknown command")
            return
        try:
            result = handler(args)
        except _Refused as refusal:
            self._refuse(seq, name, refusal.code, refusal.text)
            return
        if isinstance(result, tuple):  # (delay_s, text): reply once the LEDs have settled
            delay_s, text = result
            self._deferred.append((self._clock() + delay_s, seq, f"OK {name} {text}".rstrip()))
            return
        self._reply(seq, f"OK {name} {result}".rstrip())

    def _refuse(self, seq: int, name: str, code: ErrorCode, text: str) -> None:
        self._last_error = code.value
        self._reply(seq, f"ERR {name} {code} {text}")

    def _handlers(self) -> dict[str, Callable[[list[str]], str | tuple[float, str]]]:
        return {
            Command.IDENTIFY: self._cmd_identify,
            Command.SET: self._cmd_set,
            Command.OFF: self._cmd_off,
            Command.PATTERN_CLEAR: self._cmd_pattern_clear,
            Command.PATTERN_ADD: self._cmd_pattern_add,
            Command.PATTERN_SET: self._cmd_pattern_set,
            Command.ARM: self._cmd_arm,
            Command.START: self._cmd_start,
            Command.NEXT: self._cmd_next,
            Command.COUNT: self._cmd_count,
            Command.STATUS: self._cmd_status,
            Command.WATCHDOG: self._cmd_watchdog,
            Command.PING: self._cmd_ping,
            Command.SERIAL: self._cmd_serial,
            Command.ROLL: self._cmd_roll,
        }

    # -- commands ----------------------------------------------------------------------

    def _no_args(self, args: list[str]) -> None:
        if args:
            raise _Refused(ErrorCode.ARGUMENT, "takes no arguments")

    def _levels_arg(self, args: list[str]) -> list[int]:
        if len(args) != self.channels:
            raise _Refused(ErrorCode.ARGUMENT, f"needs {self.channels} levels")
        if not all(len(a) == 4 and _is_hex(a.encode()) for a in args):
            raise _Refused(ErrorCode.ARGUMENT, "levels are 4 hex digits")
        drop = 16 - self.level_bits
        # The drive has level_bits of resolution: keep the top bits, as the PWM would.
        return [(int(a, 16) >> drop) * FULL_SCALE // ((1 << self.level_bits) - 1) for a in args]

    def _cmd_identify(self, args: list[str]) -> str:
        self._no_args(args)
        peaks = ",".join(f"{p:g}" for p in self.peaks_nm)
        return (
            f"FW={self.firmware} PROTO={self.protocol} CH={self.channels} "
            f"NAMES={','.join(self.names)} PEAKS={peaks} BITS={self.level_bits} STEPS={self.max_steps}"
            f"{self._dimming_words()}"
        ) + self._identify_serial()

    def _dimming_words(self) -> str:
        """The ID reply's dimming: pulses where the booth sees the exposure, PWM at ``PWMHZ`` otherwise."""
        return f" DIM=PULSE PWMHZ={pwm_hz_text(self.level_bits)}"

    def _cmd_set(self, args: list[str]) -> str:
        codes = self._levels_arg(args)
        if self._state == "RUNNING" and self._mode in (Mode.BOOTH, Mode.CAMERA):
            raise _Refused(ErrorCode.STATE, "sequence running")
        self._codes = codes
        self._record_drive(None)
        return ""

    def _cmd_off(self, args: list[str]) -> str:
        self._no_args(args)
        self._all_off()
        return ""

    def _cmd_pattern_clear(self, args: list[str]) -> str:
        self._no_args(args)
        self._editable()
        self._pattern = []
        self._exposures = []
        self._held = []
        return ""

    def _exposure_arg(self, word: str) -> int:
        """``EXP=<us>``: the exposure's code (as the firmware stores it)."""
        text = word[len(EXPOSURE_FLAG) :]
        if not text.isdigit() or len(text) > 8:
            raise _Refused(ErrorCode.ARGUMENT, "EXP=<microseconds>")
        if int(text) == 0:
            raise _Refused(ErrorCode.RANGE, f"exposure 1..{EXPOSURE_MAX_US} us")
        return exposure_code(int(text))

    def _on_words(self, codes: list[int], exposure: int) -> str:
        """`` ON=…`` for a step the booth will pulse (booth and camera master), else empty."""
        plan = pulse_plan(self._duties(codes), self._top, exposure, self._roll_us, camera=False)
        if plan is None:
            return ""
        return " ON=" + ",".join(on_time_text(on) for on in plan.on_us(exposure))

    def _cmd_pattern_add(self, args: list[str]) -> str:
        words = len(args)
        held = self.channels < words <= self.channels + 4 and args[words - 1] == HOLD_FLAG
        if held:
            words -= 1
        timed = self.channels < words <= self.channels + 4 and args[words - 1].startswith(EXPOSURE_FLAG)
        if timed:
            words -= 1
        codes = self._levels_arg(args[:words])
        exposure = self._exposure_arg(args[words]) if timed else 0
        self._editable()
        if len(self._pattern) >= self.max_steps:
            raise _Refused(ErrorCode.FULL, "pattern table full")
        self._pattern.append(codes)
        self._exposures.append(exposure)
        self._held.append(held)
        return f"{len(self._pattern) - 1}{self._on_words(codes, exposure)}"

    def _cmd_pattern_set(self, args: list[str]) -> str:
        limit = self.channels + 4
        now = self.channels + 1 < len(args) <= limit and args[-1] == _NOW_FLAG
        if now:
            args = args[:-1]
        timed = self.channels + 1 < len(args) <= limit and args[-1].startswith(EXPOSURE_FLAG)
        exposure_word = args[-1] if timed else ""
        if timed:
            args = args[:-1]
        if len(args) != self.channels + 1 or not args[0].isdigit() or len(args[0]) > 5:
            raise _Refused(ErrorCode.ARGUMENT, f"PSET <step> and {self.channels} levels [EXP=<us>] [NOW]")
        index = int(args[0])
        codes = self._levels_arg(args[1:])
        exposure = self._exposure_arg(exposure_word) if timed else 0
        if index >= len(self._pattern):
            raise _Refused(ErrorCode.RANGE, "no such step")
        running = self._state == "RUNNING"
        if running and (index < self._step or (index == self._step and not self._holding)):
            raise _Refused(ErrorCode.STATE, "step already exposed")
        self._pattern[index] = codes
        self._exposures[index] = exposure
        self._held[index] = False
        on = self._on_words(codes, exposure)
        if running and self._holding and index == self._step:
            self._release_hold()
        elif (
            now
            and running
            and self._mode == Mode.BOOTH
            and index == self._step + 1
            and self._next_action is not None
            and self._next_action[1] == "apply"
        ):
            # NOW: the previous step has been triggered and the host has its frame (its exposure
            # is over): this step's slot starts at once rather than at its scheduled time.
            self._apply_step(index)
            self._release_hold()
        return on.strip()

    def _editable(self) -> None:
        if self._state in ("ARMED", "RUNNING"):
            raise _Refused(ErrorCode.STATE, "table in use")

    def _cmd_arm(self, args: list[str]) -> str:
        if len(args) != 4 or args[0] not in (Mode.HOST, Mode.BOOTH, Mode.CAMERA):
            raise _Refused(ErrorCode.ARGUMENT, "ARM HOST|BOOTH|CAMERA settle_us pulse_us period_us")
        if not all(a.isdigit() and len(a) <= 8 for a in args[1:]):
            raise _Refused(ErrorCode.ARGUMENT, "times are decimal microseconds")
        settle, pulse, period = (int(a) for a in args[1:])
        if self._state == "RUNNING":
            raise _Refused(ErrorCode.STATE, "sequence running")
        mode = Mode(args[0])
        if mode != Mode.HOST and not self._pattern:
            raise _Refused(ErrorCode.STATE, "pattern table empty")
        if mode == Mode.BOOTH and (period == 0 or period < settle + pulse):
            raise _Refused(ErrorCode.RANGE, "period shorter than settle plus pulse")
        self._mode, self._settle_us, self._pulse_us, self._period_us = mode, settle, pulse, period
        self._state, self._step, self._triggers = "ARMED", -1, 0
        self._holding = False
        return ""

    def _cmd_start(self, args: list[str]) -> str:
        self._no_args(args)
        if self._state != "ARMED":
            raise _Refused(ErrorCode.STATE, "not armed")
        self._state = "RUNNING"
        if self._mode == Mode.CAMERA:
            self._apply_step(0)
        elif self._mode == Mode.BOOTH:
            self._t0 = self._clock()
            self._next_action = (self._t0, "apply")
        return ""

    def _cmd_next(self, args: list[str]) -> str | tuple[float, str]:
        self._no_args(args)
        if self._state != "RUNNING" or self._mode != Mode.HOST:
            raise _Refused(ErrorCode.STATE, "not running in HOST mode")
        if not self._pattern or self._step + 1 >= len(self._pattern):
            self._finish()
            return "DONE"
        if self._held[self._step + 1]:
            raise _Refused(ErrorCode.STATE, "next step held; expected PSET first")
        self._apply_step(self._step + 1)
        self._triggers += 1
        return (self._settle_us / 1e6, str(self._step))

    def _cmd_count(self, args: list[str]) -> str:
        self._no_args(args)
        return str(self._triggers)

    def _cmd_status(self, args: list[str]) -> str:
        self._no_args(args)
        return (
            f"STATE={self._state} MODE={self._mode or '-'} STEP={self._step} STEPS={len(self._pattern)} "
            f"TRIG={self._triggers} WDOG={self._watchdog_ms} ERR={self._last_error or '-'} "
            f"BAD={self._bad_frames} LEVELS={','.join(f'{c:04X}' for c in self._codes)}"
        )

    def _cmd_watchdog(self, args: list[str]) -> str:
        if len(args) != 1 or not args[0].isdigit() or len(args[0]) > 7:
            raise _Refused(ErrorCode.ARGUMENT, "WDOG <milliseconds>")
        ms = int(args[0])
        if not watchdog_ms_allowed(ms):
            raise _Refused(ErrorCode.RANGE, f"0 or {WATCHDOG_MIN_MS}..{WATCHDOG_MAX_MS} ms")
        self._watchdog_ms = ms
        return str(ms)

    def _cmd_roll(self, args: list[str]) -> str:
        if len(args) != 1 or not args[0].isdigit() or len(args[0]) > 8:
            raise _Refused(ErrorCode.ARGUMENT, "ROLL <microseconds>")
        if self._state == "RUNNING":
            raise _Refused(ErrorCode.STATE, "sequence running")
        self._roll_us = int(args[0])
        return args[0].lstrip("0") or "0"

    def _cmd_ping(self, args: list[str]) -> str:
        self._no_args(args)
        return ""

    # -- the serial in EEPROM (SERIAL, SERIAL= in ID) ------------------------------------------

    def _identify_serial(self) -> str:
        return f" SERIAL={self._serial or SERIAL_UNSET}"

    def _cmd_serial(self, args: list[str]) -> str:
        if not args:
            return self._serial or SERIAL_UNSET
        if len(args) != 1 or not serial_allowed(args[0]):
            raise _Refused(ErrorCode.ARGUMENT, f"SERIAL [1..{SERIAL_MAX} of A-Z a-z 0-9 . _ -]")
        if self._state in ("ARMED", "RUNNING"):
            raise _Refused(ErrorCode.STATE, "sequence armed or running")
        self._serial = args[0]
        return args[0]

    # -- sequencing -------------------------------------------------------------------

    # -- the drive model (what the pins do, for a camera integrating them) --------------------

    @property
    def _top(self) -> int:
        return (1 << self.level_bits) - 1

    def _duties(self, codes: Sequence[int]) -> list[int]:
        """The drive values (``level_bits`` wide) of wire-scaled codes."""
        return [round(c * self._top / FULL_SCALE) for c in codes]

    def _stamp(self) -> float:
        """When a drive change happens: the scheduled time of the action being run, else now (never
        before a change already dated by a camera's exposure edge)."""
        now = self._stamp_at if self._stamp_at is not None else self._clock()
        return max(now, self._horizon)

    def _record_drive(self, index: int | None) -> None:
        """The LEDs now show ``self._codes``: pulses for table step ``index`` in booth and camera
        master when it has an exposure, PWM otherwise (as the firmware's ``drive_step``)."""
        t = self._stamp()
        duties = self._duties(self._codes)
        plan = None
        if index is not None and self._mode in (Mode.BOOTH, Mode.CAMERA) and index < len(self._exposures):
            plan = pulse_plan(duties, self._top, self._exposures[index], self._roll_us, self._mode == Mode.CAMERA)
        if plan is not None:
            for c, width in enumerate(plan.widths):
                self.drive_trace.set(c, Drive(t, "level", high=1.0 if width == PULSE_FULL else 0.0))
            self._armed = (plan, "exposure" if self._mode == Mode.CAMERA else "trigger")
            return
        self._armed = None
        period = (self._top + 1) / CLOCK_HZ
        for c, duty in enumerate(duties):
            if duty == 0 or duty >= self._top:
                self.drive_trace.set(c, Drive(t, "level", high=0.0 if duty == 0 else 1.0))
            else:  # the counters restart one clock after the write (firmware: TCNT = TOP)
                compare = duty - 1 + (duty > self._top // 2)  # the firmware's pwm_ocr
                fraction = (compare + 1) / (self._top + 1)
                self.drive_trace.set(c, Drive(t, "pwm", duty=fraction, period_s=period, origin_s=t + 1 / CLOCK_HZ))

    def _fire(self, when: float) -> None:
        """The armed pulses start at ``when``: each on for its width, ending ``window`` ticks on."""
        assert self._armed is not None
        plan = self._armed[0]
        self._armed = None
        tick = plan.tick_s
        start = when + self._rng.uniform(0.0, tick)  # the first timer clock: the prescaler's phase
        for c, width in enumerate(plan.widths):
            if 0 < width < PULSE_FULL:
                off = start + (plan.window - 1) * tick
                self.drive_trace.set(c, Drive(when, "pulse", on_s=off - width * tick, off_s=off))

    # -- sequencing -------------------------------------------------------------------

    def _apply_step(self, index: int) -> bool:
        """Apply step ``index``; a held step instead waits for its PSET with the LEDs off (False)."""
        self._step = index
        if self._held[index]:
            self._holding = True
            self._codes = [0] * self.channels
            self._record_drive(None)
            return False
        self._holding = False
        self._codes = list(self._pattern[index])
        self._record_drive(index)
        return True

    def _release_hold(self) -> None:
        """PSET reached the step being held: apply it now and carry on from here."""
        self._holding = False
        self._codes = list(self._pattern[self._step])
        self._record_drive(self._step)
        if self._mode == Mode.BOOTH:
            now = self._clock()
            # The step's slot starts now: settle, pulse, and the later steps keep their period.
            self._t0 = now - self._step * self._period_us / 1e6
            self._next_action = (now + self._settle_us / 1e6, "pulse")

    def _advance(self) -> None:
        if self._step + 1 >= len(self._pattern):
            self._finish()
        else:
            self._apply_step(self._step + 1)

    def _finish(self) -> None:
        self._codes = [0] * self.channels
        self._record_drive(None)
        self._state = "DONE"
        self._holding = False
        self._next_action = None
        self._event(f"{Event.DONE} {self._triggers}")

    def _all_off(self) -> None:
        self._codes = [0] * self.channels
        self._record_drive(None)
        self._holding = False
        self._next_action = None
        if self._state in ("ARMED", "RUNNING"):
            self._state = "IDLE"

    def _run_action(self) -> None:
        assert self._next_action is not None
        self._stamp_at = self._next_action[0]
        try:
            self._run_action_at()
        finally:
            self._stamp_at = None

    def _run_action_at(self) -> None:
        assert self._next_action is not None
        when, kind = self._next_action
        period = self._period_us / 1e6
        if kind == "advance":  # camera master, a rolling shutter's last row over
            self._next_action = None
            self._advance()
            return
        if kind == "apply":
            index = self._step + 1
            if index >= len(self._pattern):
                self._finish()
                return
            if not self._apply_step(index):
                self._next_action = None  # held: PSET resumes the sequence (_release_hold)
                return
            self._next_action = (self._t0 + index * period + self._settle_us / 1e6, "pulse")
        else:
            self._triggers += 1
            self.last_trigger_s = when
            if self._armed is not None and self._armed[1] == "trigger":
                self._fire(when + TRIGGER_FIRE_US * 1e-6)
            # The pulse first, then its report, as the firmware does: the report's write to the
            # host may block or yield the GIL to another thread, which must not delay the pulse.
            callback = self.on_trigger_out
            if callback is not None:
                callback(self._triggers)
            self._event(f"{Event.TRIGGER} {self._triggers} {self._step}")
            self._next_action = (self._t0 + (self._step + 1) * period, "apply")

    # -- output ----------------------------------------------------------------------

    def _event(self, body: str) -> None:
        self._event_seq = self._event_seq % 255 + 1
        self._send(_frame(MARK_EVENT, self._event_seq, body))

    def _reply(self, seq: int, body: str) -> None:
        self._send(_frame(MARK_REPLY, seq, body))

    def _send(self, frame: bytes) -> None:
        if self.fault_hook is not None:
            self.fault_hook("send")
        if self._stalled:
            return
        for fault in self._faults:
            if fault.kind in ("drop", "drop_end", "flip"):
                self._faults.remove(fault)
                data = bytearray(frame)
                middle = len(data) // 2
                if fault.kind == "drop":
                    del data[middle]
                elif fault.kind == "drop_end":
                    del data[-1]
                else:
                    data[middle] ^= 0x10
                frame = bytes(data)
                break
        with self._out_lock:
            output = self._output
            if output is None:
                return
            output(frame)


def _is_hex(text: bytes) -> bool:
    return bool(text) and all(chr(b) in "0123456789ABCDEF" for b in text)


def _frame(mark: str, seq: int, body: str) -> bytes:
    payload = body.encode("ascii")
    if len(payload) > MAX_BODY:  # the firmware's buffer: never a longer frame than the protocol allows
        payload = b"ERR - %s reply longer than %d bytes" % (ErrorCode.LENGTH.value.encode(), MAX_BODY)
    head = b"%s%02X:%03X:%s" % (mark.encode("ascii"), seq, len(payload), payload)
    return head + b"*%04X\n" % firmware_crc(head)


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
        self._master, self._slave = os.openpty()
        # Raw mode before anyone opens the slave: no echo, no line editing, no CR/LF mapping.
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self.auto_reset = bool(auto_reset)
        self.resets = 0
        """Times a host's open reset the board."""
        self._bootloader = Bootloader(window_s=float(bootloader_s))
        self.programmer = Stk500v2Bootloader()
        """The bootloader's STK500v2 side: what avrdude flashed while the board was in its bootloader."""
        self._held = HeldReplies(latency_s, time.monotonic())
        self._host_opens = 0
        self._opens_lock = threading.Lock()
        # Watch the slave node before its path is handed out: every host open is seen (Linux only).
        self._watch: PortOpenWatch | None = PortOpenWatch(self.port)
        self._wake_r, self._wake_w = os.pipe()
        self._stop = threading.Event()
        self._closed = False
        self._close_lock = threading.Lock()
        emulator.connect_output(self._write)
        emulator.boot()  # powered up: the banner goes nowhere, no host has the port open yet
        self._thread = threading.Thread(target=self._run, name=f"booth-emulator {self.port}", daemon=True)
        self._thread.start()
        log.info("booth emulator serving on %s", self.port)

    @property
    def in_bootloader(self) -> bool:
        """Get whether the board is in its bootloader now (reset by an open, firmware not yet running)."""
        return self._bootloader.running(time.monotonic())

    @property
    def host_open(self) -> bool:
        """Get whether a host holds the port open."""
        with self._opens_lock:
            return self._host_opens > 0

    def _port_events(self) -> None:
        assert self._watch is not None
        for change in self._watch.changes():
            with self._opens_lock:
                was = self._host_opens
                self._host_opens = max(0, was + change)
            if change > 0 and was == 0:
                # DTR asserted by the open: the Mega's reset (a second open finds DTR already up).
                self._held.clear()
                if self.auto_reset:
                    self.resets += 1
                    self.emulator.hold_in_reset()
                    self.programmer.reset()
                    self._bootloader.reset(time.monotonic())
                    log.debug("booth emulator %s: reset by the port's open", self.port)
            elif change < 0 and was == 1:
                # The host's last close: what it did not read is gone, as the kernel frees a closed tty's buffers.
                self._held.clear()
                with contextlib.suppress(termios.error, OSError):
                    termios.tcflush(self._slave, termios.TCIFLUSH)

    def _run(self) -> None:
        watch_fd = self._watch.fileno() if self._watch is not None else -1
        while not self._stop.is_set():
            try:
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
                ready, _, _ = select.select([self._master, self._wake_r, watch_fd], [], [], max(0.0, min(waits)))
                if self._wake_r in ready:
                    os.read(self._wake_r, 4096)
                if watch_fd in ready:
                    self._port_events()
                if self._master in ready:
                    data = os.read(self._master, 4096)
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
        if self._watch is not None and not self.host_open:
            return  # nobody has the port open: a USB-serial chip drops what the board sends
        if self._held.latency_s > 0:
            self._held.hold(data, time.monotonic())
            if threading.current_thread() is not self._thread:
                with contextlib.suppress(OSError):
                    os.write(self._wake_w, b"w")  # the serving thread sends it on the timer's tick
            return
        self._write_now(data)

    def _flush_held(self) -> None:
        data = self._held.take(time.monotonic())
        if data:
            self._write_now(data)

    def _write_now(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                written = os.write(self._master, view)
            except OSError:
                return  # the pty is gone: the host sees a dead link, as with an unplugged booth
            view = view[written:]

    def hangup(self) -> None:
        """Close the pty as an unplugged booth would (the host's next read fails)."""
        self._shutdown(from_thread=False)

    def close(self) -> None:
        """Stop serving and close the pty; the emulator's LEDs go off."""
        self._shutdown(from_thread=False)

    def _shutdown(self, *, from_thread: bool) -> None:
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        self._stop.set()
        os.write(self._wake_w, b"x")
        if not from_thread:
            self._thread.join(timeout=2.0)
        self.emulator.connect_output(None)
        self.emulator.host_lost()
        if self._watch is not None:
            self._watch.close()
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    @property
    def closed(self) -> bool:
        """Get whether the pty has been closed (bool)."""
        return self._closed

    def __enter__(self) -> PtyBoothServer:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
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

    Parameters
    ----------
    emulator : BoothEmulator or None
        The emulator to serve; a new one is built from ``kwargs`` if None.
    auto_reset, bootloader_s, latency_s
        The link: reset on every open and its bootloader window, the USB latency timer.
    **kwargs
        Arguments of :class:`BoothEmulator` (only when ``emulator`` is None).

    Returns
    -------
    PtyBoothServer
        Has ``.port`` (the path to open), ``.emulator`` and ``.close()``.
    """
    if emulator is None:
        emulator = BoothEmulator(**kwargs)
    elif kwargs:
        raise ValueError("serve_on_pty: got an emulator and emulator arguments; expected one or the other")
    return PtyBoothServer(emulator, auto_reset=auto_reset, bootloader_s=bootloader_s, latency_s=latency_s)
