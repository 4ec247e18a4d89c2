"""``BoothEmulator``: the booth firmware in Python, written from ``docs/booth-protocol.md``.

It parses frames with its own code (``emulator_wire.py``, its own CRC table too) and shares only
the name constants with the driver, so a parser bug cannot look consistent on both sides. Its
commands are ``emulator_commands.py``, its RAM, sequencer, watchdog and LED drive model
``emulator_sequencer.py`` (the trigger line: ``on_trigger_out`` for booth-master pulses,
:meth:`~BoothEmulator.exposure_active` for the camera's ExposureActive line), all on an injectable
clock. This module is the firmware's link side: bytes in, frames out, boot and reset, and the
faults a test injects on the link. ``emulator_pty.py`` serves it on a real pseudo-terminal.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable, Sequence

from msflash.led_controller.drive_waveform import DriveTrace
from msflash.led_controller.emulator_commands import FirmwareCommands, Refused
from msflash.led_controller.emulator_sequencer import FULL_SCALE, Clock
from msflash.led_controller.emulator_wire import FrameRejected, encode_frame, read_request
from msflash.led_controller.protocol import (
    MARK_EVENT,
    MARK_REPLY,
    MAX_BODY,
    MAX_LINE,
    PROTOCOL_VERSION,
    SERIAL_MAX,
    SERIAL_UNSET,
    Command,
    ErrorCode,
    Event,
    serial_allowed,
    watchdog_ms_allowed,
)

DEFAULT_NAMES = ("led440", "led480", "led500", "led520", "led596", "led636", "led660")
DEFAULT_PEAKS_NM = (440.0, 480.0, 500.0, 520.0, 596.0, 636.0, 660.0)
FAULT_KINDS = ("drop", "drop_end", "flip", "garble_input", "stall", "close")
"""What :meth:`BoothEmulator.inject_fault` arranges."""


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


class BoothEmulator(FirmwareCommands):
    """The msflash booth firmware, emulated.

    Parameters
    ----------
    clock
        Monotonic seconds; inject a :class:`ManualClock` in tests.
    watchdog_s
        Host-silence timeout after which LEDs go off (0 disables); the host can change it.
    level_bits
        Reported drive resolution (12..16); levels are quantised to it.
    protocol
        ``PROTO=`` in ``ID``; another than :data:`~led_controller.protocol.PROTOCOL_VERSION`
        plays a firmware the host must refuse.
    serial
        ``SERIAL=`` in ``ID`` (None: never set, ``SERIAL=-``); ``SERIAL <text>`` changes it,
        resets keep it.
    seed
        Seed of the unkind parts of the drive model (a camera-master pulse's interrupt latency,
        the timer prescaler's phase).

    Attributes
    ----------
    on_trigger_out
        Called with the trigger count each time the booth pulses the camera's trigger line
        (booth master), on the emulator's thread once :attr:`levels` holds the step being
        exposed; keep it short.
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
        if serial is not None and not serial_allowed(serial):
            raise ValueError(f"BoothEmulator: serial {serial!r}; expected 1..{SERIAL_MAX} of A-Z a-z 0-9 . _ -")
        self.names = tuple(names)
        self.peaks_nm = tuple(float(p) for p in peaks_nm)
        self.channels = len(self.names)
        self.firmware = firmware
        self.max_steps = max_steps
        self.level_bits = level_bits
        self.protocol = int(protocol)
        self.on_trigger_out = None
        self._clock = clock
        self._lock = threading.RLock()
        self._out_lock = threading.Lock()
        self._output: Callable[[bytes], None] | None = None
        self._power_up_watchdog_ms = watchdog_ms
        self._serial = serial  # the board's EEPROM: kept across resets
        self.boots = 0
        """Times the firmware started since the emulator was made (:meth:`boot`)."""
        self.drive_trace = DriveTrace(self.channels)
        """What each LED pin does over time (PWM, pulses, on, off), on this emulator's clock; kept
        across resets (a reset shows as every LED off)."""
        self._rng = random.Random(seed)
        self._power_up_state()
        self._faults: list[str] = []
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
            banner = f"{Event.BOOT} FW={self.firmware} PROTO={self.protocol}"
            self._send(b"\n" + encode_frame(MARK_EVENT, self._event_seq, banner))

    @property
    def serial(self) -> str | None:
        """Get the serial set with ``SERIAL`` (None: never set)."""
        with self._lock:
            return self._serial

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
                self._faults.extend([kind] * count)

    def resume(self) -> None:
        """End a stall; bytes that arrived meanwhile are lost (as on a stuck USB link)."""
        with self._lock:
            self._stalled = False

    def host_lost(self) -> None:
        """The link to the host is gone (unplug, hang-up): LEDs off, sequence aborted."""
        with self._lock:
            self._all_off()

    def _take_fault(self, kinds: tuple[str, ...]) -> str | None:
        """The first pending fault of one of ``kinds``, taken off the list, or None."""
        for kind in self._faults:
            if kind in kinds:
                self._faults.remove(kind)
                return kind
        return None

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
                if line and self._take_fault(("garble_input",)):
                    line = _flip_bit(line, 0x04)
                self._handle_line(line)
            if len(self._inbuf) > MAX_LINE:
                # Too long to be a frame: throw it away up to its terminator and say so once.
                self._inbuf.clear()
                if not self._discarding:
                    self._discarding = True
                    self._reject(ErrorCode.LENGTH, "line too long")
            self.tick()

    def _reject(self, code: ErrorCode, text: str) -> None:
        self._bad_frames += 1
        self._last_error = code.value
        self._reply(0, f"ERR - {code} {text}")

    def _handle_line(self, line: bytes) -> None:
        try:
            request = read_request(line)
        except FrameRejected as rejected:
            self._reject(rejected.code, rejected.text)
            return
        # A valid frame from the host: feed the watchdog.
        self._last_host = self._clock()
        self._watchdog_tripped = False
        seq, name = request.seq, request.name
        handler = self._handlers().get(name)
        try:
            if handler is None:
                raise Refused(ErrorCode.COMMAND, "unknown command")
            result = handler(request.args)
        except Refused as refusal:
            self._last_error = refusal.code.value
            self._reply(seq, f"ERR {name} {refusal.code} {refusal.text}")
            return
        if isinstance(result, tuple):  # (delay_s, text): reply once the LEDs have settled
            delay_s, text = result
            self._deferred.append((self._clock() + delay_s, seq, f"OK {name} {text}".rstrip()))
            return
        self._reply(seq, f"OK {name} {result}".rstrip())

    # -- output ----------------------------------------------------------------------

    def _event(self, body: str) -> None:
        self._event_seq = self._event_seq % 255 + 1
        self._send(encode_frame(MARK_EVENT, self._event_seq, body))

    def _reply(self, seq: int, body: str) -> None:
        self._send(encode_frame(MARK_REPLY, seq, body))

    def _send(self, frame: bytes) -> None:
        if self.fault_hook is not None:
            self.fault_hook("send")
        if self._stalled:
            return
        fault = self._take_fault(("drop", "drop_end", "flip"))
        if fault == "flip":
            frame = _flip_bit(frame, 0x10)
        elif fault is not None:  # drop: a byte from the middle; drop_end: the line end
            frame = frame[:-1] if fault == "drop_end" else frame[: len(frame) // 2] + frame[len(frame) // 2 + 1 :]
        with self._out_lock:
            output = self._output
            if output is not None:
                output(frame)


def _flip_bit(data: bytes, mask: int) -> bytes:
    """``data`` with the bits of ``mask`` flipped in its middle byte (a fault on the line)."""
    flipped = bytearray(data)
    flipped[len(flipped) // 2] ^= mask
    return bytes(flipped)
