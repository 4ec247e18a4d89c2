"""The booth console: one typed command at a time, sent through the booth's driver, with the frames
on the wire and what they mean (``msflash booth console PORT``, for bringing up a booth).

The driver is :class:`LedBooth` (our firmware) or :class:`TextBooth` (a plain-text booth,
``--booth-protocol text``); ``id``, ``levels``, ``off`` and ``status`` go through either, the
pattern-table commands only through :class:`LedBooth`, and ``send LINE`` (a raw text line) only
through :class:`TextBooth`.

:class:`BoothConsole` parses a line (``levels 0.5 0 1 …``, ``table …``, ``status`` …), checks it
before anything is sent, runs it through the driver and returns the lines to show: the frames of
the transcript the driver records (``>`` request, ``<`` reply, ``!`` event) and an explanation.
A refused or unreadable command is explained in one line and the console carries on.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from msflash.led_controller.adapters.text_booth import TextBooth, TextBoothInfo
from msflash.led_controller.booth import LedBooth
from msflash.led_controller.errors import BoothError
from msflash.led_controller.protocol import BoothInfo, level_to_code

HELP = """commands (levels are 0..1, one per channel; times in µs):
  id                              what the booth is
  levels L0 L1 …                  set every LED at once            e.g. levels 0.5 0 1 0 0 0 0
  off                             all LEDs off, sequence aborted
  table S0 S1 …                   load a pattern table, each step comma-separated levels
                                  (prefix hold: for a held step)   e.g. table 0.1,0,0,0,0,0,0 hold:0,0,0,0,0,0,0
  pset STEP L0 L1 … [now]         fill or replace a table step
  arm host|booth|camera [SETTLE [PULSE [PERIOD]]]   arm the table   e.g. arm booth 1000 100 100000
  start | next | count | status | ping
  wdog SECONDS                    watchdog period (0 off, 0.05..600)
  serial [TEXT]                   the booth's serial, kept in its EEPROM; TEXT sets it
                                  (1..32 of A-Z a-z 0-9 . _ -)   e.g. serial bench-A
  events                          events received and not shown yet
  help | quit"""

TEXT_HELP = """commands of a plain-text booth (levels are 0..1, one per channel):
  id                              what the booth is (ID?)
  levels L0 L1 …                  set every LED at once (L …)      e.g. levels 0.5 0 1
  off                             all LEDs off (OFF)
  status                          the levels the booth holds (L?)
  send LINE                       send LINE as typed; show the reply e.g. send L?
  help | quit"""


TABLE_COMMANDS = frozenset({"table", "pset", "arm", "start", "next", "count", "ping", "wdog", "events", "serial"})
"""Commands only our firmware's protocol has (pattern table, trigger count, watchdog, events)."""


class ConsoleQuit(Exception):
    """The user asked to leave (``quit``, ``exit``)."""


class ConsoleInputError(ValueError):
    """A typed command that cannot be sent as written (the message says what was expected)."""


@dataclass(frozen=True)
class _Command:
    run: Callable[[list[str]], list[str]]
    form: str

    @classmethod
    def plain(cls, run: Callable[[], list[str]], name: str) -> _Command:
        """A command of one word: an argument is refused before anything is sent."""

        def checked(args: list[str]) -> list[str]:
            if args:
                raise ConsoleInputError(f"{name} takes no arguments")
            return run()

        return cls(checked, name)


