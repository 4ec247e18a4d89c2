"""What a host finds on a booth an earlier host left: a killed run's LEDs and raised watchdog.

A run covers its long silences by raising the booth's watchdog (:meth:`LedBooth.watchdog_covering`)
and sets it back when the block ends; a run killed meanwhile (SIGKILL, a crash of the machine)
leaves it raised, and its LEDs on until that longer watchdog fires. The booth cannot tell a raised
period from a chosen one, so the next host decides: :func:`reset_leftovers` switches off what is on
and sets a period longer than the protocol's power-up default back to it, saying so.
"""

from __future__ import annotations

from msflash.led_controller.booth import LedBooth
from msflash.led_controller.protocol import WATCHDOG_POWER_UP_MS


def reset_leftovers(booth: LedBooth) -> tuple[str, ...]:
    """Switch off LEDs or a sequence left running and set a raised watchdog back to the power-up period.

    One ``STAT``, then ``OFF`` and ``WDOG`` only if needed.

    Returns
    -------
    tuple of str
        One note per thing changed (empty when the booth was idle, dark and at most at the default).

    Raises
    ------
    BoothError
        The booth did not answer or refused.
    """
    status = booth.status()
    notes = []
    if any(status.levels) or status.state in ("ARMED", "RUNNING"):
        booth.all_off()
        notes.append(
            f"{booth.name}: found the LEDs on (sequence {status.state}), as a run that did not finish "
            "leaves them; switched off"
        )
    power_up_s = WATCHDOG_POWER_UP_MS / 1000.0
    if status.watchdog_s > power_up_s:
        booth.set_watchdog(power_up_s)
        notes.append(
            f"{booth.name}: found the watchdog at {status.watchdog_s:g} s, longer than the power-up "
            f"{power_up_s:g} s (raised by a run that did not finish?); set back to {power_up_s:g} s"
        )
    return tuple(notes)
