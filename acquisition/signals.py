"""The signals that stop a command, and the ways msflash lets them stop it cleanly.

A command stops on Ctrl-C (``SIGINT``), ``SIGTERM`` (a service manager, ``kill``) and ``SIGHUP``
(the terminal or the SSH session closed under a running capture): :data:`STOPPING_SIGNALS`, the
one list every part of msflash uses. Python raises ``KeyboardInterrupt`` for the first and kills
the process where it stands for the other two, which would leave the LEDs on until the booth's
watchdog fires and half-written outputs behind. So :func:`command_signals` (the CLI's ``main``, from its first
instruction to its last) and :func:`sigterm_as_exit` (the Python API's capture blocks) turn them into exceptions —
:class:`Terminated` is a ``SystemExit``: every ``with`` block unwinds as on Ctrl-C — *once*: a second signal is
recorded, never raised inside the cleanup the first one unwinds; a signal the process ignores (``nohup``) stays
ignored; a stop dropped unraised (C code that clears exceptions, a finalizer) is delivered again.
:func:`hold_stopping_signals` holds all three across a short gap that must not be cut, :func:`signals_deferred` records
them while a block that cannot be interrupted runs (:func:`deliver_deferred` raises the first afterwards), and
:func:`handlers_kept` puts back what asyncio's loop replaced. Each works in the main thread only (Python delivers
signals there); elsewhere it does nothing.
"""

from __future__ import annotations

import _thread
import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, cast

TERMINATING_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
"""The stopping signals whose default action kills the process: turned into :class:`Terminated`."""

STOPPING_SIGNALS = (signal.SIGINT, *TERMINATING_SIGNALS)
"""Every signal that stops a command: Ctrl-C, SIGTERM and SIGHUP."""


class _Watched:
    """A stop that tells the handler which raised it (:attr:`owner`) when it is dropped before anyone
    :attr:`received` it: then the signal is delivered again (:meth:`_Stop.lost`).

    A handler's exception is raised in whatever Python code runs next, and some C code calling Python code clears
    every exception it gets back (CPython 3.11's ``import`` of a module object with a Python ``__getattr__``, as
    colour-science's; ``PyObject_HasAttr``; ``PyDict_GetItem``): the stop would vanish there (docs/reliability.md)."""

    owner: _Stop | None = None
    signal_number = 0
    received = False
    """Set by whoever catches the stop and acts on it (:func:`received`): then dropping it loses nothing."""

    def __del__(self) -> None:
        if self.owner is not None and not self.received:
            self.owner.lost(self.signal_number)


class Terminated(_Watched, SystemExit):
    """SIGTERM or SIGHUP, raised by :func:`sigterm_as_exit` (exit status 128 + the signal's number): the CLI
    says so in one line."""


class _Interrupted(_Watched, KeyboardInterrupt):
    """Ctrl-C, as a command's handler raises it: a ``KeyboardInterrupt`` that is delivered again if it is lost."""


def _watched_stop(owner: _Stop, number: int) -> BaseException:
    """The stop ``owner`` raises for ``number``: :class:`_Interrupted` for Ctrl-C, :class:`Terminated` else."""
    stop: _Watched = _Interrupted() if number == signal.SIGINT else Terminated(128 + number)
    stop.owner, stop.signal_number = owner, number
    return cast(BaseException, stop)


def carried_stop(error: BaseException) -> BaseException | None:
    """The stop ``error`` carries as its cause or context — a cleanup that failed while the stop unwound it — if one is
    there that nobody :func:`received` and whose command still runs; else None. Not left to the stop's finalizer: kept
    in a reference cycle (a frame that stored it), it would be freed by a collection, whenever that comes."""
    seen: set[int] = set()
    link: BaseException | None = error
    while link is not None and id(link) not in seen:
        seen.add(id(link))
        if isinstance(link, _Watched) and not link.received and link.owner is not None and link.owner.active:
            return link
        link = link.__cause__ or link.__context__
    return None


def received(stop: BaseException) -> None:
    """Say that ``stop`` (a ``KeyboardInterrupt`` or :class:`Terminated`) was caught and acted on: dropping it
    after this does not deliver it again. For the places that end a command on a stop rather than re-raise it."""
    if isinstance(stop, _Watched):
        stop.received = True


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


FORCING_CTRL_C = 3
"""Ctrl-C pressed this many times in one command ends it at once, its cleanup cut short: a person insisting is never
left with a process that will not stop (a cleanup waiting on a device that no longer answers)."""


def _forced_exit() -> None:
    """End the process now (exit 130), saying so in one line: the cleanup was cut short, and an LED left on goes off
    only when the booth's watchdog fires (docs/booth-protocol.md §7; :mod:`acquisition.session.booth_guard`)."""
    os.write(
        2,
        f"msflash: stopped at once (Ctrl-C {FORCING_CTRL_C} times): cleanup cut short; an LED left on goes off "
        "only by the booth's watchdog\n".encode(),
    )
    os._exit(128 + signal.SIGINT)


