"""Who the booth is, and the wait for it to boot after its port is opened (``docs/booth-protocol.md`` §6).

Opening the port resets a stock Arduino Mega (docs/booth-firmware.md §4): :meth:`Handshake.identify_after_boot`
sends nothing until the firmware's ``BOOT`` banner or ``boot_s`` has passed, drops the bootloader's
noise and asks ``ID`` (:meth:`Handshake.identify`, which refuses another protocol version).
"""

from __future__ import annotations

import logging
import time

from msflash.led_controller import protocol
from msflash.led_controller.booth_link import BoothLink, _BootedMeanwhile, _Garbled
from msflash.led_controller.errors import BoothError, BoothProtocolError, BoothTimeoutError
from msflash.led_controller.protocol import BoothEvent, BoothInfo, Command

log = logging.getLogger(__name__)

DEFAULT_BOOT_S = 2.5
"""How long :meth:`LedBooth.open` waits, silent, for the firmware's boot banner after opening the port, in
seconds (``--booth-boot-s``). A stock Arduino Mega resets when its port is opened and its bootloader
swallows what the host sends for 1.5–2 s; the host must not send meanwhile (every byte keeps the
stk500v2 bootloader longer, ``led_controller/usb_link.py``). 0: ask at once (a board with auto-reset
disabled, or one that is not an Arduino)."""


class Handshake(BoothLink):
    """The booth's identity (``ID``) and the boot after opening, over a :class:`BoothLink`."""

    _info: BoothInfo | None = None

    @property
    def info(self) -> BoothInfo:
        """Get what :meth:`identify` last returned (:class:`BoothInfo`)."""
        if self._info is None:
            return self.identify()
        return self._info

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
        self._drop_stale_replies(quietly=True)
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
