"""``LedBooth``: the driver of an msflash LED booth over any pyserial URL.

The far end of the wire may be the real firmware, the emulator on a pseudo-terminal, or a
recorded transcript; the driver code is the same in every case. The driver is built by job:
the link (``booth_link.py``: the reader thread, the queues, the wire log, the exchange with its
retries), the booth's identity and the boot after opening (``booth_handshake.py``), the pattern
table (``booth_table.py``) and, here, opening, levels, the watchdog, status and events.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import Literal

from msflash.led_controller import protocol
from msflash.led_controller.booth_handshake import DEFAULT_BOOT_S
from msflash.led_controller.booth_interface import BoothCapabilities
from msflash.led_controller.booth_link import _Garbled, _LinkLost
from msflash.led_controller.booth_table import TimedTable
from msflash.led_controller.errors import BoothError, BoothTimeoutError
from msflash.led_controller.protocol import BoothEvent, BoothStatus, Command
from msflash.led_controller.serial_port import open_driver

log = logging.getLogger(__name__)

_READ_POLL_S = 0.02
"""Read timeout of the port: how quickly the reader thread notices ``close``."""

WATCHDOG_MAX_S = protocol.WATCHDOG_MAX_MS / 1000.0
"""Longest watchdog period the protocol allows, in seconds (:data:`led_controller.protocol.WATCHDOG_MAX_MS`)."""


class LedBooth(TimedTable):
    """Driver of an msflash LED booth (protocol v1, see ``docs/booth-protocol.md``).

    Use :meth:`open` rather than the constructor; use the booth as a context manager so that
    every exit path switches the LEDs off. An already-open ``port``'s read timeout should be short
    (tens of ms): it bounds how fast ``close`` returns. ``log_serial`` is a transcript file of
    ``> request`` / ``< reply`` / ``! event`` lines.
    """

    _watchdog_s: float | None = None
    """The booth's watchdog period once known (``STAT``, ``WDOG``)."""

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

        ``url`` is a device path (``/dev/ttyACM0``), a pty path, or a pyserial URL (``loop://``,
        ``spy:///dev/ttyACM0?file=trace.txt``); ``baudrate`` is ignored by USB CDC devices and ptys;
        ``boot_s`` 0 sends ``ID`` at once, for a board that does not reset when its port opens.
        The booth returned is identified (:attr:`info` is set).

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
        return open_driver(
            url,
            baudrate,
            (_READ_POLL_S, timeout_s),
            lambda port: cls(port, timeout_s=timeout_s, log_serial=log_serial, name=url),
            lambda booth: booth.identify_after_boot(boot_s),
        )

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
    def name(self) -> str:
        """Get the port name used in messages (str)."""
        return self._name

    @property
    def capabilities(self) -> BoothCapabilities:
        """Get the sync modes an msflash booth runs: host pacing, booth master and camera master (protocol v1)."""
        return BoothCapabilities(booth_master=True, camera_master=True)

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