class _Stop:
    """The handler of the stopping signals while a command runs: the first signal raises (``KeyboardInterrupt`` for
    Ctrl-C, :class:`Terminated` for the others), every later one is recorded in :attr:`late` instead.

    One raise per command: a second signal (the terminal closing after a ``kill``, a service manager's SIGTERM
    repeated, Ctrl-C pressed again) would otherwise land inside the ``finally`` blocks the first one unwinds —
    switching the LEDs off, finishing ``sequence.json`` — and cut them short. Ctrl-C pressed :data:`FORCING_CTRL_C`
    times is the exception: the person insists, and the process ends at once. After :meth:`quiet` (the command has
    finished) even the first is only recorded, for the CLI to report once its outcome is written."""

    def __init__(self) -> None:
        self.raising = True
        self.raised: int | None = None
        """The signal raised, if one was."""
        self.late: list[int] = []
        """The signals recorded instead of raised."""
        self.active = False
        """Installed as the handler (:func:`_install` to :func:`_restore`): only then is a lost stop delivered again."""
        self.quieted = False
        self.presses = 0
        """Ctrl-C pressed so far: at :data:`FORCING_CTRL_C`, the process ends at once."""
        self.again = False
        self.in_flight = False
        """A signal :meth:`lost` is delivering again has not landed yet (:meth:`settle` waits for it)."""
        self.delivery = _thread.allocate_lock()
        """Held while a signal is delivered again, and while the handler is closed: none is sent once it is."""
        self.pending: int | None = None
        """The signal :meth:`lost` is about to send again (not sent yet)."""

    def __call__(self, number: int, _frame: object) -> None:
        self.in_flight = False
        if number == signal.SIGINT:
            if self.again:  # the one :meth:`lost` delivers again: not a press
                self.again = False
            else:
                self.presses += 1
        if not self.raising:
            self.late.append(number)
            if self.presses >= FORCING_CTRL_C:
                _forced_exit()
            return
        self.raising = False  # before raising: a signal landing while this one unwinds is recorded
        self.raised = number
        raise _watched_stop(self, number)  # no local name: this frame, in its traceback, would keep it alive

    def swallowed(self, unraisable: Any) -> bool:
        """Whether the exception Python could not raise (``sys.unraisablehook``) is one this handler raised: then
        the signal is delivered again (:meth:`lost`), to land once the finalizer it hit has returned.

        A signal whose handler runs inside a ``__del__``, a weakref callback or a garbage collection raises there,
        and Python prints "Exception ignored in …" with a traceback and goes on: the stop was lost (the traceback
        seen once under load, with SIGTERM)."""
        stop = unraisable.exc_value
        if not isinstance(stop, _Watched) or stop.owner is not self:
            return False
        stop.received = True  # delivered again now, not when the hook lets go of it
        self.lost(stop.signal_number)
        return True

    def lost(self, number: int) -> None:
        """The stop this handler raised for ``number`` was dropped unreceived (:class:`_Watched`): while the command
        runs, deliver the signal again, from a thread of its own, to be raised anew; once it has finished
        (:meth:`quiet`), record it in :attr:`late` for the CLI to say."""
        if not self.active:
            return
        self.raised = None
        if self.quieted:
            self.late.append(number)
            return
        self.raising, self.again, self.in_flight, self.pending = True, number == signal.SIGINT, True, number
        main = threading.main_thread().ident
        assert main is not None  # the main thread has started: the handler ran in it
        # Not threading.Thread: its start() waits for the thread, and the signal would land in that wait, inside the
        # finalizer or hook calling this. The thread sends it once this call has let go of ``leaving``.
        leaving = _thread.allocate_lock()
        leaving.acquire()

        def deliver() -> None:
            with leaving, self.delivery:
                if self.pending is not None:  # else :meth:`close` took it: the handlers may be gone
                    self.pending = None
                    signal.pthread_kill(main, number)

        _thread.start_new_thread(deliver, ())
        leaving.release()

    def quiet(self) -> None:
        """From now on record every stopping signal rather than raise it."""
        self.raising = False
        self.quieted = True

    def close(self) -> None:
        """End the command's handling (idempotent): record from now on (:meth:`quiet`), let a signal being delivered
        again land (:meth:`settle`), record one not sent yet instead of sending it later — before the handlers are put
        back and before :attr:`late` is read."""
        self.quiet()
        self.settle()
        with self.delivery:  # a delivering thread that has not sent by now never will: its signal is recorded
            self.active = False
            if self.pending is not None:
                self.late.append(self.pending)
                self.pending, self.in_flight = None, False
        self.settle()  # one sent just before lands here, while this handler is still installed

    def settle(self) -> None:
        """Wait, a second at most, for a signal :meth:`lost` is delivering again to land while this handler is still
        installed (recorded in :attr:`late` once :meth:`quiet`): not after the command's handlers were put back, where
        Python's own would raise it with a traceback."""
        deadline = time.monotonic() + 1.0
        while self.in_flight and time.monotonic() < deadline:
            time.sleep(0.001)  # the signal interrupts the sleep, and its handler runs here


