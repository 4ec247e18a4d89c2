"""The commands the emulated firmware answers (``docs/booth-protocol.md`` §4), one method each.

:class:`FirmwareCommands` is the command table (:meth:`~FirmwareCommands._handlers`): each handler
takes the request's argument words, checks them as the firmware does and returns the reply's text,
a ``(delay_s, text)`` pair for a reply sent once the LEDs have settled (``NEXT``), or raises
:class:`Refused` with the ``ERR`` code and text. The state they change is the
:class:`~led_controller.emulator_sequencer.Sequencer`'s.
"""

from __future__ import annotations

from collections.abc import Callable

from msflash.led_controller.drive_waveform import EXPOSURE_MAX_US, exposure_code, on_time_text, pulse_plan, pwm_hz_text
from msflash.led_controller.emulator_sequencer import FULL_SCALE, Sequencer
from msflash.led_controller.emulator_wire import is_hex
from msflash.led_controller.protocol import (
    EXPOSURE_FLAG,
    HOLD_FLAG,
    SERIAL_MAX,
    SERIAL_UNSET,
    WATCHDOG_MAX_MS,
    WATCHDOG_MIN_MS,
    Command,
    ErrorCode,
    Mode,
    serial_allowed,
    watchdog_ms_allowed,
)

NOW_FLAG = "NOW"
"""``PSET … NOW``: start the step at once once the previous one was triggered (booth-protocol.md §5)."""

Handler = Callable[[list[str]], str | tuple[float, str]]


class Refused(Exception):
    """A command the booth refuses: the ``ERR`` reply's code and text."""

    def __init__(self, code: ErrorCode, text: str) -> None:
        super().__init__(text)
        self.code = code
        self.text = text


