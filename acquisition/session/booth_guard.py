"""What every capture engine owes the booth: its watchdog covered, its failures named, LEDs off at the end.

The booth's watchdog (``docs/booth-protocol.md`` §7) switches the LEDs off when the host has been
silent for its period, but a capture is silent on purpose for a whole booth- or camera-master
table or a whole host-paced exposure (:func:`host_silence_s`). When the watchdog is shorter, it is
raised for the sequence and set back afterwards (:meth:`led_controller.LedBooth.watchdog_covering`);
otherwise a long sequence was aborted half way, or a long LED exposure silently lit only in part.
A frame exposed while the watchdog had switched the LEDs off is refused (:func:`check_watchdog`).

Whatever happens the LEDs go off (``OFF`` also aborts a running table) and the camera stops
(:func:`switch_off`); when the capture ends in an error, a failure of that cleanup (the booth's
link is what failed) is logged and the original error is raised, not the cleanup's.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from contextlib import AbstractContextManager, ExitStack, contextmanager

from msflash.acquisition.devices.camera import Camera
from msflash.acquisition.errors import BoothStepError, CaptureError
from msflash.acquisition.plan import CapturePlan
from msflash.led_controller.booth_interface import Booth
from msflash.led_controller.errors import BoothError

log = logging.getLogger(__name__)

TRIGGER_PULSE_US = 100
"""Width of the booth's trigger pulse in booth-master mode."""

READOUT_US = 2_000
"""Camera readout / host slack added to each booth-master period beyond exposure and deadtime."""

WATCHDOG_SLACK_S = 0.5
"""Host pauses on top of a plan's scheduled silence towards the booth (writing a frame, the flash
decision, the OS scheduler), in seconds: see :func:`host_silence_s`."""


def booth_period_us(plan: CapturePlan) -> int:
    """Booth-master step period: settle + pulse + longest exposure + deadtime + readout, in µs."""
    longest = max((s.exposure_us for s in plan.steps), default=0.0)
    return int(math.ceil(plan.settle_s * 1e6 + TRIGGER_PULSE_US + longest + plan.deadtime_s * 1e6 + READOUT_US))


def host_silence_s(plan: CapturePlan) -> float:
    """The longest the host may send the booth nothing while it runs ``plan``, in seconds.

    The booth's watchdog must not fire meanwhile (``docs/booth-protocol.md`` §7: it switches the
    LEDs off and aborts the table). Host paced: one step — the ``SET``, the exposure and the wait
    for its frame, at most ``plan.frame_timeout_s`` before the host gives up and sends ``OFF``.
    Booth and camera master: the whole table runs without a command — one
    :func:`booth_period_us` per step, one more period and the frame timeout for the last frame
    (the wait for ``DONE``). Both plus :data:`WATCHDOG_SLACK_S`.

    Examples
    --------
    >>> from msflash.acquisition.plan import CapturePlan
    >>> round(host_silence_s(CapturePlan.ambient_then_each_led(7, 10_000.0)), 3)
    1.513
    >>> round(host_silence_s(CapturePlan.ambient_then_each_led(7, 500_000.0, trigger="booth")), 3)
    6.549
    """
    if plan.trigger == "software":
        return plan.frame_timeout_s + WATCHDOG_SLACK_S
    return (len(plan.steps) + 1) * booth_period_us(plan) * 1e-6 + plan.frame_timeout_s + WATCHDOG_SLACK_S


def check_watchdog(booth: Booth, where: str, saved: str = "") -> None:
    """Refuse the frame of ``where`` (a step) if the booth's watchdog switched the LEDs off meanwhile.

    The host was silent for longer than the booth's watchdog (a stall beyond
    :func:`host_silence_s`): the frame may have been exposed partly or wholly dark, and a host-paced
    sequence would not notice otherwise. ``saved`` says what is on disk.
    """
    if booth.watchdog_fired():
        raise CaptureError(
            f"{where}: the booth's watchdog switched the LEDs off during this frame (the host was silent for "
            f"longer than its period); expected the LEDs on until the frame was in — the frame is not kept"
            + (f". {saved}" if saved else "")
        )


def sequence_watchdog(booth: Booth, plan: CapturePlan) -> AbstractContextManager[None]:
    """At the start of a sequence: a ``WDOG`` event from before it (LEDs left on by earlier code,
    then forgotten) is dropped — it says nothing of this sequence's frames, which
    :func:`check_watchdog` judges — and the watchdog is covered for ``plan`` (:func:`watchdog_covering`)."""
    if booth.watchdog_fired():
        log.info("the booth's watchdog had switched the LEDs off before this sequence")
    return watchdog_covering(booth, plan)


def watchdog_covering(booth: Booth, plan: CapturePlan) -> AbstractContextManager[None]:
    """The booth's watchdog kept from firing while ``plan`` runs (:meth:`Booth.watchdog_covering`).
    Leaves the ``WDOG`` events alone: within a sequence (the flash step) they are this sequence's,
    for :func:`check_watchdog`."""
    return booth.watchdog_covering(host_silence_s(plan))


def switch_off(camera: Camera, booth: Booth, error: BaseException | None) -> None:
    """LEDs off (``OFF`` also aborts a running table), then the camera stopped.

    After an ``error``, a failure to switch off or to stop (when the booth's link is what failed,
    ``OFF`` cannot get through either) is logged, not raised: the original error is the one that
    says what went wrong (and the booth's watchdog switches off a silent host's LEDs).
    """
    if error is None:
        try:
            booth.all_off()
        finally:
            camera.stop()
        return
    try:
        booth.all_off()
    except Exception as off_err:  # noqa: BLE001 - the original error matters more
        log.warning(
            "LEDs not confirmed off after the error: %s; the booth's watchdog switches them off "
            "once the host has been silent for its period",
            off_err,
        )
    try:
        camera.stop()
    except Exception as stop_err:  # noqa: BLE001 - the original error matters more
        log.warning("stopping the camera after the error failed: %s", stop_err)


def close_stack(stack: ExitStack, error: BaseException | None) -> None:
    """Leave the contexts of ``stack`` (the watchdog covers) as a ``with`` block would after ``error``."""
    if error is None:
        stack.close()
    else:
        stack.__exit__(type(error), error, error.__traceback__)


@contextmanager
def booth_errors_at(where: str, saved: str = "") -> Iterator[None]:
    """A booth failure within the block raised as :class:`BoothStepError` naming ``where`` (a step).

    The driver's message names the port and the command, not what the capture was doing; the user
    needs both. ``saved`` says what is on disk.
    """
    try:
        yield
    except BoothStepError:
        raise
    except BoothError as err:
        raise BoothStepError(f"{where}: {err}" + (f". {saved}" if saved else "")) from err
