"""``LedBooth``: the driver of an msflash LED booth over any pyserial URL.

The far end of the wire may be the real firmware, the emulator on a pseudo-terminal, or a
recorded transcript; the driver code is the same in every case. A reader thread frames the
incoming lines and puts replies and events into two separate queues; every byte is logged in
:meth:`LedBooth._wire` and nowhere else.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import errno
import itertools
import logging
import math
import queue
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Literal

import serial

from msflash.led_controller import protocol
from msflash.led_controller.booth_interface import BoothCapabilities
from msflash.led_controller.errors import (
    BoothError,
    BoothNotFoundError,
    BoothProtocolError,
    BoothTimeoutError,
)
from msflash.led_controller.protocol import BoothEvent, BoothInfo, BoothStatus, Command, Mode

try:
    import termios

    _TERMIOS_ERRORS: tuple[type[Exception], ...] = (termios.error,)
except ImportError:  # not a POSIX host: pyserial raises no termios errors there
    _TERMIOS_ERRORS = ()

log = logging.getLogger(__name__)

SyncMode = Literal["host", "booth", "camera"]

PSET_NOW_FLAG = "NOW"
"""Last word of ``PSET <step> <levels> NOW``: start the step at once (``docs/booth-protocol.md`` §5)."""

_READ_POLL_S = 0.02
"""Read timeout of the port: how quickly the reader thread notices ``close``."""

ARM_TIME_MAX_US = 10_000_000
"""Longest settle, pulse or step period :meth:`LedBooth.arm` sends, in µs (10 s)."""

DEFAULT_BOOT_S = 2.5
"""How long :meth:`LedBooth.open` waits, silent, for the firmware's boot banner after opening the port, in
seconds (``--booth-boot-s``). A stock Arduino Mega resets when its port is opened and its bootloader
swallows what the host sends for 1.5–2 s; the host must not send meanwhile (every byte keeps the
stk500v2 bootloader longer, ``led_controller/usb_link.py``). 0: ask at once (a board with auto-reset
disabled, or one that is not an Arduino)."""

WATCHDOG_MAX_S = protocol.WATCHDOG_MAX_MS / 1000.0
"""Longest watchdog period the protocol allows, in seconds (:data:`led_controller.protocol.WATCHDOG_MAX_MS`)."""


class _LinkLost:
    """Queue item: the serial link failed (carries the cause)."""

    def __init__(self, error: BaseException) -> None:
        self.error = error


class _BootedMeanwhile(Exception):
    """The booth sent its boot banner while a request waited for its reply (the request went to its bootloader)."""


class _Garbled:
    """Queue item: a line that is not a valid frame (carries the protocol error)."""

    def __init__(self, error: BoothProtocolError) -> None:
        self.error = error


IDEMPOTENT_COMMANDS = frozenset(
    {
        Command.IDENTIFY,
        Command.STATUS,
        Command.COUNT,
        Command.PING,
        Command.SET,
        Command.OFF,
        Command.WATCHDOG,
        Command.PATTERN_CLEAR,
        Command.ROLL,
    }
)
"""Commands that leave the booth as one would, sent twice: sent again once after a damaged reply or
none. The others (NEXT, PADD, PSET, ARM, START, SERIAL …) are never resent: the booth may have acted on them,
and a frame-error reply (sequence 00) does not say which request it was for."""


class _Retryable(Exception):
    """A failed exchange :meth:`LedBooth._command` may send again (an idempotent command): the error to
    raise otherwise, and why."""

    def __init__(self, error: BoothError, why: str) -> None:
        super().__init__(why)
        self.error = error
        self.why = why


class LedBooth:
    """Driver of an msflash LED booth (protocol v1, see ``docs/booth-protocol.md``).

    Use :meth:`open` rather than the constructor; use the booth as a context manager so that
    every exit path switches the LEDs off.

    Parameters
    ----------
    port : serial.SerialBase
        An already-open port (a device, a pty, ``loop://``, ``spy://`` or a test transport).
        Its read timeout should be short (tens of ms): it bounds how fast ``close`` returns.
    timeout_s : float
        Reply timeout of every command, in seconds.
    log_serial : str or Path or None
        If given, a transcript file of ``> request`` / ``< reply`` / ``! event`` lines.
    name : str or None
        Name used in messages and logs (defaults to the port name).
    """

    def __init__(
        self,
        port: Any,
        *,
        timeout_s: float = 1.0,
        log_serial: str | Path | None = None,
        name: str | None = None,
    ) -> None:
        if not timeout_s > 0:
            raise ValueError(f"LedBooth: timeout_s {timeout_s!r} invalid; expected a positive number")
        self._port = port
        self._name = name or str(getattr(port, "name", None) or getattr(port, "portstr", "booth"))
        self.timeout_s = float(timeout_s)
        self._replies: queue.Queue[protocol.Frame | _Garbled | _LinkLost] = queue.Queue()
        self._events: collections.deque[BoothEvent | _Garbled | _LinkLost] = collections.deque()
        self._events_cv = threading.Condition()
        self._command_lock = threading.Lock()
        self._wire_lock = threading.Lock()
        self._seqs = itertools.cycle(range(1, 256))
        self._last_event_seq: int | None = None
        self._link_error: BaseException | None = None
        self._stop = threading.Event()
        self._closed = False
        self._info: BoothInfo | None = None
        self._pset_now = True
        self._on_us: dict[int, tuple[float, ...]] = {}  # table step -> ON= on-times (pulse-dimmed steps)
        self._watchdog_s: float | None = None  # the booth's watchdog period once known (STAT, WDOG)
        self._boots = 0  # BOOT banners seen (the firmware started: a reset)
        try:
            self._transcript: IO[str] | None = (
                open(log_serial, "w", encoding="ascii", newline="\n") if log_serial else None  # noqa: SIM115
            )
        except OSError as err:
            raise BoothError(
                f"{self._name}: cannot record the serial transcript in {log_serial} "
                f"({err.strerror or err}); expected a writable file path"
            ) from err
        if self._transcript is not None:
            self._transcript.write(f"# msflash booth transcript, port {self._name}, {time.strftime('%Y-%m-%d')}\n")
        self._reader = threading.Thread(target=self._read_loop, name=f"booth-reader {self._name}", daemon=True)
        self._reader.start()

    # -- opening and closing -------------------------------------------------------------

    @classmethod
    def open(
        cls,
        url: str,
        *,
        timeout_s: float = 1.0,
        log_serial: str | Path | None = None,
        baudrate: int = 115200,
        boot_s: float = DEFAULT_BOOT_S,
    ) -> LedBooth:
        """Open the booth at a pyserial URL, wait for it to boot, and identify it.

        Opening the port resets a stock Arduino Mega (docs/booth-firmware.md §4): the driver then
        sends nothing until the firmware's boot banner (``BOOT``, docs/booth-protocol.md §6) or
        ``boot_s`` has passed, drops what came before it (bootloader noise), and asks ``ID``; a reply
        damaged by the boot, or a banner that comes late, gets ``ID`` again until ``boot_s`` plus
        ``timeout_s`` have passed.

        Parameters
        ----------
        url : str
            A device path (``/dev/ttyACM0``), a pty path, or a pyserial URL (``loop://``,
            ``spy:///dev/ttyACM0?file=trace.txt``).
        timeout_s : float
            Reply timeout of every command, in seconds.
        log_serial : str or Path or None
            Transcript file to record the exchange in.
        baudrate : int
            Baud rate (ignored by USB CDC devices and ptys).
        boot_s : float
            How long to wait for the boot banner, in seconds (:data:`DEFAULT_BOOT_S`; 0: send ``ID``
            at once, for a board that does not reset when its port opens).

        Returns
        -------
        LedBooth
            An identified booth (:attr:`info` is set).

        Raises
        ------
        BoothNotFoundError
            If the port does not exist.
        BoothError
            If the port cannot be opened (permissions, busy — another program holds it: the port is
            opened exclusively) or does not answer as a booth.
        ValueError
            If ``boot_s`` is negative or not finite.
        """
        if not (0 <= boot_s < math.inf):
            raise ValueError(f"boot wait {boot_s!r} s; expected a finite number of seconds ≥ 0 (0: no wait)")
        port = open_serial_port(url, baudrate, _READ_POLL_S, timeout_s)
        try:
            booth = cls(port, timeout_s=timeout_s, log_serial=log_serial, name=url)
        except BaseException:
            port.close()  # the driver never took the port: release it here
            raise
        try:
            booth.identify_after_boot(boot_s)
        except BaseException:
            booth.close()
            raise
        return booth

    def close(self) -> None:
        """Stop the reader thread and close the port (idempotent; does not switch LEDs off)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        with contextlib.suppress(Exception):
            self._port.cancel_read()
        self._reader.join(timeout=2.0)
        try:
            self._port.close()
        except (OSError, serial.SerialException) as err:
            log.warning("%s: closing the port failed: %s", self._name, err)
        if self._transcript is not None:
            self._transcript.close()

    def __enter__(self) -> LedBooth:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> Literal[False]:
        try:
            self.all_off()
        except Exception as off_err:
            if exc is None:
                raise
            # The original error is what the user needs to see; the failed all_off is
            # attached to it (the booth's watchdog switches the LEDs off in the end).
            log.error("%s: all_off failed while handling %r: %s", self._name, exc, off_err)
            exc.add_note(f"while handling this, all_off on {self._name} also failed: {off_err}")
        finally:
            self.close()
        return False

    # -- public commands -----------------------------------------------------------------

    @property
    def info(self) -> BoothInfo:
        """Get what :meth:`identify` last returned (:class:`BoothInfo`)."""
        if self._info is None:
            return self.identify()
        return self._info

    @property
    def name(self) -> str:
        """Get the port name used in messages (str)."""
        return self._name

    @property
    def capabilities(self) -> BoothCapabilities:
        """Get the sync modes an msflash booth runs: host pacing, booth master and camera master (protocol v1)."""
        return BoothCapabilities(booth_master=True, camera_master=True)

    def identify(self, *, timeout_s: float | None = None, _until_boot: bool = False) -> BoothInfo:
        """Ask the booth for its firmware, channels, channel names, peak wavelengths and serial.

        Raises
        ------
        BoothError
            If the booth speaks another protocol version than this driver (``PROTO=``; a version
            is raised by any change that is not additive, ``docs/booth-protocol.md`` §9).
        """
        reply, raw = self._command(Command.IDENTIFY, timeout_s=timeout_s, until_boot=_until_boot)
        info = protocol.parse_identify(reply, raw, where=self._name)
        if info.protocol != protocol.PROTOCOL_VERSION:
            newer = info.protocol > protocol.PROTOCOL_VERSION
            raise BoothError(
                f"{self._name}: booth firmware {info.firmware} speaks booth protocol {info.protocol}; expected "
                f"protocol {protocol.PROTOCOL_VERSION} (docs/booth-protocol.md) — "
                + ("update msflash for this firmware" if newer else "update the booth's firmware")
            )
        self._info = info
        log.info(
            "%s: booth %s, %d channels %s",
            self._name,
            self._info.firmware,
            self._info.channels,
            ",".join(self._info.names),
        )
        return self._info

    # -- the boot after opening (a board that resets when its port opens) --------------------

    @property
    def boots_seen(self) -> int:
        """Get how many ``BOOT`` banners the booth sent since the port was opened."""
        return self._boots

    def identify_after_boot(self, boot_s: float) -> BoothInfo:
        """Wait, silent, up to ``boot_s`` for the firmware's ``BOOT`` banner, then identify (see :meth:`open`).

        Raises
        ------
        BoothTimeoutError
            Nothing answered: one line naming the port, how long it waited and auto-reset as a cause.
        """
        start = time.monotonic()
        if boot_s == 0:
            try:
                return self.identify()
            except BoothTimeoutError as err:
                raise self._no_answer(start, boot_s, banner_after_s=None) from err
        banner = self._wait_boot_banner(start + boot_s)
        deadline = max(time.monotonic(), start + boot_s) + self.timeout_s
        while True:
            self._drop_boot_noise()
            remaining = deadline - time.monotonic()
            try:
                return self.identify(timeout_s=max(remaining, 0.05), _until_boot=True)
            except _BootedMeanwhile:
                # The firmware booted while ID was on its way to a slow bootloader: ask it now.
                banner = banner if banner is not None else time.monotonic() - start
                deadline = max(deadline, time.monotonic() + self.timeout_s)
                continue
            except BoothTimeoutError as err:
                raise self._no_answer(start, boot_s, banner_after_s=banner) from err
            except BoothProtocolError as err:
                # A request cut by the boot (E_FRAME) or a reply with bootloader noise in it.
                if deadline - time.monotonic() <= 0:
                    raise
                log.debug("%s: %s while booting; asking again", self._name, err)
                time.sleep(0.05)

    def _wait_boot_banner(self, until: float) -> float | None:
        """Seconds from now to the ``BOOT`` banner, waiting up to ``until``; None if none came."""
        start = time.monotonic()
        with self._events_cv:
            while True:
                for item in list(self._events):
                    if isinstance(item, BoothEvent) and item.kind == protocol.Event.BOOT:
                        self._events.remove(item)
                        return time.monotonic() - start
                remaining = until - time.monotonic()
                if remaining <= 0:
                    return None
                self._events_cv.wait(remaining)

    def _drop_boot_noise(self) -> None:
        """Forget what arrived before the firmware ran: bootloader noise, damaged lines, banners.

        The reader thread has already taken every byte off the port into its queues, so emptying them is
        the flush (a ``reset_input_buffer`` here would race with it and could cut a reply in two).
        """
        while True:
            try:
                item = self._replies.get_nowait()
            except queue.Empty:
                break
            if isinstance(item, _LinkLost):
                self._replies.put(item)
                break
        with self._events_cv:
            for event in list(self._events):
                if isinstance(event, _Garbled) or (isinstance(event, BoothEvent) and event.kind == protocol.Event.BOOT):
                    self._events.remove(event)

    def _no_answer(self, start: float, boot_s: float, *, banner_after_s: float | None) -> BoothTimeoutError:
        waited = time.monotonic() - start
        if banner_after_s is not None:
            what = (
                f"booted (its BOOT banner came {banner_after_s:.2g} s after the port opened) but did not answer "
                f"ID within {waited:.3g} s of opening the port; expected an ID reply (is another program "
                "sending to it, or is the baud rate wrong?)"
            )
        elif boot_s > 0:
            what = (
                f"no answer within {waited:.3g} s of opening the port (no boot banner in {boot_s:g} s, then "
                f"no reply to ID); expected an msflash booth — check that it is powered and the port is right; "
                f"a board that resets when its port opens (Arduino auto-reset) needs --booth-boot-s longer "
                f"than its bootloader (now {boot_s:g} s), or auto-reset disabled (10 µF RESET–GND)"
            )
        else:
            what = (
                f"no reply to ID within {waited:.3g} s of opening the port (--booth-boot-s 0: no wait for a "
                "boot); expected an msflash booth — check that it is powered and the port is right; if it "
                f"resets when its port opens (Arduino auto-reset), let it boot: --booth-boot-s {DEFAULT_BOOT_S:g}"
            )
        return BoothTimeoutError(f"{self._name}: {what}", command=str(Command.IDENTIFY), timeout_s=waited)

    def set_levels(self, levels: Sequence[float]) -> None:
        """Set every LED level (one value per channel, each in [0, 1], 16-bit on the wire).

        Raises
        ------
        ValueError
            If the count differs from the channel count or a level is outside [0, 1].
        """
        words = protocol.encode_levels(levels, self.info.channels)
        self._command(Command.SET, *words)

    def all_off(self) -> None:
        """Switch every LED off and abort any running sequence."""
        self._command(Command.OFF)

    def ping(self) -> None:
        """Check the link (and feed the booth's watchdog)."""
        self._command(Command.PING)

    def set_serial(self, serial: str) -> None:
        """Give the booth a serial (``SERIAL <text>``), which it keeps in its EEPROM and reports as ``SERIAL=``.

        Raises
        ------
        ValueError
            If ``serial`` is not 1..32 of ``A-Z a-z 0-9 . _ -`` (or is ``-``).
        BoothError
            ``E_STATE`` while a sequence is armed or running; ``E_CMD`` from firmware without ``SERIAL``.
        """
        if not protocol.serial_allowed(serial):
            raise ValueError(
                f"serial {serial!r}: expected 1..{protocol.SERIAL_MAX} of A-Z a-z 0-9 . _ - (and not '-' alone)"
            )
        self._command(Command.SERIAL, serial)
        if self._info is not None:
            self._info = dataclasses.replace(self._info, serial=serial)

    def set_watchdog(self, timeout_s: float) -> None:
        """Set the booth's watchdog: LEDs go off after ``timeout_s`` of host silence (0 disables)."""
        ms = int(round(float(timeout_s) * 1000))
        if not protocol.watchdog_ms_allowed(ms):
            raise ValueError(f"set_watchdog: {timeout_s!r} s out of range; expected 0 or 0.05..600 s")
        self._command(Command.WATCHDOG, ms)
        self._watchdog_s = ms / 1000.0

    @property
    def watchdog_s(self) -> float:
        """Get the booth's watchdog period in seconds (0: disabled); asked once (``STAT``), then kept by
        :meth:`set_watchdog` and :meth:`status`."""
        if self._watchdog_s is None:
            self.status()
        assert self._watchdog_s is not None
        return self._watchdog_s

    @contextlib.contextmanager
    def watchdog_covering(self, silence_s: float) -> Iterator[None]:
        """Keep the booth's watchdog from firing while the host is silent on purpose for up to ``silence_s``.

        A capture sends nothing while a booth- or camera-master table runs, or while a long exposure
        is under way (host paced); a watchdog shorter than that switches the LEDs off in the middle
        of a frame — an aborted sequence, or worse, an LED frame exposed partly dark. When the
        watchdog is on and shorter than ``silence_s``, it is raised to ``silence_s`` (at most
        :data:`WATCHDOG_MAX_S`) for the block and set back afterwards, so a host that dies still
        has its LEDs switched off, only later. A watchdog that is off or long enough is left alone
        (no traffic). Setting it back is skipped when the link is lost and otherwise only logged
        if it fails: the block's own error is what the caller needs to see.
        """
        previous = self.watchdog_s
        if previous == 0 or previous >= silence_s:
            yield
            return
        if silence_s > WATCHDOG_MAX_S:
            log.warning(
                "%s: the host stays silent up to %.0f s, longer than the longest watchdog (%.0f s); "
                "the booth may switch the LEDs off before the end",
                self._name,
                silence_s,
                WATCHDOG_MAX_S,
            )
        self.set_watchdog(min(math.ceil(silence_s * 1000) / 1000.0, WATCHDOG_MAX_S))
        try:
            yield
        finally:
            if self._link_error is None and not self._closed:
                try:
                    self.set_watchdog(previous)
                except (BoothError, ValueError) as err:  # ValueError: a period the protocol does not allow
                    log.warning("%s: setting the watchdog back to %g s failed: %s", self._name, previous, err)

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
        self._on_us.clear()
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
            self._on_us.pop(index, None)
        else:
            self._on_us[index] = on

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

        Parameters
        ----------
        mode : {"host", "booth", "camera"}
            ``camera``: the camera's ExposureActive line advances the table; ``booth``: the
            booth sets each step, waits ``settle_us``, pulses the camera trigger for
            ``pulse_us`` and moves on every ``period_us``; ``host``: each :meth:`next_step`
            applies a step and replies after ``settle_us``, then the host triggers the camera.
        settle_us, pulse_us, period_us : int
            LED settle time, trigger pulse width and (booth mode) step period, in µs.
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

    def status(self) -> BoothStatus:
        """Get a snapshot of the booth's state (:class:`BoothStatus`)."""
        reply, raw = self._command(Command.STATUS)
        status = protocol.parse_status(reply, raw, where=self._name)
        self._watchdog_s = status.watchdog_s
        return status

    def reported_levels(self) -> tuple[float, ...]:
        """Get the levels the booth holds now, as its ``STAT`` reports them."""
        return self.status().levels

    def wait_event(self, kind: str | None = None, *, timeout_s: float | None = None) -> BoothEvent:
        """Wait for the next event (of ``kind`` if given: ``TRIG``, ``DONE``, ``WDOG``).

        Events of other kinds stay queued for later calls.

        Raises
        ------
        BoothTimeoutError
            If no such event arrives within ``timeout_s`` (default: the command timeout).
        BoothError
            If the booth's watchdog fired while waiting for another kind, or the link was lost.
        BoothProtocolError
            If an event line was damaged or events were lost (sequence gap).
        """
        timeout = self.timeout_s if timeout_s is None else float(timeout_s)
        deadline = time.monotonic() + timeout
        with self._events_cv:
            while True:
                for item in list(self._events):
                    if isinstance(item, (_Garbled, _LinkLost)):
                        self._events.remove(item)
                        if isinstance(item, _Garbled):
                            raise item.error
                        raise self._link_lost_error("waiting for an event", item.error) from item.error
                    if kind is None or item.kind == kind:
                        self._events.remove(item)
                        return item
                    if item.kind == protocol.Event.WATCHDOG:
                        self._events.remove(item)
                        raise BoothError(
                            f"{self._name}: the booth's watchdog switched the LEDs off while waiting "
                            f"for {kind}; expected the host to send a command at least every watchdog period"
                        )
                    if item.kind == protocol.Event.BOOT:
                        self._events.remove(item)
                        raise BoothError(
                            f"{self._name}: the booth restarted (its firmware sent BOOT) while waiting for "
                            f"{kind}; its table and levels are lost; expected it to stay powered — check its "
                            "supply (LED current), the USB cable, and that no other program opened its port"
                        )
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise BoothTimeoutError(
                        f"{self._name}: no {kind or 'event'} event within {timeout:g} s; "
                        "expected the booth to report it (is the sequence armed and started?)",
                        command=f"event {kind or '*'}",
                        timeout_s=timeout,
                    )
                self._events_cv.wait(remaining)

    def watchdog_fired(self) -> bool:
        """Whether the booth reported its watchdog switching the LEDs off (``WDOG``) since the last call.

        Takes the ``WDOG`` events out of the queue and leaves the others (no serial traffic): a
        capture asks after each frame, since a frame exposed while the watchdog had switched the
        LEDs off is wrong without anything else noticing (host paced: the next ``SET`` just works).
        """
        with self._events_cv:
            fired = [e for e in self._events if isinstance(e, BoothEvent) and e.kind == protocol.Event.WATCHDOG]
            for event in fired:
                self._events.remove(event)
            return bool(fired)

    def pending_events(self) -> list[BoothEvent]:
        """Remove and return the events received but not yet waited for."""
        with self._events_cv:
            out = [e for e in self._events if isinstance(e, BoothEvent)]
            self._events.clear()
            return out

    # -- the exchange ---------------------------------------------------------------------

    def _command(
        self, command: str, *args: object, timeout_s: float | None = None, until_boot: bool = False
    ) -> tuple[protocol.Reply, bytes]:
        """One request and its reply, asked once more where asking again cannot change what happens.

        An idempotent command (:data:`IDEMPOTENT_COMMANDS`: the queries, SET, OFF, WDOG, PCLR, ROLL) is sent once
        more after a reply that arrived damaged (a flipped bit, a dropped byte), no reply at all, or a
        framing error the booth reports (sequence 00): sending it twice leaves the booth as once would.
        Other commands fail at once (the booth may have acted). Each retry is logged. ``until_boot``: give up (:class:`_BootedMeanwhile`) as soon as a ``BOOT``
        banner arrives, the request having gone to a bootloader that is now gone (never retried).
        """
        name = str(command)
        try:
            return self._exchange(name, *args, timeout_s=timeout_s, until_boot=until_boot)
        except _Retryable as first:
            if until_boot or name not in IDEMPOTENT_COMMANDS:
                raise first.error from first.error.__cause__
            log.warning("%s: %s once more after %s", self._name, name, first.why)
            try:
                return self._exchange(name, *args, timeout_s=timeout_s, until_boot=until_boot)
            except _Retryable as second:
                raise second.error from second.error.__cause__

    def _exchange(
        self, command: str, *args: object, timeout_s: float | None = None, until_boot: bool = False
    ) -> tuple[protocol.Reply, bytes]:
        """One request and its reply; :class:`_Retryable` wraps what :meth:`_command` may ask again."""
        timeout = self.timeout_s if timeout_s is None else timeout_s
        name = str(command)
        boots = self._boots
        with self._command_lock:
            if self._closed:
                raise BoothError(f"{self._name}: {name} on a closed booth; expected an open LedBooth")
            if self._link_error is not None:
                raise self._link_lost_error(name, self._link_error) from self._link_error
            self._drop_stale_replies()
            seq = next(self._seqs)
            self._send(protocol.encode_request(seq, name, *args), name, timeout)
            deadline = time.monotonic() + timeout
            while True:
                remaining = deadline - time.monotonic()
                try:
                    if remaining <= 0:
                        raise queue.Empty
                    item = self._replies.get(timeout=min(remaining, 0.05) if until_boot else remaining)
                except queue.Empty:
                    if until_boot and self._boots != boots:
                        raise _BootedMeanwhile from None
                    if remaining > 0.05 and until_boot:
                        continue
                    raise _Retryable(
                        BoothTimeoutError(
                            f"{self._name}: no reply to {name} within {timeout:g} s; expected "
                            f"'={seq:02X}:…'; check that the booth is powered and the port is right",
                            command=name,
                            timeout_s=timeout,
                        ),
                        f"no reply within {timeout:g} s",
                    ) from None
                if isinstance(item, _LinkLost):
                    raise self._link_lost_error(name, item.error) from item.error
                if isinstance(item, _Garbled):
                    err = item.error
                    garbled = BoothProtocolError(
                        f"{self._name}: bad reply to {name}: {err.raw[:80]!r}; expected "
                        f"{protocol.FRAME_FORM} (line noise? check the cable and baud rate)",
                        command=name,
                        expected=err.expected,
                        raw=err.raw,
                    )
                    garbled.__cause__ = err
                    raise _Retryable(garbled, f"a damaged reply {err.raw[:40]!r}")
                if item.seq == protocol.SEQ_FRAME_ERROR:
                    raise self._unread(name, seq, protocol.parse_reply(item, name, where=self._name), item.raw)
                if item.seq != seq:
                    # A late reply to an earlier command that timed out: not ours.
                    log.warning("%s: dropped stale reply %r while waiting for %s", self._name, item.raw, name)
                    continue
                reply = protocol.parse_reply(item, name, where=self._name)
                if not reply.ok:
                    if reply.code in protocol.FRAME_ERROR_CODES:
                        raise self._unread(name, seq, reply, item.raw)
                    raise BoothError(
                        f"{self._name}: booth refused {name} ({reply.code}: {reply.text}); expected 'OK {name}'"
                    )
                return reply, item.raw

    def _unread(self, name: str, seq: int, reply: protocol.Reply, raw: bytes) -> _Retryable:
        """The booth says it could not read the request (a framing error): nothing was done."""
        return _Retryable(
            BoothProtocolError(
                f"{self._name}: the booth could not read the {name} request "
                f"({reply.code} {reply.text}); expected a clean link (check the cable)",
                command=name,
                expected=f"'={seq:02X}:…'",
                raw=raw,
            ),
            f"the booth could not read it ({reply.code})",
        )

    def _drop_stale_replies(self) -> None:
        while True:
            try:
                item = self._replies.get_nowait()
            except queue.Empty:
                return
            if isinstance(item, _LinkLost):
                self._replies.put(item)
                return
            raw = item.raw if isinstance(item, protocol.Frame) else item.error.raw
            log.warning("%s: dropped unclaimed reply %r", self._name, raw)

    def _send(self, frame: bytes, command: str, timeout: float) -> None:
        self._wire(">", frame)
        try:
            self._port.write(frame)
            self._port.flush()
        except serial.SerialTimeoutException as err:
            raise BoothTimeoutError(
                f"{self._name}: writing {command} blocked for {timeout:g} s; expected the booth to read its input",
                command=command,
                timeout_s=timeout,
            ) from err
        except (serial.SerialException, OSError, *_TERMIOS_ERRORS) as err:
            # termios.error: pyserial's flush (tcdrain) on a pty or USB port that was just hung up.
            self._link_error = err
            raise self._link_lost_error(command, err) from err

    def _link_lost_error(self, doing: str, cause: BaseException) -> BoothError:
        return BoothError(
            f"{self._name}: serial link lost during {doing} ({cause}); expected an open port; "
            "check the USB cable and the booth's power, then reopen"
        )

    def _wire(self, direction: str, data: bytes) -> None:
        """Log every byte on the wire (the one place where this happens) and record the transcript.

        ``direction`` is ``>`` for host to booth and ``<`` for booth to host; complete lines
        only, so the transcript reads back line by line.
        """
        log.debug("%s %s %r", self._name, direction, data)
        if self._transcript is None:
            return
        line = data.rstrip(b"\n").decode("ascii", errors="backslashreplace")
        mark = "!" if direction == "<" and line.startswith(protocol.MARK_EVENT) else direction
        with self._wire_lock:
            self._transcript.write(f"{mark} {line}\n")
            self._transcript.flush()

    def _read_loop(self) -> None:
        buffer = bytearray()
        discarding = False  # within an over-long line, already reported: dropped up to its terminator
        while not self._stop.is_set():
            try:
                waiting = self._port.in_waiting
                data = self._port.read(max(1, min(waiting, 4096)))
            except Exception as err:  # any failure of the transport means the link is gone
                if self._stop.is_set():
                    return
                log.error("%s: serial link lost: %s", self._name, err)
                self._link_error = err
                lost = _LinkLost(err)
                self._replies.put(lost)
                with self._events_cv:
                    self._events.append(lost)
                    self._events_cv.notify_all()
                return
            if not data:
                continue
            buffer += data
            while True:
                end = buffer.find(protocol.TERMINATOR)
                if discarding:
                    if end < 0:
                        buffer.clear()
                        break
                    del buffer[: end + 1]
                    discarding = False
                    continue
                if end < 0:
                    break
                line = bytes(buffer[:end])
                del buffer[: end + 1]
                if not line:
                    continue  # an empty line: the line end a booth sends before its boot banner
                self._wire("<", line + protocol.TERMINATOR)
                self._dispatch(line)
            if len(buffer) > protocol.MAX_LINE:
                # No frame is this long (docs/booth-protocol.md §2): one framing error for the line's
                # first MAX_LINE + 1 bytes, the rest dropped up to its terminator, never buffered.
                line = bytes(buffer[: protocol.MAX_LINE + 1])
                buffer.clear()
                discarding = True
                self._wire("<", line)
                self._dispatch(line)

    def _dispatch(self, line: bytes) -> None:
        try:
            frame = protocol.parse_frame(line, where=self._name)
        except BoothProtocolError as err:
            tail = _resynchronised(line, self._name)
            if tail is not None:  # a frame that lost its line end, then a whole frame: keep the whole one
                log.warning(
                    "%s: dropped a damaged frame %r (its line end was lost) before %r",
                    self._name,
                    line[: len(line) - len(tail)][:80],
                    tail[:40],
                )
                self._dispatch(tail)
                return
            if line.startswith(protocol.MARK_EVENT.encode()):
                self._push_event(_Garbled(err))
            else:
                self._replies.put(_Garbled(err))
            return
        if frame.mark == protocol.MARK_REPLY:
            self._replies.put(frame)
        elif frame.mark == protocol.MARK_EVENT:
            try:
                event = protocol.parse_event(frame, where=self._name)
            except BoothProtocolError as err:
                self._push_event(_Garbled(err))
                return
            self._check_event_seq(event)
            self._push_event(event)
        else:
            self._replies.put(
                _Garbled(
                    BoothProtocolError(
                        f"{self._name}: received a request frame {line[:80]!r}; expected replies and events "
                        "only (is echo on, or is another host on this port?)",
                        command=None,
                        expected="'=…' or '!…' frames",
                        raw=line,
                    )
                )
            )

    def _check_event_seq(self, event: BoothEvent) -> None:
        last = self._last_event_seq
        self._last_event_seq = event.seq
        if event.kind == protocol.Event.BOOT:
            self._boots += 1  # the firmware started: its event counter starts again
            return
        if last is None:
            return
        expected = last % 255 + 1
        if event.seq != expected:
            self._push_event(
                _Garbled(
                    BoothProtocolError(
                        f"{self._name}: event sequence jumped from {last} to {event.seq}; expected {expected} "
                        "(events were lost on the link)",
                        command=None,
                        expected=f"event seq {expected}",
                        raw=event.raw,
                    )
                )
            )

    def _push_event(self, item: BoothEvent | _Garbled) -> None:
        with self._events_cv:
            self._events.append(item)
            self._events_cv.notify_all()


def _resynchronised(line: bytes, where: str) -> bytes | None:
    """The whole frame at the end of a damaged ``line``, if one is there (a byte lost from a frame may be
    its line end: the next frame then follows it on the same line), else None."""
    marks = (protocol.MARK_REPLY.encode(), protocol.MARK_EVENT.encode())
    for start in range(1, len(line)):
        if line[start : start + 1] in marks:
            try:
                protocol.parse_frame(line[start:], where=where)
            except BoothProtocolError:
                continue
            return line[start:]
    return None


def open_serial_port(url: str, baudrate: int, read_timeout_s: float, write_timeout_s: float) -> serial.SerialBase:
    """The serial port of a booth, opened exclusively, or one :class:`BoothError` line saying why not.

    Exclusive: a second host on the same booth (another msflash) would take replies meant for this
    one and drive the LEDs under its frames; it is refused as a busy port instead. Every booth driver
    and the doctor's probe open their port here.

    Raises
    ------
    BoothNotFoundError
        If the port does not exist.
    BoothError
        If it cannot be opened (permissions, busy, a malformed pyserial URL).
    """
    try:
        return serial.serial_for_url(
            url, baudrate=baudrate, timeout=read_timeout_s, write_timeout=write_timeout_s, exclusive=True
        )
    except serial.SerialException as err:
        raise port_open_error(url, err) from err
    except ValueError as err:
        raise BoothError(f"booth {url}: cannot open ({err}); expected a device path or pyserial URL") from err


def port_open_error(url: str, err: serial.SerialException) -> BoothError:
    """The one-line error for a serial port that did not open (missing, no permission, busy), naming ``url``."""
    code = getattr(err, "errno", None)
    text = str(err)
    # pyserial folds the OSError into its message, so match the errno text as well as the code.
    if code == errno.ENOENT or "[Errno 2]" in text or "No such file" in text:
        return BoothNotFoundError(
            f"booth {url}: no such port; expected an existing serial device "
            "(run 'msflash doctor' or 'msflash devices' to list booths)"
        )
    if code == errno.EACCES or "Permission denied" in text or "[Errno 13]" in text:
        return BoothError(
            f"booth {url}: permission denied; expected read/write access — add your user to "
            "the 'dialout' group (sudo usermod -aG dialout $USER, then log in again)"
        )
    if code == errno.EBUSY or "[Errno 16]" in text or "exclusively lock" in text:
        return BoothError(f"booth {url}: port busy; expected it free — close other programs using it")
    return BoothError(f"booth {url}: cannot open ({text}); expected a serial device or pyserial URL")


def levels_close(a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether two level vectors agree to within one 16-bit wire step."""
    return len(a) == len(b) and all(math.isclose(x, y, abs_tol=1.0 / protocol.LEVEL_MAX) for x, y in zip(a, b))
