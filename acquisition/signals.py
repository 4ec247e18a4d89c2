"""The signals that stop a command, and the three ways msflash lets them stop it cleanly.

A command stops on Ctrl-C (``SIGINT``), ``SIGTERM`` (a service manager, ``kill``) and ``SIGHUP``
(the terminal or the SSH session closed under a running capture): :data:`STOPPING_SIGNALS`, the
one list every part of msflash uses. Python raises ``KeyboardInterrupt`` for the first and kills
the process where it stands for the other two, which would leave the LEDs on until the booth's
watchdog fires and half-written outputs behind. So :func:`sigterm_as_exit` turns the other two into
:class:`Terminated` (a ``SystemExit``: every ``with`` block unwinds as on Ctrl-C), :func:`hold_stopping_signals`
holds all three across a short gap that must not be cut, and :func:`signals_deferred` records them while a block
that cannot be interrupted runs (:func:`deliver_deferred` raises the first afterwards). Each works in the main thread only (Python delivers signals there); elsewhere it does nothing.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator

TERMINATING_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
"""The stopping signals whose default action kills the process: turned into :class:`Terminated`."""

STOPPING_SIGNALS = (signal.SIGINT, *TERMINATING_SIGNALS)
"""Every signal that stops a command: Ctrl-C, SIGTERM and SIGHUP."""


class Terminated(SystemExit):
    """SIGTERM or SIGHUP, raised by :func:`sigterm_as_exit` (exit status 128 + the signal's number): the CLI
    says so in one line."""


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def sigterm_as_exit() -> Iterator[None]:
    """Turn SIGTERM and SIGHUP (:data:`TERMINATING_SIGNALS`) into :class:`Terminated` while active.

    Then ``with LedBooth…`` blocks switch the LEDs off and writers finish or remove what they
    wrote, as on Ctrl-C. The previous handlers are restored on exit.
    """
    if not _in_main_thread():
        yield
        return

    def _raise(signum: int, _frame: object) -> None:
        raise Terminated(128 + signum)

    previous = {number: signal.signal(number, _raise) for number in TERMINATING_SIGNALS}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def hold_stopping_signals() -> Callable[[], None]:
    """Hold the stopping signals from now; returns the call that releases them (once; idempotent).

    For a few instructions that must not be cut: a signal that comes meanwhile is recorded instead of acted
    on, and the release restores the handlers and raises it. Held by the handlers, not by the main thread's
    signal mask: a process-directed signal lands on any thread that does not block it (OpenBLAS's,
    OpenImageIO's), and Python runs its handler in the main thread at once. A plain function rather than a
    ``with`` block, because the release belongs inside the ``try`` whose cleanup takes charge of what the held
    instructions made (an export's staging folder).
    """
    if not _in_main_thread():
        return lambda: None
    held: list[int] = []
    previous = [signal.signal(number, lambda number, _frame: held.append(number)) for number in STOPPING_SIGNALS]
    released = False

    def release() -> None:
        nonlocal released
        if not released:
            released = True
            for number, handler in zip(STOPPING_SIGNALS, previous, strict=True):
                signal.signal(number, handler)
            deliver_deferred(held)

    return release


@contextlib.contextmanager
def signals_deferred(held: list[int]) -> Iterator[None]:
    """Record the stopping signals that arrive while the block runs in ``held``, instead of acting on them.

    For a block that calls into a library which cannot be interrupted half way (a dask cluster
    starting or closing); the caller raises them once that is safe (:func:`deliver_deferred`).
    """
    if not _in_main_thread():
        yield
        return
    previous = [signal.signal(number, lambda number, _frame: held.append(number)) for number in STOPPING_SIGNALS]
    try:
        yield
    finally:
        for number, handler in zip(STOPPING_SIGNALS, previous, strict=True):
            signal.signal(number, handler)


def deliver_deferred(held: list[int]) -> None:
    """Raise the first signal :func:`signals_deferred` recorded, as its own handler would have (KeyboardInterrupt…)."""
    if held:
        signal.raise_signal(held.pop(0))
