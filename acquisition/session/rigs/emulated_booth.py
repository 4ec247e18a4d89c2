"""The simulated rigs' own booth: the booth emulator on a pty, driven by the real ``LedBooth``.

Shared by the ``sim``, ``aravis-fake`` and ``replay:DIR`` rigs: the emulator for a set of LEDs
(:func:`check_emulated_booth` refuses LEDs it cannot serve, in one line), served on a new pty with
a short bootloader window (:data:`SIM_BOOTLOADER_S`), and the trigger-line callbacks that run on
the emulator's thread (:func:`trigger_line`: a failure is logged and kept, never raised there).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from pathlib import Path

from msflash.acquisition.errors import RigOpenError, UsageError
from msflash.led_controller import BoothEmulator, LedBooth, serve_on_pty
from msflash.led_controller.errors import BoothProtocolError
from msflash.led_controller.protocol import Command, encode_request, parse_frame, parse_identify, parse_reply
from msflash.processing.led_wavelength import led_peaks_nm
from msflash.processing.spectra import Spectra

log = logging.getLogger(__name__)


def line_callback(rig_errors: list[BaseException], what: str, action: Callable[[], None]) -> Callable[..., None]:
    """A trigger-line callback for the emulator's thread: failures are logged and kept, never raised there."""

    def fire(*_args: object) -> None:
        try:
            action()
        except Exception as err:  # noqa: BLE001 - raising would kill the emulator's thread
            log.error("%s failed: %s", what, err)
            rig_errors.append(err)

    return fire


def emulator_for(leds: Spectra) -> BoothEmulator:
    return BoothEmulator(names=[n.replace(" ", "_") for n in leds.names], peaks_nm=led_peaks_nm(leds))


SIM_BOOTLOADER_S = 0.2
"""The bootloader window of the simulated rigs' own booth, in seconds: it resets when the driver opens its
pty, as a stock Mega does, and swallows what is sent meanwhile, but boots faster than a Mega's 1.6 s
(:data:`led_controller.usb_link.MEGA_BOOTLOADER_S`) so every simulated run does not wait for it. The
full window is what ``--booth-port`` against ``msflash booth-emulator`` or the firmware in simavr sees."""


def open_emulated_booth(leds: Spectra, log_serial: str | Path | None, closers: list) -> tuple[BoothEmulator, LedBooth]:
    """The booth emulator for ``leds`` served on a new pty, and the ``LedBooth`` driver on that pty.

    Each part's closer is appended to ``closers`` as soon as the part is open, so the caller's
    :func:`close_all` undoes a partial open.

    Raises
    ------
    RigOpenError
        Naming the pty (``booth emulator on /dev/pts/N: …``) when any part fails.
    """
    port = "a new pty"
    try:
        emulator = emulator_for(leds)
        server = serve_on_pty(emulator, bootloader_s=SIM_BOOTLOADER_S)
        closers.append(server.close)
        port = server.port
        booth = LedBooth.open(server.port, log_serial=log_serial)
        closers.append(booth.close)
        closers.append(booth.all_off)
    except Exception as err:
        raise RigOpenError(f"booth emulator on {port}: {err}") from err
    return emulator, booth


def close_all(closers: list) -> None:
    for closer in reversed(closers):
        with contextlib.suppress(Exception):
            closer()


def check_emulated_booth(leds: Spectra, where: str) -> None:
    """Whether the booth emulator can serve one channel per LED of ``leds``; a one-line error if not.

    The emulator is built for ``leds`` as the rig would build it and asked to identify itself (its
    reply parsed by the driver's parser), so every limit of the firmware and the wire format is
    checked as it applies: 1–64 channels, names that are plain words (spaces become ``_``; no
    commas, ``*`` or non-ASCII), and an identify reply that fits one frame.

    Raises
    ------
    UsageError
        Naming ``where`` (the option or file the LEDs came from), the channels and the limit.
    """
    names = leds.names if leds.count <= 8 else (*leds.names[:3], "…", leds.names[-1])
    channels = f"{leds.count} LED channel(s) ({', '.join(names)})"
    try:
        emulator = emulator_for(leds)
        replies: list[bytes] = []
        emulator.connect_output(replies.append)
        emulator.receive(encode_request(1, Command.IDENTIFY))
        raw = b"".join(replies).rstrip(b"\r\n")
        # The emulator refuses names whose identify reply would pass the protocol's 1024 bytes.
        frame = parse_frame(raw, where="booth emulator", command=Command.IDENTIFY)
        info = parse_identify(parse_reply(frame, Command.IDENTIFY, where="booth emulator"), raw, where="booth emulator")
    except (ValueError, BoothProtocolError) as err:
        raise UsageError(
            f"{where}: {channels}: the booth emulator cannot serve them ({err}); expected 1–64 "
            "channels named by plain ASCII words whose identify reply fits one frame"
        ) from err
    if info.channels != leds.count:
        raise UsageError(f"{where}: {channels}: the booth emulator reports {info.channels}; expected one per LED")