def _install(stop: _Stop, numbers: tuple[int, ...]) -> dict[int, object]:
    """``stop`` as the handler of ``numbers``, but for a signal the process was told to ignore (``nohup`` ignores
    SIGHUP, a shell's background job SIGINT: the user asked to survive them); the previous handlers."""
    previous: dict[int, object] = {}
    stop.active = True
    for number in numbers:
        if signal.getsignal(number) is not signal.SIG_IGN:
            previous[number] = signal.signal(number, stop)
    return previous


def _restore(previous: dict[int, object]) -> None:
    for number, handler in previous.items():
        signal.signal(number, handler)  # type: ignore[arg-type]


@contextlib.contextmanager
def _redelivered_from_finalizers(stop: _Stop) -> Iterator[None]:
    """While the block runs, a stop raised inside a finalizer is delivered again (:meth:`_Stop.swallowed`) instead
    of printed as an ignored exception."""
    previous = sys.unraisablehook

    def hook(unraisable: Any) -> None:
        if not stop.swallowed(unraisable):
            previous(unraisable)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous


@contextlib.contextmanager
def sigterm_as_exit() -> Iterator[None]:
    """Turn SIGTERM and SIGHUP (:data:`TERMINATING_SIGNALS`) into :class:`Terminated` while active (once: a second
    signal is recorded, not raised, so it cannot cut the cleanup the first one unwinds).

    Then ``with LedBooth…`` blocks switch the LEDs off and writers finish or remove what they
    wrote, as on Ctrl-C. The previous handlers are restored on exit. Inside :func:`command_signals` (the CLI's
    ``main``) it changes nothing: the command's handler already does this, for the whole command. A signal the
    process ignores (``nohup``'s SIGHUP) stays ignored. Code inside the block that catches the :class:`Terminated`
    and carries on says so with :func:`received`; else, dropped, it is delivered again (:class:`_Watched`).
    """
    if not _in_main_thread() or isinstance(signal.getsignal(signal.SIGTERM), _Stop):
        yield
        return
    stop = _Stop()
    previous = _install(stop, TERMINATING_SIGNALS)
    try:
        with _redelivered_from_finalizers(stop):
            yield
    finally:
        stop.close()  # a signal while the handlers are put back is recorded, not raised out of this block
        _restore(previous)
    if stop.raised is None and stop.late:  # the block ended as a stop came, or one it caught and dropped came back
        raise Terminated(128 + stop.late[0])


@contextlib.contextmanager
def command_signals() -> Iterator[_Stop]:
    """Every stopping signal (:data:`STOPPING_SIGNALS`) raised once, from the first instruction of a command to its
    last: parsing and importing its modules included (before, SIGTERM there killed the process silently), and the
    moments after it returned (a signal then was lost). The caller calls :meth:`_Stop.quiet` once the command has
    returned and reports what :attr:`_Stop.late` recorded meanwhile. Outside the main thread it yields a handler
    that is never installed."""
    stop = _Stop()
    if not _in_main_thread():
        yield stop
        return
    previous = _install(stop, STOPPING_SIGNALS)
    try:
        with _redelivered_from_finalizers(stop):
            yield stop
    finally:
        stop.close()
        _restore(previous)


@contextlib.contextmanager
def handlers_kept() -> Iterator[None]:
    """Put the stopping signals' handlers back as they were when the block began, whatever it did to them.

    asyncio's event loop takes the signals it was given (``loop.add_signal_handler``) and, when it closes, sets them
    to the *default* action, not to what was there before: ``live``'s rig, still open, could then be killed where it
    stood by a SIGTERM, its LEDs left on.
    """
    if not _in_main_thread():
        yield
        return
    previous = {number: signal.getsignal(number) for number in STOPPING_SIGNALS}
    try:
        yield
    finally:
        _restore({number: handler for number, handler in previous.items() if handler is not None})


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
    hold = _holding(held)
    previous = [signal.signal(number, hold) for number in STOPPING_SIGNALS]
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
    hold = _holding(held)
    previous = [signal.signal(number, hold) for number in STOPPING_SIGNALS]
    try:
        yield
    finally:
        for number, handler in zip(STOPPING_SIGNALS, previous, strict=True):
            signal.signal(number, handler)


def deliver_deferred(held: list[int]) -> None:
    """Raise the first signal :func:`signals_deferred` recorded, as its own handler would have (KeyboardInterrupt…)."""
    if held:
        number = held.pop(0)
        handler = signal.getsignal(number)
        if number == signal.SIGINT and isinstance(handler, _Stop):
            handler.again = True  # counted as a press when it was held
        signal.raise_signal(number)


def _holding(held: list[int]) -> Callable[[int, Any], None]:
    """The handler that records the stopping signals in ``held`` (:func:`signals_deferred`,
    :func:`hold_stopping_signals`) — counting each Ctrl-C towards the command's forced exit (:data:`FORCING_CTRL_C`),
    so that a block that never returns (a dask cluster's start that hangs) can still be ended by insisting."""
    command = signal.getsignal(signal.SIGINT)

    def hold(number: int, _frame: Any) -> None:
        held.append(number)
        if number == signal.SIGINT and isinstance(command, _Stop):
            command.presses += 1
            if command.presses >= FORCING_CTRL_C:
                _forced_exit()

    return hold
