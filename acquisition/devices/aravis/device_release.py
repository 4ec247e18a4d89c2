"""Letting go of a GigE Vision device whose control is lost, on a thread that may finalise it.

Aravis 0.8's heartbeat thread emits ``control-lost`` holding a reference to the device; if the application
drops its own meanwhile (:meth:`AravisCamera.close` right after a camera died), the device is finalised *on
the heartbeat thread*, which then joins itself: GLib aborts the process, or the join waits forever on a
handler that needs the GIL (docs/steady-tests.md). So a device known to be lost or unreachable is handed to :func:`release_lost_device`: a thread
of its own keeps it until its ``control-lost`` emission is over, then drops the last references
itself (finalising it there joins the heartbeat thread from another thread, as GLib requires). A
device that still answers is released by the caller at once: no emission can be in flight.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

log = logging.getLogger(__name__)

LOSS_WAIT_S = 30.0
"""How long to wait for a silent device's ``control-lost`` (Aravis 0.8.26 emits it after a 1 s
heartbeat period, 5 s of retries and a read's own 5 × 500 ms: about 8.5 s at most)."""
EMISSION_END_S = 2.0
"""Margin after the handler ran for the emission to drop its reference. The emission's remaining
work after the last handler is unsetting its argument values — microseconds — but it is not
observable from Python; seconds cover a heartbeat thread descheduled on a loaded host."""


def release_lost_device(device: Any, owners: tuple[Any, ...], lost: threading.Event, name: str) -> threading.Thread:
    """Keep ``device`` (and ``owners``, the objects holding it) until its ``control-lost`` emission ends.

    Parameters
    ----------
    device
        The ``Aravis.Device`` of a camera whose control was lost or that stopped answering.
    owners
        Other references to drop with it (the ``Aravis.Camera``); the caller keeps none.
    lost
        Set by the caller's own ``control-lost`` handler, still connected when this is called:
        an emission before this function connects its handler has set it.

    Returns
    -------
    threading.Thread
        The thread that releases them; not a daemon, so the interpreter finalises the device
        there, never at exit on the heartbeat thread.
    """
    emitted = threading.Event()

    def on_lost(_device: Any) -> None:  # on the heartbeat thread, inside the emission
        emitted.set()

    handler = device.connect("control-lost", on_lost)
    if lost.is_set():
        emitted.set()
    holder: list[Any] = [device, *owners]

    def release() -> None:
        if not emitted.wait(LOSS_WAIT_S):
            log.info("%s: no control-lost within %g s; releasing the device", name, LOSS_WAIT_S)
        time.sleep(EMISSION_END_S)  # a margin, not a wait for an event: see EMISSION_END_S
        try:
            holder[0].disconnect(handler)
        except TypeError:  # pragma: no cover - already disconnected
            pass
        holder.clear()  # the last references: the device is finalised here

    thread = threading.Thread(target=release, name=f"aravis-release-{name}", daemon=False)
    thread.start()
    return thread
