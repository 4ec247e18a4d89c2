"""The booth's pattern table: loading it, setting steps while it runs, arming it in a sync mode.

:class:`TimedTable` loads the table (``PCLR``, ``PADD`` with held steps and exposures), changes a
step (``PSET``, ``… NOW``), keeps each pulse-dimmed step's on-times (``ON=``, for
:meth:`TimedTable.delivered_levels`), sets the rolling-shutter skew (``ROLL``) and arms, starts
and steps the sequence (``docs/booth-protocol.md`` §5, §10).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Literal

from msflash.led_controller import protocol
from msflash.led_controller.booth_handshake import Handshake
from msflash.led_controller.errors import BoothError, BoothProtocolError, BoothTimeoutError
from msflash.led_controller.protocol import Command, Mode

log = logging.getLogger(__name__)

SyncMode = Literal["host", "booth", "camera"]

PSET_NOW_FLAG = "NOW"
"""Last word of ``PSET <step> <levels> NOW``: start the step at once (``docs/booth-protocol.md`` §5)."""

ARM_TIME_MAX_US = 10_000_000
"""Longest settle, pulse or step period :meth:`LedBooth.arm` sends, in µs (10 s)."""


class TimedTable(Handshake):
    """The pattern table's commands, over the booth's identity and link."""

    _pset_now = True
    """Whether to send ``PSET … NOW`` (until the booth refuses it)."""
    _on_us: Mapping[int, tuple[float, ...]] = MappingProxyType({})
    """Table step -> its ``ON=`` on-times (pulse-dimmed steps); replaced, never changed in place."""

    def load_pattern(
        self,
        steps: Sequence[Sequence[float]],
        *,
        held: Sequence[int] = (),
        exposures_us: Sequence[float] | None = None,
    ) -> None:
        """Replace the booth's pattern table (each step: one level per channel, in [0, 1]).

        Every step is checked before anything is sent, so a bad step never leaves a half table.
        Steps listed in ``held`` are loaded as placeholders (``PADD … HOLD``): the booth does not
        expose them (no trigger, LEDs off) until :meth:`set_step` gives their levels, even while
        the sequence runs; their levels in ``steps`` are not used until then.

        ``exposures_us`` (one per step, a booth whose :attr:`BoothInfo.pulse_dimming` is set):
        each step's exposure (``EXP=``, rounded to whole µs), so that in booth and camera master
        the booth dims it by pulses of ``w·T`` inside the exposure; :meth:`delivered_levels` then
        says what each step's exposure gets.

        Raises
        ------
        ValueError
            If the table is empty, too long for the booth, a step is malformed, or exposures are
            given to a booth that does not pulse.
        """
        info = self.info
        exposure_words = self._exposure_words(exposures_us, len(steps), "load_pattern")
        held = tuple(int(i) for i in held)
        if any(not 0 <= i < len(steps) for i in held):
            raise ValueError(f"load_pattern: held steps {list(held)}; expected indices in 0..{len(steps) - 1}")
        if not 1 <= len(steps) <= info.max_steps:
            raise ValueError(f"load_pattern: {len(steps)} steps; expected 1..{info.max_steps} (the booth's table size)")
        encoded = []
        for i, step in enumerate(steps):
            try:
                encoded.append(protocol.encode_levels(step, info.channels))
            except ValueError as err:
                raise ValueError(f"load_pattern: step {i}: {err}") from err
        self._command(Command.PATTERN_CLEAR)
        self._on_us = {}
        for i, words in enumerate(encoded):
            flag = (protocol.HOLD_FLAG,) if i in held else ()
            reply, raw = self._command(Command.PATTERN_ADD, *words, *exposure_words[i], *flag)
            index = protocol.parse_count(reply, raw, command=Command.PATTERN_ADD, where=self._name)
            self._keep_on_times(i, reply, raw, Command.PATTERN_ADD)
            if index != i:
                raise BoothProtocolError(
                    f"{self._name}: PADD stored step {i} at index {index}; expected index {i}",
                    command=Command.PATTERN_ADD,
                    expected=f"'OK PADD {i}'",
                    raw=raw,
                )

    def _exposure_words(self, exposures_us: Sequence[float] | None, count: int, where: str) -> list[tuple[str, ...]]:
        """``("EXP=<us>",)`` per step (empty tuples without exposures); checked before anything is sent."""
        if exposures_us is None:
            return [()] * count
        if not self.info.pulse_dimming:
            raise ValueError(
                f"{where}: exposures given to booth {self._name}, which does not pulse (DIM={self.info.dimming})"
            )
        if len(exposures_us) != count:
            raise ValueError(f"{where}: {len(exposures_us)} exposures for {count} steps; expected one per step")
        words: list[tuple[str, ...]] = []
        for i, exposure in enumerate(exposures_us):
            us = round(float(exposure)) if math.isfinite(float(exposure)) else -1
            if not 1 <= us <= 99_999_999:
                raise ValueError(f"{where}: step {i}: exposure {exposure!r} µs; expected 1..99999999 µs")
            words.append((f"{protocol.EXPOSURE_FLAG}{us}",))
        return words

    def _keep_on_times(self, index: int, reply: protocol.Reply, raw: bytes, command: str) -> None:
        on = protocol.parse_on_times(reply.args, self.info.channels, raw, command=command, where=self._name)
        if on is None:
            self._on_us = {step: times for step, times in self._on_us.items() if step != index}
        else:
            self._on_us = {**self._on_us, index: on}

    def delivered_levels(self, index: int, exposure_us: float) -> tuple[float, ...] | None:
        """What table step ``index`` gives each LED in an exposure of ``exposure_us``, as a level (its
        on-time ÷ the exposure, ``ON=`` of the step's ``PADD``/``PSET`` reply), in booth and camera
        master; None for a step the booth dims by PWM (no exposure given, or too long to pulse).

        The booth quantises the on-time to its timer's ticks (62.5 ns up to 4.1 ms exposures); this is
        the level the frame actually got, to record beside the one asked for.
        """
        on = self._on_us.get(index)
        if on is None or not exposure_us > 0:
            return None
        return tuple(min(1.0, value / exposure_us) for value in on)

    def set_roll(self, skew_us: float) -> None:
        """``ROLL``: the camera's rolling-shutter skew (first row's start to the last's), µs; 0 for a global
        shutter. Pulses then fit the flash window, and in camera master the next step waits for the
        last row (``docs/booth-protocol.md`` §5). Set before :meth:`load_pattern` (its ``ON=`` use it).

        Raises
        ------
        ValueError
            A booth that does not pulse, or a skew outside 0..99999999 µs.
        """
        us = round(float(skew_us)) if math.isfinite(float(skew_us)) else -1
        if not 0 <= us <= 99_999_999:
            raise ValueError(f"set_roll: {skew_us!r} µs; expected 0..99999999 µs")
        if not self.info.pulse_dimming:
            raise ValueError(f"set_roll: booth {self._name} does not pulse (DIM={self.info.dimming}); it has no ROLL")
        self._command(Command.ROLL, us)

    def set_step(
        self, index: int, levels: Sequence[float], *, now: bool = False, exposure_us: float | None = None
    ) -> None:
        """Set the levels of pattern step ``index`` (``PSET``) and release it if it was held.

        Allowed while the sequence runs, for a step the booth has not reached or is holding at:
        the booth then exposes it with these levels (after ``settle_us``). One round trip.

        ``exposure_us`` (a pulsing booth): the step's exposure, as for :meth:`load_pattern`.

        ``now`` (``PSET … NOW``, booth master): if the booth has already triggered the step before
        ``index``, step ``index`` starts at once instead of at its scheduled time. Send it only
        once that previous frame is in (its exposure is over). A booth that does not know ``NOW``
        (``E_ARG``) gets the plain ``PSET`` (remembered for the next calls).

        Raises
        ------
        ValueError
            If the count differs from the channel count or a level is outside [0, 1].
        BoothError
            ``E_RANGE`` for a step beyond the table, ``E_STATE`` for a step already exposed.
        """
        if isinstance(index, bool) or not isinstance(index, int) or index < 0:
            raise ValueError(f"set_step: index {index!r}; expected a non-negative integer")
        words = protocol.encode_levels(levels, self.info.channels)
        timed = self._exposure_words(None if exposure_us is None else [exposure_us], 1, "set_step")[0]
        if now and self._pset_now:
            try:
                reply, raw = self._command(Command.PATTERN_SET, index, *words, *timed, PSET_NOW_FLAG)
                self._keep_on_times(index, reply, raw, Command.PATTERN_SET)
                return
            except BoothError as err:
                if "E_ARG" not in str(err) or isinstance(err, (BoothProtocolError, BoothTimeoutError)):
                    raise
                log.info("%s: the booth does not know PSET … NOW; sending plain PSET", self._name)
                self._pset_now = False
        reply, raw = self._command(Command.PATTERN_SET, index, *words, *timed)
        self._keep_on_times(index, reply, raw, Command.PATTERN_SET)

    def arm(
        self,
        mode: SyncMode,
        *,
        settle_us: int = 1000,
        pulse_us: int = 100,
        period_us: int = 0,
    ) -> None:
        """Arm the loaded pattern table in a synchronisation mode (resets the trigger counter).

        ``camera``: the camera's ExposureActive line advances the table; ``booth``: the booth sets
        each step, waits ``settle_us`` (the LEDs' settle), pulses the camera trigger for ``pulse_us``
        and moves on every ``period_us``; ``host``: each :meth:`next_step` applies a step and replies
        after ``settle_us``, then the host triggers the camera.
        """
        modes = {"host": Mode.HOST, "booth": Mode.BOOTH, "camera": Mode.CAMERA}
        if mode not in modes:
            raise ValueError(f"arm: mode {mode!r} unknown; expected one of {', '.join(modes)}")
        values = {"settle_us": settle_us, "pulse_us": pulse_us, "period_us": period_us}
        for key, value in values.items():
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= ARM_TIME_MAX_US:
                raise ValueError(f"arm: {key} {value!r} invalid; expected an integer in 0..{ARM_TIME_MAX_US}")
        if mode == "booth" and period_us < settle_us + pulse_us:
            raise ValueError(
                f"arm: period_us {period_us} shorter than settle_us + pulse_us ({settle_us + pulse_us}); "
                "expected a period long enough for settle, pulse and exposure"
            )
        self._command(Command.ARM, modes[mode], settle_us, pulse_us, period_us)

    def start(self) -> None:
        """Start the armed sequence."""
        self._command(Command.START)

    def next_step(self) -> int | None:
        """Host-paced mode: apply the next pattern step; returns its index, None after the last.

        The booth replies once the LEDs have settled, so the camera may be triggered at once.
        """
        reply, raw = self._command(Command.NEXT, timeout_s=self.timeout_s + 10.0)
        if reply.args == ("DONE",):
            return None
        return protocol.parse_count(reply, raw, command=Command.NEXT, where=self._name)

    def trigger_count(self) -> int:
        """Get the number of triggers since the last :meth:`arm`."""
        reply, raw = self._command(Command.COUNT)
        return protocol.parse_count(reply, raw, command=Command.COUNT, where=self._name)
