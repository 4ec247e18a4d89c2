"""The emulated firmware's RAM, its sequencer and what its LED pins do (``docs/booth-protocol.md`` §5, §7).

:class:`Sequencer` holds what the firmware keeps in RAM (levels, the pattern table, the armed
mode and its times, the step, the trigger count, the watchdog), steps through the table in the
three sync modes — host paced (``NEXT``), booth master (timed actions on the clock) and camera
master (the camera's ExposureActive edges, :meth:`Sequencer.exposure_active`) — runs what is due
on the clock (:meth:`Sequencer.tick`: delayed replies, booth-master steps, the watchdog), and
records each LED pin's drive (PWM, pulses, on, off) in a
:class:`~led_controller.drive_waveform.DriveTrace` for a camera integrating it. The commands
that change this state are :class:`~led_controller.emulator_commands.FirmwareCommands`; the link is
:class:`~led_controller.emulator.BoothEmulator`.
"""

from __future__ import annotations

import math
import random
import threading
import time
from collections.abc import Callable, Sequence

from msflash.led_controller.drive_waveform import CLOCK_HZ, PULSE_FULL, Drive, DriveTrace, PulsePlan, pulse_plan
from msflash.led_controller.protocol import HOLD_FLAG, Event, Mode

FULL_SCALE = 0xFFFF
FIRE_LATENCY_US = (2.0, 8.0)
"""Camera master: how late the firmware's pulses start after ExposureActive rises (its interrupt
latency, docs/flash-energy.md). The emulator draws each fire's delay from this range."""
TRIGGER_FIRE_US = 0.25
"""Booth master: the firmware starts the pulse timers this long after raising the trigger output."""

Clock = Callable[[], float]


class Sequencer:
    """The firmware's RAM and sequencer; every method runs with :attr:`_lock` held by its caller."""

    channels: int
    level_bits: int
    drive_trace: DriveTrace
    on_trigger_out: Callable[[int], None] | None
    _clock: Clock
    _lock: threading.RLock
    _rng: random.Random
    _power_up_watchdog_ms: int
    _watchdog_fires: int

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
        self._settle_us = self._period_us = 0
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

    def _event(self, body: str) -> None:
        """Send an event frame (the link's: :meth:`BoothEmulator._event`)."""
        raise NotImplementedError

    def _reply(self, seq: int, body: str) -> None:
        """Send a reply frame (the link's: :meth:`BoothEmulator._reply`)."""
        raise NotImplementedError

    # -- observers ----------------------------------------------------------------------

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

    @property
    def pattern(self) -> tuple[tuple[float, ...], ...]:
        """Get the loaded pattern table (levels in [0, 1])."""
        with self._lock:
            return tuple(tuple(c / FULL_SCALE for c in step) for step in self._pattern)

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

    def mean_levels(self, starts_s: Sequence[float], duration_s: float) -> list[list[float]]:
        """``[row][channel]``: each LED's mean level over ``[start, start + duration_s]`` (clock seconds).

        What a camera row exposed then collects from each LED, as a fraction of the LED on
        throughout: the PWM waveform with its phase, the pulses, the level changes in between
        (:class:`~led_controller.drive_waveform.DriveTrace`). Windows in the future assume the
        drive stays as it is now.
        """
        with self._lock:
            return self.drive_trace.mean_levels(starts_s, duration_s)

    # -- the camera side ------------------------------------------------------------------

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

    # -- the clock ------------------------------------------------------------------------

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

    # -- stepping through the table -------------------------------------------------------

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