class BoothConsole:
    """Runs typed commands on a booth opened with ``log_serial=transcript`` and explains them.

    The console shows the frames each command adds to the transcript.
    """

    def __init__(
        self,
        booth: LedBooth | TextBooth,
        transcript: Path,
        number: Callable[[str], float] = float,
        whole: Callable[[str], int] = int,
    ) -> None:
        """``number`` and ``whole`` read the typed numbers (the CLI passes msflash's one parser of a user's number,
        :mod:`processing.user_numbers`, which this package may not import: ``float`` reads ``1_0`` and ``١``)."""
        self._number, self._whole = number, whole
        self._transcript: IO[str] = open(transcript, encoding="ascii")  # noqa: SIM115
        self._transcript.read()  # the header and the ID exchange of opening are shown by `id`
        self._info: BoothInfo | TextBoothInfo = booth.info
        if isinstance(booth, TextBooth):
            self._text: TextBooth | None = booth
            self._help = TEXT_HELP
            self._commands: dict[str, _Command] = {
                "id": _Command.plain(self._identify_text, "id"),
                "levels": _Command(self._levels, "levels L0 L1 … (one per channel)"),
                "off": _Command.plain(self._off, "off"),
                "status": _Command.plain(self._status_text, "status"),
                "send": _Command(self._send, "send LINE"),
            }
            return
        self._text = None
        self._help = HELP
        self._booth = booth
        self._commands = {
            "id": _Command.plain(self._identify, "id"),
            "levels": _Command(self._levels, "levels L0 L1 … (one per channel)"),
            "off": _Command.plain(self._off, "off"),
            "table": _Command(self._table, "table S0 S1 … (steps of comma-separated levels)"),
            "pset": _Command(self._pset, "pset STEP L0 L1 … [now]"),
            "arm": _Command(self._arm, "arm host|booth|camera [SETTLE_US [PULSE_US [PERIOD_US]]]"),
            "start": _Command.plain(self._start, "start"),
            "next": _Command.plain(self._next, "next"),
            "count": _Command.plain(self._count, "count"),
            "status": _Command.plain(self._status, "status"),
            "ping": _Command.plain(self._ping, "ping"),
            "wdog": _Command(self._watchdog, "wdog SECONDS"),
            "events": _Command.plain(self._events, "events"),
            "serial": _Command(self._serial, "serial [TEXT]"),
        }

    def close(self) -> None:
        """Stop reading the transcript (the booth itself is the caller's to close)."""
        self._transcript.close()

    def execute(self, line: str) -> list[str]:
        """Run one typed line; returns the lines to show (frames, then the explanation).

        Raises
        ------
        ConsoleQuit
            On ``quit`` or ``exit``.
        """
        words = line.split()
        if not words or words[0].startswith("#"):
            return []
        name, args = words[0].lower(), words[1:]
        if name in ("quit", "exit"):
            raise ConsoleQuit
        if name == "help":
            return self._help.splitlines()
        command = self._commands.get(name)
        if command is None and self._text is not None and name in TABLE_COMMANDS:
            return [
                f"error: {name} needs a booth that runs a pattern table (--booth-protocol msflash); "
                f"this text booth takes {', '.join(self._commands)}, help, quit (nothing sent)"
            ]
        if command is None:
            return [f"error: unknown command {name!r}; expected one of {', '.join(self._commands)}, help, quit"]
        try:
            explained = command.run(args)
        except ConsoleInputError as err:
            return [f"error: {err}; expected {command.form} (nothing sent)"]
        except ValueError as err:  # the driver's own checks, before anything is sent
            return [f"error: {err} (nothing sent)"]
        except BoothError as err:
            return [*self._frames(), f"booth: {err}"]
        return [*self._frames(), *explained]

    # -- what the wire carried --------------------------------------------------------------

    def _frames(self) -> list[str]:
        return [f"  {line}" for line in self._transcript.read().splitlines() if line and not line.startswith("#")]

    # -- parsing typed arguments ---------------------------------------------------------------

    def _level_list(self, words: list[str]) -> list[float]:
        if len(words) != self._info.channels:
            raise ConsoleInputError(f"{len(words)} levels for {self._info.channels} channels")
        try:
            levels = [self._number(w) for w in words]
        except ValueError:
            raise ConsoleInputError(f"levels {' '.join(words)!r} are not numbers") from None
        for index, level in enumerate(levels):
            if not 0.0 <= level <= 1.0:
                raise ConsoleInputError(f"level {index} ({self._info.names[index]}) is {level:g}, outside 0..1")
        return levels

    def _describe(self, levels: list[float] | tuple[float, ...]) -> str:
        if self._text is not None:  # no drive codes: the text protocol carries decimals
            return ", ".join(f"{n} {x:.4f}" for n, x in zip(self._info.names, levels))
        return ", ".join(
            f"{n} {x:.4f} ({level_to_code(x, index=i):04X})" for i, (n, x) in enumerate(zip(self._info.names, levels))
        )

    # -- the commands ------------------------------------------------------------------------

    def _identify(self) -> list[str]:
        info = self._booth.identify()
        self._info = info
        leds = ", ".join(f"{n} ({p:g} nm)" for n, p in zip(info.names, info.peaks_nm))
        return [
            f"firmware {info.firmware}, protocol {info.protocol}; {info.channels} channels: {leds}",
            (
                f"drive {info.level_bits} bits (the wire carries 16; the booth keeps the top {info.level_bits}); "
                f"pattern table of {info.max_steps} steps"
            ),
            f"serial {info.serial}" if info.serial else "serial not set (serial TEXT sets one, kept in its EEPROM)",
        ]

    def _levels(self, args: list[str]) -> list[str]:
        levels = self._level_list(args)
        (self._text or self._booth).set_levels(levels)
        return [f"LEDs now: {self._describe(levels)}"]

    def _off(self) -> list[str]:
        if self._text is not None:
            self._text.all_off()
            return ["all LEDs off"]
        self._booth.all_off()
        return ["all LEDs off; any armed or running sequence aborted (state IDLE)"]

    # -- a plain-text booth ----------------------------------------------------------------------

    def _identify_text(self) -> list[str]:
        assert self._text is not None
        info = self._text.identify()
        self._info = info
        return [f"firmware {info.firmware!r}, plain-text protocol; {info.channels} channels: {' '.join(info.names)}"]

    def _status_text(self) -> list[str]:
        assert self._text is not None
        return [f"LEDs: {self._describe(self._text.reported_levels())}"]

    def _send(self, args: list[str]) -> list[str]:
        if not args:
            raise ConsoleInputError("a line to send")
        assert self._text is not None
        reply = self._text.exchange(" ".join(args))
        return [f"booth answered {reply!r}"]

    def _table(self, args: list[str]) -> list[str]:
        if not args:
            raise ConsoleInputError("no steps")
        steps, held = [], []
        for index, word in enumerate(args):
            if word.lower().startswith("hold:"):
                held.append(index)
                word = word[5:]
            steps.append(self._level_list([w for w in word.split(",")]))
        self._booth.load_pattern(steps, held=held)
        lines = [f"table loaded: {len(steps)} steps (PCLR, then one PADD each)"]
        lines += [
            f"  step {i}{' (held: never shown until pset)' if i in held else ''}: {self._describe(s)}"
            for i, s in enumerate(steps)
        ]
        return lines

    def _pset(self, args: list[str]) -> list[str]:
        now = bool(args) and args[-1].lower() == "now"
        if now:
            args = args[:-1]
        try:
            step = self._whole(args[0]) if args else -1
        except ValueError:
            step = -1
        if step < 0:
            raise ConsoleInputError("a step number first")
        levels = self._level_list(args[1:])
        self._booth.set_step(step, levels, now=now)
        return [f"step {step} {'started at once' if now else 'filled in'}: {self._describe(levels)}"]

    def _arm(self, args: list[str]) -> list[str]:
        if not 1 <= len(args) <= 4:
            raise ConsoleInputError("a mode and up to three times")
        mode = args[0].lower()
        try:
            times = [self._whole(w) for w in args[1:]]
        except ValueError:
            raise ConsoleInputError(f"times {' '.join(args[1:])!r} are not whole microseconds") from None
        settle, pulse, period = (times + [1000, 100, 0][len(times) :])[:3]
        self._booth.arm(mode, settle_us=settle, pulse_us=pulse, period_us=period)  # type: ignore[arg-type]
        return [
            (f"armed {mode}: settle {settle} µs, pulse {pulse} µs, period {period} µs; trigger count reset; send start")
        ]

    def _start(self) -> list[str]:
        self._booth.start()
        return ["sequence running"]

    def _next(self) -> list[str]:
        step = self._booth.next_step()
        if step is None:
            return ["no more steps: LEDs off, sequence DONE"]
        return [f"step {step} applied and settled: trigger the camera now"]

    def _count(self) -> list[str]:
        return [f"{self._booth.trigger_count()} triggers since arm"]

    def _status(self) -> list[str]:
        s = self._booth.status()
        watchdog = "off" if s.watchdog_s == 0 else f"{s.watchdog_s:g} s"
        return [
            (
                f"state {s.state}, mode {s.mode or '-'}, step {s.step} of {s.steps}, {s.trigger_count} triggers, "
                f"watchdog {watchdog}, last error {s.last_error or '-'}, {s.bad_frames} unreadable frames"
            ),
            f"LEDs: {self._describe(s.levels)}",
        ]

    def _serial(self, args: list[str]) -> list[str]:
        if len(args) > 1:
            raise ConsoleInputError("serial takes one word: 1..32 of A-Z a-z 0-9 . _ -")
        if args:
            try:
                self._booth.set_serial(args[0])
            except ValueError as err:
                raise ConsoleInputError(str(err)) from err
            return [f"serial now {args[0]}, kept in the booth's EEPROM (ID says SERIAL={args[0]})"]
        serial = self._booth.identify().serial
        return [f"serial {serial}" if serial else "serial not set (serial TEXT sets one)"]

    def _ping(self) -> list[str]:
        self._booth.ping()
        return ["booth answered (watchdog fed)"]

    def _watchdog(self, args: list[str]) -> list[str]:
        if len(args) != 1:
            raise ConsoleInputError("one period in seconds")
        try:
            seconds = self._number(args[0])
        except ValueError:
            raise ConsoleInputError(f"{args[0]!r} is not a number of seconds") from None
        self._booth.set_watchdog(seconds)
        return [
            "watchdog off"
            if seconds == 0
            else f"watchdog {seconds:g} s: LEDs go off if no command arrives for that long"
        ]

    def _events(self) -> list[str]:
        events = self._booth.pending_events()
        return [f"event {e.kind} {' '.join(e.args)}" for e in events] or ["no events waiting"]