class FirmwareCommands(Sequencer):
    """The firmware's command table over its RAM and sequencer."""

    names: tuple[str, ...]
    peaks_nm: tuple[float, ...]
    firmware: str
    protocol: int
    max_steps: int
    _serial: str | None

    def _handlers(self) -> dict[str, Handler]:
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
            Command.PING: self._no_args,
            Command.SERIAL: self._cmd_serial,
            Command.ROLL: self._cmd_roll,
        }

    # -- arguments ------------------------------------------------------------------------

    def _no_args(self, args: list[str]) -> str:
        if args:
            raise Refused(ErrorCode.ARGUMENT, "takes no arguments")
        return ""

    def _levels_arg(self, args: list[str]) -> list[int]:
        if len(args) != self.channels:
            raise Refused(ErrorCode.ARGUMENT, f"needs {self.channels} levels")
        if not all(len(a) == 4 and is_hex(a.encode()) for a in args):
            raise Refused(ErrorCode.ARGUMENT, "levels are 4 hex digits")
        drop = 16 - self.level_bits
        # The drive has level_bits of resolution: keep the top bits, as the PWM would.
        return [(int(a, 16) >> drop) * FULL_SCALE // ((1 << self.level_bits) - 1) for a in args]

    def _exposure_arg(self, word: str) -> int:
        """``EXP=<us>``: the exposure's code (as the firmware stores it)."""
        text = word[len(EXPOSURE_FLAG) :]
        if not text.isdigit() or len(text) > 8:
            raise Refused(ErrorCode.ARGUMENT, "EXP=<microseconds>")
        if int(text) == 0:
            raise Refused(ErrorCode.RANGE, f"exposure 1..{EXPOSURE_MAX_US} us")
        return exposure_code(int(text))

    def _editable(self) -> None:
        if self._state in ("ARMED", "RUNNING"):
            raise Refused(ErrorCode.STATE, "table in use")

    # -- identity -------------------------------------------------------------------------

    def _cmd_identify(self, args: list[str]) -> str:
        self._no_args(args)
        peaks = ",".join(f"{p:g}" for p in self.peaks_nm)
        return (
            f"FW={self.firmware} PROTO={self.protocol} CH={self.channels} "
            f"NAMES={','.join(self.names)} PEAKS={peaks} BITS={self.level_bits} STEPS={self.max_steps}"
            f" DIM=PULSE PWMHZ={pwm_hz_text(self.level_bits)} SERIAL={self._serial or SERIAL_UNSET}"
        )

    def _cmd_serial(self, args: list[str]) -> str:
        """``SERIAL [text]``: the serial in EEPROM, asked or set (kept across resets)."""
        if not args:
            return self._serial or SERIAL_UNSET
        if len(args) != 1 or not serial_allowed(args[0]):
            raise Refused(ErrorCode.ARGUMENT, f"SERIAL [1..{SERIAL_MAX} of A-Z a-z 0-9 . _ -]")
        if self._state in ("ARMED", "RUNNING"):
            raise Refused(ErrorCode.STATE, "sequence armed or running")
        self._serial = args[0]
        return args[0]

    # -- levels ---------------------------------------------------------------------------

    def _cmd_set(self, args: list[str]) -> str:
        codes = self._levels_arg(args)
        if self._state == "RUNNING" and self._mode in (Mode.BOOTH, Mode.CAMERA):
            raise Refused(ErrorCode.STATE, "sequence running")
        self._codes = codes
        self._record_drive(None)
        return ""

    def _cmd_off(self, args: list[str]) -> str:
        self._no_args(args)
        self._all_off()
        return ""

    # -- the pattern table ----------------------------------------------------------------

    def _cmd_pattern_clear(self, args: list[str]) -> str:
        self._no_args(args)
        self._editable()
        self._pattern = []
        self._exposures = []
        self._held = []
        return ""

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
            raise Refused(ErrorCode.FULL, "pattern table full")
        self._pattern.append(codes)
        self._exposures.append(exposure)
        self._held.append(held)
        return f"{len(self._pattern) - 1}{self._on_words(codes, exposure)}"

    def _cmd_pattern_set(self, args: list[str]) -> str:
        limit = self.channels + 4
        now = self.channels + 1 < len(args) <= limit and args[-1] == NOW_FLAG
        if now:
            args = args[:-1]
        timed = self.channels + 1 < len(args) <= limit and args[-1].startswith(EXPOSURE_FLAG)
        exposure_word = args[-1] if timed else ""
        if timed:
            args = args[:-1]
        if len(args) != self.channels + 1 or not args[0].isdigit() or len(args[0]) > 5:
            raise Refused(ErrorCode.ARGUMENT, f"PSET <step> and {self.channels} levels [EXP=<us>] [NOW]")
        index = int(args[0])
        codes = self._levels_arg(args[1:])
        exposure = self._exposure_arg(exposure_word) if timed else 0
        if index >= len(self._pattern):
            raise Refused(ErrorCode.RANGE, "no such step")
        running = self._state == "RUNNING"
        if running and (index < self._step or (index == self._step and not self._holding)):
            raise Refused(ErrorCode.STATE, "step already exposed")
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

    def _cmd_roll(self, args: list[str]) -> str:
        if len(args) != 1 or not args[0].isdigit() or len(args[0]) > 8:
            raise Refused(ErrorCode.ARGUMENT, "ROLL <microseconds>")
        if self._state == "RUNNING":
            raise Refused(ErrorCode.STATE, "sequence running")
        self._roll_us = int(args[0])
        return args[0].lstrip("0") or "0"

    # -- running the table ----------------------------------------------------------------

    def _cmd_arm(self, args: list[str]) -> str:
        if len(args) != 4 or args[0] not in (Mode.HOST, Mode.BOOTH, Mode.CAMERA):
            raise Refused(ErrorCode.ARGUMENT, "ARM HOST|BOOTH|CAMERA settle_us pulse_us period_us")
        if not all(a.isdigit() and len(a) <= 8 for a in args[1:]):
            raise Refused(ErrorCode.ARGUMENT, "times are decimal microseconds")
        settle, pulse, period = (int(a) for a in args[1:])
        if self._state == "RUNNING":
            raise Refused(ErrorCode.STATE, "sequence running")
        mode = Mode(args[0])
        if mode != Mode.HOST and not self._pattern:
            raise Refused(ErrorCode.STATE, "pattern table empty")
        if mode == Mode.BOOTH and (period == 0 or period < settle + pulse):
            raise Refused(ErrorCode.RANGE, "period shorter than settle plus pulse")
        # The trigger pulse's width (pulse) is the firmware's timer's: the emulator's pulse is an instant.
        self._mode, self._settle_us, self._period_us = mode, settle, period
        self._state, self._step, self._triggers = "ARMED", -1, 0
        self._holding = False
        return ""

    def _cmd_start(self, args: list[str]) -> str:
        self._no_args(args)
        if self._state != "ARMED":
            raise Refused(ErrorCode.STATE, "not armed")
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
            raise Refused(ErrorCode.STATE, "not running in HOST mode")
        if not self._pattern or self._step + 1 >= len(self._pattern):
            self._finish()
            return "DONE"
        if self._held[self._step + 1]:
            raise Refused(ErrorCode.STATE, "next step held; expected PSET first")
        self._apply_step(self._step + 1)
        self._triggers += 1
        return (self._settle_us / 1e6, str(self._step))

    # -- queries and the watchdog ---------------------------------------------------------

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
            raise Refused(ErrorCode.ARGUMENT, "WDOG <milliseconds>")
        ms = int(args[0])
        if not watchdog_ms_allowed(ms):
            raise Refused(ErrorCode.RANGE, f"0 or {WATCHDOG_MIN_MS}..{WATCHDOG_MAX_MS} ms")
        self._watchdog_ms = ms
        return str(ms)
