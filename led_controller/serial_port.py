"""Opening a booth's serial port: exclusively, with one line saying why it did not open.

Every booth driver (``LedBooth``, ``TextBooth``) and the doctor's probe open their port here, and
the drivers their transcript of the exchange.
"""

from __future__ import annotations

import errno
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, TypeVar

import serial

from msflash.led_controller.booth_interface import Booth
from msflash.led_controller.errors import BoothError, BoothNotFoundError


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


Driver = TypeVar("Driver", bound=Booth)


def open_driver(
    url: str,
    baudrate: int,
    timeouts_s: tuple[float, float],
    driver: Callable[[serial.SerialBase], Driver],
    start: Callable[[Driver], object],
) -> Driver:
    """A booth driver on the port at ``url`` (:func:`open_serial_port`, ``timeouts_s`` read and write): ``driver``
    made on the port, then ``start``-ed (identified); the port closed if the driver cannot be made, the driver
    (switching its LEDs off) if it cannot start. Every booth driver opens through here."""
    port = open_serial_port(url, baudrate, *timeouts_s)
    try:
        made = driver(port)
    except BaseException:
        port.close()  # the driver never took the port: release it here
        raise
    try:
        start(made)
    except BaseException:
        made.close()
        raise
    return made


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


def open_transcript(path: str | Path | None, port: str, kind: str) -> IO[str] | None:
    """The serial transcript of ``port`` (None without ``path``), its header line written; one BoothError line if not."""
    if not path:
        return None
    try:
        transcript = open(path, "w", encoding="ascii", newline="\n")  # noqa: SIM115
    except OSError as err:
        raise BoothError(
            f"{port}: cannot record the serial transcript in {path} ({err.strerror or err}); expected a writable file path"
        ) from err
    transcript.write(f"# msflash {kind} transcript, port {port}, {time.strftime('%Y-%m-%d')}\n")
    return transcript
