"""Finding msflash booths among the serial ports (by USB VID:PID or product string)."""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from msflash.led_controller.errors import BoothNotFoundError

log = logging.getLogger(__name__)

BOOTH_USB_IDS: frozenset[tuple[int, int]] = frozenset({(0x1209, 0x4D53)})
"""USB (vendor, product) ids of booth firmware builds (pid.codes vendor 0x1209; "MS")."""

BOOTH_PRODUCT_MARKERS = ("msflash booth", "msflash-booth")
"""Product-string fragments (case-insensitive) that identify a booth with a generic USB id."""


@dataclass(frozen=True)
class SerialPortInfo:
    """A serial port as the system lists it."""

    device: str
    """Device path to open, e.g. ``/dev/ttyACM0``."""
    vid: int | None
    """USB vendor id, or None for non-USB ports."""
    pid: int | None
    """USB product id, or None."""
    product: str | None
    """USB product string, or None."""
    serial_number: str | None
    """USB serial number, or None."""
    description: str
    """Human-readable description."""

    @property
    def usb_id(self) -> str:
        """Get ``vvvv:pppp`` in hex, or ``-`` for non-USB ports."""
        return "-" if self.vid is None or self.pid is None else f"{self.vid:04x}:{self.pid:04x}"


def list_serial_ports() -> list[SerialPortInfo]:
    """All serial ports pyserial can see."""
    from serial.tools import list_ports

    return [_from_pyserial(p) for p in list_ports.comports()]


def _from_pyserial(port: Any) -> SerialPortInfo:
    return SerialPortInfo(
        device=port.device,
        vid=port.vid,
        pid=port.pid,
        product=port.product,
        serial_number=port.serial_number,
        description=port.description or "",
    )


def is_booth(port: SerialPortInfo) -> bool:
    """Whether a port looks like a booth (known VID:PID or a booth product string)."""
    if port.vid is not None and port.pid is not None and (port.vid, port.pid) in BOOTH_USB_IDS:
        return True
    text = f"{port.product or ''} {port.description}".lower()
    return any(marker in text for marker in BOOTH_PRODUCT_MARKERS)


def find_booths(ports: Iterable[SerialPortInfo] | None = None) -> list[SerialPortInfo]:
    """The serial ports that look like booths, in device order.

    Parameters
    ----------
    ports : iterable of SerialPortInfo or None
        Ports to look through (default: :func:`list_serial_ports`).
    """
    candidates = list_serial_ports() if ports is None else list(ports)
    found = sorted((p for p in candidates if is_booth(p)), key=lambda p: p.device)
    log.debug("booth discovery: %d of %d serial ports match", len(found), len(candidates))
    return found


def other_serial_ports(ports: Iterable[SerialPortInfo]) -> list[SerialPortInfo]:
    """The serial ports that do not look like our booths, in device order (a text booth may be among them).

    Nothing is opened: which of them is a booth only asking can tell, and only a port the user names
    is asked (:func:`text_booth_hint`).
    """
    return sorted((p for p in ports if not is_booth(p)), key=lambda p: p.device)


def text_booth_hint(device: str) -> str:
    """How to ask the port ``device`` whether it is a plain-text booth.

    >>> text_booth_hint("/dev/ttyUSB0")
    "'msflash doctor --port /dev/ttyUSB0 --booth-protocol text' to check a text booth"
    """
    return f"'msflash doctor --port {device} --booth-protocol text' to check a text booth"


def find_booth(ports: Iterable[SerialPortInfo] | None = None) -> SerialPortInfo:
    """The one booth among the serial ports.

    Raises
    ------
    BoothNotFoundError
        If there is no booth or more than one; the message lists what was found.
    """
    candidates = list_serial_ports() if ports is None else list(ports)
    booths = find_booths(candidates)
    if len(booths) == 1:
        return booths[0]
    listing = ", ".join(f"{p.device} ({p.usb_id} {p.product or p.description})" for p in candidates) or "none"
    if not booths:
        raise BoothNotFoundError(
            f"booth discovery: no booth among the serial ports (found: {listing}); expected a port "
            f"with USB id {', '.join(f'{v:04x}:{p:04x}' for v, p in sorted(BOOTH_USB_IDS))} or product "
            "'msflash booth' — plug it in, or pass --port"
        )
    raise BoothNotFoundError(
        f"booth discovery: {len(booths)} booths ({', '.join(p.device for p in booths)}); "
        "expected one — pass --port to choose"
    )
