"""``--rig sim --booth-port PORT``: the simulated camera with a booth outside this process.

The booth at ``PORT`` may be ``msflash booth-emulator`` on a pty (with ``--fault`` for link
faults) or a real booth. The simulated camera renders each frame with the levels the booth
reports (``STAT``) when the frame is triggered — what the booth holds, not what the host asked
for. No trigger wire reaches across processes, so only host pacing (``--sync host``) works.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from msflash.acquisition.errors import RigOpenError, UsageError
from msflash.led_controller import LedBooth
from msflash.led_controller.adapters import open_booth
from msflash.led_controller.booth_handshake import DEFAULT_BOOT_S
from msflash.led_controller.booth_interface import Booth
from msflash.led_controller.recovery import reset_leftovers
from msflash.processing.spectra import Spectra

log = logging.getLogger(__name__)

SYNC_WITH_EXTERNAL_BOOTH = "host"
"""The one ``--sync`` mode a simulated camera can have with a booth in another process."""


def check_booth_port(rig: str, sync: str) -> None:
    """``--booth-port`` with ``--rig`` and ``--sync``: a one-line error unless the rig is ``sim`` paced by the host.

    Raises
    ------
    UsageError
        Naming the option and what was expected.
    """
    if rig != "sim":
        raise UsageError(
            f"--booth-port: gives the simulated rig an outside booth, but the rig is '{rig}'; expected "
            "--rig sim (a hardware rig's booth is --port)"
        )
    if sync != SYNC_WITH_EXTERNAL_BOOTH:
        raise UsageError(
            f"--booth-port with --sync {sync}: no trigger wire reaches from the simulated camera to a "
            f"booth in another process; expected --sync {SYNC_WITH_EXTERNAL_BOOTH}"
        )


def open_external_booth(
    port: str,
    leds: Spectra,
    log_serial: str | Path | None,
    closers: list,
    protocol: str = "msflash",
    *,
    boot_s: float = DEFAULT_BOOT_S,
) -> Booth:
    """The booth at ``port``, identified, checked to have one channel per LED and cleared of leftovers.

    Its closers are appended to ``closers`` as soon as it is open (LEDs off, then the port).
    Leftovers of a run that did not finish are switched off and reported (:func:`reset_leftovers`;
    an adapter of another ``protocol``, :func:`led_controller.adapters.open_booth`, switches its LEDs
    off as it opens).

    Raises
    ------
    RigOpenError
        ``booth PORT: …``: the port did not open or answer as a booth, or its channels differ.
    """
    mismatch = ("the simulated LEDs are", "one channel per LED (--leds N or --led-spectra FILE.csv)")
    try:
        booth = open_checked_booth(port, protocol, log_serial, boot_s, leds, closers, mismatch)
    except RigOpenError:
        raise
    except Exception as err:  # noqa: BLE001 - every failure to open is the rig's, with the port named
        message = str(err)
        raise RigOpenError(message if message.startswith(("booth", port)) else f"booth {port}: {message}") from err
    return booth


def open_checked_booth(
    port: str,
    protocol: str,
    log_serial: str | Path | None,
    boot_s: float,
    leds: Spectra,
    closers: list,
    mismatch: tuple[str, str],
) -> Booth:
    """The booth at ``port``, its closers appended to ``closers`` as soon as it is open (LEDs off, then the port),
    checked to have one channel per LED (``mismatch``: what the LEDs are and what is expected, for the refusal) and
    cleared of a killed run's leftovers and raised watchdog (:func:`reset_leftovers`; an adapter of another
    ``protocol`` switches its LEDs off as it opens). The one opening of the sim rig's external booth and the
    hardware rig's."""
    booth = open_booth(port, protocol, log_serial=log_serial, boot_s=boot_s)
    closers.append(booth.close)
    closers.append(booth.all_off)
    if booth.info.channels != leds.count:
        raise RigOpenError(
            f"booth {port}: {booth.info.channels} channels ({', '.join(booth.info.names)}) but {mismatch[0]} "
            f"{leds.count} ({', '.join(leds.names)}); expected {mismatch[1]}"
        )
    if isinstance(booth, LedBooth):
        for note in reset_leftovers(booth):
            log.warning("%s", note)
    return booth


def levels_reported_by(booth: Booth) -> Callable[[], tuple[float, ...]]:
    """A ``led_levels_source`` for the simulated camera: the levels the booth reports now
    (:meth:`~led_controller.booth_interface.Booth.reported_levels`: one ``STAT``, or ``L?`` for a text booth)."""
    return booth.reported_levels
