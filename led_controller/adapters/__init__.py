"""Booths behind the :class:`~led_controller.booth_interface.Booth` interface, opened by protocol name.

``msflash`` is :class:`led_controller.LedBooth` (``docs/booth-protocol.md``); ``text`` is
:class:`led_controller.adapters.text_booth.TextBooth` (``docs/booth-adapters.md``).
"""

from __future__ import annotations

from pathlib import Path

from msflash.led_controller.adapters.text_booth import TextBooth
from msflash.led_controller.booth import LedBooth
from msflash.led_controller.booth_handshake import DEFAULT_BOOT_S
from msflash.led_controller.booth_interface import Booth

BOOTH_PROTOCOLS = ("msflash", "text")
"""``--booth-protocol`` names, the default first."""


def open_booth(
    port: str,
    protocol: str = "msflash",
    *,
    log_serial: str | Path | None = None,
    timeout_s: float = 1.0,
    boot_s: float = DEFAULT_BOOT_S,
) -> Booth:
    """The booth at ``port`` speaking ``protocol`` (a name of :data:`BOOTH_PROTOCOLS`), opened and identified.

    ``timeout_s`` is the reply timeout of each command, in seconds; ``boot_s`` how long to let a board
    that resets when its port opens boot before asking it anything (``--booth-boot-s``,
    :data:`led_controller.booth.DEFAULT_BOOT_S`; 0: ask at once).

    Raises
    ------
    ValueError
        An unknown protocol name.
    BoothError
        The port did not open or answer in that protocol.
    """
    if protocol == "msflash":
        return LedBooth.open(port, log_serial=log_serial, timeout_s=timeout_s, boot_s=boot_s)
    if protocol == "text":
        return TextBooth.open(port, log_serial=log_serial, timeout_s=timeout_s, boot_s=boot_s)
    raise ValueError(f"--booth-protocol {protocol!r}: unknown; expected one of {', '.join(BOOTH_PROTOCOLS)}")
