"""Finding msflash booths among the serial ports (by USB VID:PID or product string).

Nothing is opened here: opening a port resets a stock Arduino and sends bytes to whatever device
is behind it. A port is a *booth* by our USB id or product string; an *Arduino Mega* by Arduino's
ids (a Mega flashed with the booth firmware keeps its 16U2's Arduino id), which ``run`` takes when
it is the only candidate; other Arduinos and common USB-serial chips (FTDI, CH340, CP210x, PL2303,
a 16U2/32U4 running LUFA) are named so the user can pass ``--port``. ``/dev/serial/by-id`` links,
stable across re-plugging and unique per board when the chip has a serial number, are shown beside
each port.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from msflash.led_controller.errors import BoothNotFoundError

log = logging.getLogger(__name__)

BOOTH_USB_IDS: frozenset[tuple[int, int]] = frozenset({(0x1209, 0x4D53)})
"""USB (vendor, product) ids of booth firmware builds (pid.codes vendor 0x1209; "MS")."""

BOOTH_PRODUCT_MARKERS = ("msflash booth", "msflash-booth")
"""Product-string fragments (case-insensitive) that identify a booth with a generic USB id."""

ARDUINO_MEGA_USB_IDS: dict[tuple[int, int], str] = {
    (0x2341, 0x0010): "Arduino Mega 2560",
    (0x2341, 0x0042): "Arduino Mega 2560 R3",
    (0x2A03, 0x0010): "Arduino Mega 2560 (arduino.org)",
    (0x2A03, 0x0042): "Arduino Mega 2560 R3 (arduino.org)",
    (0x2341, 0x003F): "Arduino Mega ADK",
    (0x2341, 0x0044): "Arduino Mega ADK R3",
}
"""USB ids of the boards the reference firmware runs on (ATmega2560, its 16U2 or 8U2 as USB-serial)."""

OTHER_ARDUINO_USB_IDS: dict[tuple[int, int], str] = {
    (0x2341, 0x0001): "Arduino Uno",
    (0x2341, 0x0043): "Arduino Uno R3",
    (0x2A03, 0x0043): "Arduino Uno R3 (arduino.org)",
    (0x2341, 0x0243): "Arduino Uno R3",
    (0x2341, 0x8036): "Arduino Leonardo",
    (0x2341, 0x8037): "Arduino Micro",
}
"""Arduino boards the reference firmware does not run on (not an ATmega2560): a text booth, perhaps."""

USB_SERIAL_CHIPS: dict[tuple[int, int], str] = {
    (0x0403, 0x6001): "FTDI FT232R USB-serial",
    (0x0403, 0x6015): "FTDI FT-X USB-serial",
    (0x0403, 0x6010): "FTDI FT2232 USB-serial",
    (0x0403, 0x6014): "FTDI FT232H USB-serial",
    (0x1A86, 0x7523): "WCH CH340 USB-serial",
    (0x1A86, 0x5523): "WCH CH341 USB-serial",
    (0x1A86, 0x55D4): "WCH CH9102 USB-serial",
    (0x10C4, 0xEA60): "Silicon Labs CP210x USB-serial",
    (0x067B, 0x2303): "Prolific PL2303 USB-serial",
    (0x03EB, 0x204B): "LUFA USB-serial (ATmega16U2/32U4)",
}
"""Common USB-serial chips: a Mega clone (CH340, FTDI), a Mega whose 16U2 runs LUFA, or any serial device."""

FTDI_VENDOR = 0x0403
"""FTDI chips hold short replies for their latency timer (16 ms by default; ``doctor`` reads it)."""


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
    by_id: str | None = None
    """Its ``/dev/serial/by-id/…`` link (stable across re-plugging), or None."""

    @property
    def usb_id(self) -> str:
        """Get ``vvvv:pppp`` in hex, or ``-`` for non-USB ports."""
        return "-" if self.vid is None or self.pid is None else f"{self.vid:04x}:{self.pid:04x}"

    @property
    def kind(self) -> str:
        """Get what the port is: ``booth``, ``arduino-mega``, ``arduino``, ``usb-serial`` or ``serial``."""
        if is_booth(self):
            return "booth"
        key = (self.vid, self.pid)
        if key in ARDUINO_MEGA_USB_IDS:
            return "arduino-mega"
        if key in OTHER_ARDUINO_USB_IDS:
            return "arduino"
        if key in USB_SERIAL_CHIPS:
            return "usb-serial"
        return "serial"

    @property
    def board(self) -> str:
        """Get the board or chip its USB id names (``Arduino Mega 2560 R3``), else its product or description."""
        key = (self.vid, self.pid)
        for table in (ARDUINO_MEGA_USB_IDS, OTHER_ARDUINO_USB_IDS, USB_SERIAL_CHIPS):
            if key in table:
                return table[key]
        return self.product or self.description or "-"

    @property
    def path(self) -> str:
        """Get the path to pass as ``--port``: the ``/dev/serial/by-id`` link when there is one."""
        return self.by_id or self.device


def list_serial_ports(dev_root: Path = Path("/dev")) -> list[SerialPortInfo]:
    """All serial ports pyserial can see, with their ``/dev/serial/by-id`` links (nothing is opened)."""
    from serial.tools import list_ports

    return with_by_id_links([from_pyserial(p) for p in list_ports.comports()], dev_root)


def by_id_links(dev_root: Path = Path("/dev")) -> dict[str, str]:
    """``/dev/ttyACM0`` → ``/dev/serial/by-id/usb-…-if00``: udev's links, read from ``dev_root/serial/by-id``.

    The device named is the link's target as seen from ``dev_root`` (``/dev/…`` for the real root).
    """
    folder = dev_root / "serial" / "by-id"
    links: dict[str, str] = {}
    try:
        entries = sorted(folder.iterdir())
    except OSError:
        return links  # no udev links (no USB-serial device, or a system without udev)
    for entry in entries:
        try:
            target = Path(os.path.normpath(entry.parent / os.readlink(entry)))
        except OSError:
            continue
        try:
            device = "/dev/" + str(target.relative_to(dev_root))
        except ValueError:
            device = str(target)
        links.setdefault(device, "/dev/serial/by-id/" + entry.name)
    return links


def with_by_id_links(ports: Iterable[SerialPortInfo], dev_root: Path = Path("/dev")) -> list[SerialPortInfo]:
    """The ports with :attr:`SerialPortInfo.by_id` filled in from ``dev_root/serial/by-id``."""
    links = by_id_links(dev_root)
    return [replace(p, by_id=links.get(p.device, p.by_id)) for p in ports]


def from_pyserial(port: Any) -> SerialPortInfo:
    """A pyserial ``ListPortInfo`` as a :class:`SerialPortInfo` (by-id link not filled in)."""
    return SerialPortInfo(
        device=port.device,
        vid=port.vid,
        pid=port.pid,
        product=port.product,
        serial_number=port.serial_number,
        description=port.description or "",
    )


def describe_port(port: SerialPortInfo) -> str:
    """One line for a port: device, board or chip, USB id, USB serial and by-id link.

    >>> describe_port(SerialPortInfo("/dev/ttyACM0", 0x2341, 0x0042, "Mega", "7523", "ttyACM0", "/dev/serial/by-id/x"))
    '/dev/ttyACM0 (Arduino Mega 2560 R3, 2341:0042, USB serial 7523, /dev/serial/by-id/x)'
    """
    parts = [port.board, port.usb_id]
    if port.serial_number:
        parts.append(f"USB serial {port.serial_number}")
    if port.by_id:
        parts.append(port.by_id)
    return f"{port.device} ({', '.join(parts)})"


def is_booth(port: SerialPortInfo) -> bool:
    """Whether a port looks like a booth (known VID:PID or a booth product string)."""
    if port.vid is not None and port.pid is not None and (port.vid, port.pid) in BOOTH_USB_IDS:
        return True
    text = f"{port.product or ''} {port.description}".lower()
    return any(marker in text for marker in BOOTH_PRODUCT_MARKERS)


def find_booths(ports: Iterable[SerialPortInfo] | None = None) -> list[SerialPortInfo]:
    """The serial ports (default: :func:`list_serial_ports`) that look like booths, in device order."""
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


def find_megas(ports: Iterable[SerialPortInfo]) -> list[SerialPortInfo]:
    """The ports of Arduino Mega boards (the reference firmware's board, by USB id), in device order."""
    return sorted((p for p in ports if p.kind == "arduino-mega"), key=lambda p: p.device)


def find_booth(ports: Iterable[SerialPortInfo] | None = None) -> SerialPortInfo:
    """The one booth among the serial ports: by our USB id or product string, else the one Arduino Mega.

    A stock Mega flashed with the booth firmware keeps the Arduino id of its 16U2, so when no port
    carries the booth id and exactly one Arduino Mega is plugged in, that one is taken (opening it
    resets it: :meth:`LedBooth.open` waits for it to boot).

    Raises
    ------
    BoothNotFoundError
        If there is no candidate or more than one; the message lists what was found and the
        ``/dev/serial/by-id`` paths to pass as ``--port``.
    """
    candidates = list_serial_ports() if ports is None else list(ports)
    booths = find_booths(candidates)
    if len(booths) == 1:
        return booths[0]
    if len(booths) > 1:
        raise BoothNotFoundError(
            f"booth discovery: {len(booths)} booths ({'; '.join(describe_port(p) for p in booths)}); "
            "expected one — pass --port to choose (a /dev/serial/by-id path stays the same across re-plugging)"
        )
    megas = find_megas(candidates)
    if len(megas) == 1:
        log.info(
            "booth discovery: no port with the booth's USB id; taking the Arduino Mega %s", describe_port(megas[0])
        )
        return megas[0]
    listing = "; ".join(describe_port(p) for p in candidates) or "none"
    if megas:
        raise BoothNotFoundError(
            f"booth discovery: {len(megas)} Arduino Megas and no port with the booth's USB id (found: {listing}); "
            "expected one — pass --port with the one running the booth firmware ('msflash doctor --port P' "
            "shows each one's firmware and SERIAL=)"
        )
    raise BoothNotFoundError(
        f"booth discovery: no booth among the serial ports (found: {listing}); expected a port "
        f"with USB id {', '.join(f'{v:04x}:{p:04x}' for v, p in sorted(BOOTH_USB_IDS))}, product "
        "'msflash booth' or an Arduino Mega — plug it in, or pass --port (a Mega clone with a CH340 or "
        "FTDI chip, or another USB-serial adapter, is found only by --port)"
    )
