"""The moments a stopping signal was not turned into one line (docs/reliability.md §8): while the command line was
parsed and the command's module imported (the default action killed the process silently), just as the command
finished (lost), a second signal inside the cleanup the first one unwinds (the cleanup cut short), ``nohup``'s
ignored SIGHUP (overridden), and ``live`` after its event loop closed (asyncio set the default action back: its rig,
still open, was killed where it stood).

Each signal is delivered at a chosen point by ``signal.raise_signal`` from a hook in the command's path — no
sleeps, no timing. In-process tests first install a recording handler of their own, so that before the fix a
signal the command let through was recorded there instead of killing pytest."""

from __future__ import annotations

import argparse
import contextlib
import gc
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from msflash.acquisition.app import cli
from msflash.acquisition.signals import Terminated, sigterm_as_exit


@pytest.fixture
def let_through() -> Iterator[list[int]]:
    """The stopping signals that got past msflash to the handlers it found (the default action, before the fix)."""
    seen: list[int] = []
    previous = {
        number: signal.signal(number, lambda n, _f: seen.append(n)) for number in (signal.SIGTERM, signal.SIGHUP)
    }
    try:
        yield seen
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def _run(monkeypatch: pytest.MonkeyPatch, handler: Callable[[argparse.Namespace], int], words: list[str]) -> int:
    """``cli.main(words)`` with ``handler`` as the command (the line parsed as usual, then the handler swapped in)."""
    parser = cli.build_parser(words)
    monkeypatch.setattr(parser, "parse_args", lambda argv: argparse.Namespace(verbose=0, handler=handler))
    monkeypatch.setattr(cli, "build_parser", lambda argv=None: parser)
    return cli.main(words)


def _until_stopped(steps: list[str]) -> None:
    """Wait for the signal delivered again to stop the caller; ``"never stopped"`` in ``steps`` if it does not come
    within 120 s (a hang guard, not a timing: it comes back within milliseconds)."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        threading.Event().wait(0.01)
    steps.append("never stopped")


def _stderr_lines(capsys: pytest.CaptureFixture[str]) -> list[str]:
    return [line for line in capsys.readouterr().err.splitlines() if line.strip()]


def test_a_sigterm_while_the_line_is_parsed_stops_the_command_in_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], let_through: list[int]
) -> None:
    """The handler was installed around the command's handler only: parsing and importing the command's module
    (numpy, OpenImageIO… seconds under load) ran under the default action."""
    ran: list[str] = []
    real = cli.build_parser

    def parsing(argv: list[str] | None = None) -> argparse.ArgumentParser:
        parser = real(argv)
        signal.raise_signal(signal.SIGTERM)  # lands while the line is being parsed
        monkeypatch.setattr(parser, "parse_args", lambda argv: argparse.Namespace(verbose=0, handler=ran.append))
        return parser

    monkeypatch.setattr(cli, "build_parser", parsing)
    assert cli.main(["estimate", "SEQ"]) == 128 + signal.SIGTERM
    assert _stderr_lines(capsys) == ["msflash: terminated (SIGTERM)"]
    assert ran == [] and let_through == []


def test_a_sigterm_as_the_command_finishes_is_said_not_lost(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], let_through: list[int]
) -> None:
    """After the command's handler returned, the default action was back: the signal killed the process silently
    (or, here, went to the handler msflash found). Now the command's outcome, then the stop line."""
    calls = []

    def closing_the_progress_bar() -> None:  # the last thing a command does
        calls.append(1)
        if len(calls) == 1:
            signal.raise_signal(signal.SIGTERM)

    monkeypatch.setattr(cli, "close_bar", closing_the_progress_bar)
    assert _run(monkeypatch, lambda args: 0, ["capture"]) == 128 + signal.SIGTERM
    lines = _stderr_lines(capsys)
    assert lines == [
        "msflash: terminated (SIGTERM); LEDs off; stopped before the sequence began: no frame was captured"
    ]
    assert let_through == []


def test_a_signal_after_the_command_returned_is_recorded_and_said() -> None:
    from msflash.acquisition.signals import command_signals

    with command_signals() as signals:
        signals.quiet()
        signal.raise_signal(signal.SIGTERM)
        signal.raise_signal(signal.SIGINT)
        for _ in range(1000):  # bytecodes: a handler due now runs here
            pass
    assert signals.raised is None and signals.late == [signal.SIGTERM, signal.SIGINT]


@pytest.mark.parametrize("second", [signal.SIGHUP, signal.SIGTERM, signal.SIGINT], ids=["SIGHUP", "SIGTERM", "SIGINT"])
def test_a_second_signal_cannot_cut_the_cleanup_the_first_one_unwinds(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], let_through: list[int], second: int
) -> None:
    """SIGTERM then the terminal closing (SIGHUP), or a service manager repeating SIGTERM: the second landed inside
    the ``finally`` switching the LEDs off and raised there, cutting it short."""
    steps: list[str] = []

    def capture(args: argparse.Namespace) -> int:
        with sigterm_as_exit():  # as run and capture hold it around their rig
            try:
                signal.raise_signal(signal.SIGTERM)
                steps.append("captured on")
            finally:
                signal.raise_signal(second)  # lands inside the cleanup
                steps.append("LEDs off")
        return 0

    assert _run(monkeypatch, capture, ["capture"]) == 128 + signal.SIGTERM
    assert steps == ["LEDs off"]
    lines = _stderr_lines(capsys)
    assert len(lines) == 1 and lines[0].startswith("msflash: terminated (SIGTERM); LEDs off")
    assert let_through == []


def test_ctrl_c_three_times_ends_a_cleanup_that_does_not_end() -> None:
    """A second signal is recorded, not raised, so that it cannot cut the cleanup short; but a cleanup waiting on a
    device that no longer answers would then never end, whatever the person pressed. Ctrl-C a third time ends the
    process at once, in one line. The command's cleanup presses Ctrl-C twice itself and then waits for ever (in a
    process of its own: the exit is immediate)."""
    script = textwrap.dedent(
        """
        import argparse, signal, threading
        from msflash.acquisition.app import cli

        def hanging_cleanup(args):
            try:
                signal.raise_signal(signal.SIGINT)
            finally:
                print("cleanup began", flush=True)
                signal.raise_signal(signal.SIGINT)
                print("second Ctrl-C recorded", flush=True)
                signal.raise_signal(signal.SIGINT)
                print("third Ctrl-C recorded", flush=True)
                threading.Event().wait()  # a device that no longer answers
            return 0

        parser = cli.build_parser(["capture"])
        parser.parse_args = lambda argv: argparse.Namespace(verbose=0, handler=hanging_cleanup)
        cli.build_parser = lambda argv=None: parser
        signal.signal(signal.SIGINT, signal.default_int_handler)  # as a terminal leaves it (a background job ignores it)
        cli.main(["capture"])
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 128 + signal.SIGINT, done.stderr[-2000:]
    assert done.stdout.splitlines() == ["cleanup began", "second Ctrl-C recorded"]
    assert done.stderr.strip().splitlines() == [
        "msflash: stopped at once (Ctrl-C 3 times): cleanup cut short; an LED left on goes off only by the booth's watchdog"
    ]


def test_a_sighup_nohup_ignores_stays_ignored(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``nohup msflash run …``, then the session closed: msflash replaced the ignored SIGHUP by its own handler and
    stopped the capture — what nohup was run to prevent."""
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:

        def capture(args: argparse.Namespace) -> int:
            with sigterm_as_exit():
                signal.raise_signal(signal.SIGHUP)  # the terminal closes
                for _ in range(1000):
                    pass
            return 0

        assert _run(monkeypatch, capture, ["capture"]) == 0
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)
    assert _stderr_lines(capsys) == []


def test_sigterm_after_lives_event_loop_closed_still_switches_the_leds_off(tmp_path: Path) -> None:
    """asyncio's loop took SIGINT, SIGTERM and SIGHUP to stop the page, and set them to the *default* action when it
    closed: a SIGTERM while ``live`` then closed its rig killed the process where it stood — LEDs on, no line.
    The signal is raised by a hook around the rig, after the loop closed and before the rig closes (in a process of
    its own: before the fix it killed that process). The page is not served: ``serve`` returns once the loop holds
    the signals."""
    script = textwrap.dedent(
        """
        import contextlib, signal, sys
        from msflash.acquisition.app import cli, cli_live
        from msflash.acquisition.app.live.server import LiveServer

        async def serve_nothing(self, stop):
            return None

        LiveServer.serve = serve_nothing
        real, closed = cli_live.open_from_args, []

        @contextlib.contextmanager
        def rig_then_sigterm(args):
            try:
                with real(args) as rig:
                    try:
                        yield rig
                    finally:
                        signal.raise_signal(signal.SIGTERM)  # the loop closed; the rig still open
            finally:
                closed.append("the rig's own exit ran")

        cli_live.open_from_args = rig_then_sigterm
        status = cli.main(["live", "--rig", "sim", "--port", "0", "--runs", sys.argv[1]])
        print("rig closed:", closed, flush=True)
        sys.exit(status)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path / "runs")], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 128 + signal.SIGTERM, done.stderr[-2000:]
    assert 'rig closed: ["the rig\'s own exit ran"]' in done.stdout
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1] == "msflash: terminated (SIGTERM); LEDs off"


def test_live_under_nohup_keeps_sighup_ignored(tmp_path: Path) -> None:
    """``nohup msflash live …``, then the session closed: asyncio's loop took SIGHUP over nohup's ignore and stopped
    the live view. The page's serve raises SIGHUP itself (the hook) and reports whether the view was told to stop;
    it must not be, and ``live`` ends as the serve returns (exit 0)."""
    script = textwrap.dedent(
        """
        import asyncio, signal, sys
        from msflash.acquisition.app import cli
        from msflash.acquisition.app.live.server import LiveServer

        async def serve_through_a_sighup(self, stop):
            signal.raise_signal(signal.SIGHUP)
            for _ in range(20):  # the loop's turns: its self-pipe read, then the handler it schedules
                await asyncio.sleep(0)
            print("stopped by SIGHUP:", stop.is_set(), flush=True)

        LiveServer.serve = serve_through_a_sighup
        signal.signal(signal.SIGHUP, signal.SIG_IGN)  # as nohup leaves it
        sys.exit(cli.main(["live", "--rig", "sim", "--port", "0", "--runs", sys.argv[1]]))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path / "runs")], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "stopped by SIGHUP: False" in done.stdout


def test_outside_the_main_thread_nothing_is_installed() -> None:
    import threading

    from msflash.acquisition.signals import command_signals

    before = signal.getsignal(signal.SIGTERM)
    seen: list[object] = []

    def other() -> None:
        with command_signals() as signals, sigterm_as_exit():
            seen.append(signals)

    thread = threading.Thread(target=other)
    thread.start()
    thread.join()
    assert len(seen) == 1 and signal.getsignal(signal.SIGTERM) is before


def test_terminated_carries_the_signals_status() -> None:
    with pytest.raises(Terminated) as raised, contextlib.ExitStack() as stack:
        stack.enter_context(sigterm_as_exit())
        signal.raise_signal(signal.SIGHUP)
    assert raised.value.code == 128 + signal.SIGHUP


def test_a_sigterm_landing_inside_a_finalizer_still_stops_the_command_in_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], let_through: list[int]
) -> None:
    """A handler that runs inside a ``__del__`` (or a weakref callback, a garbage collection) raises there; Python
    printed "Exception ignored in …" with the Terminated traceback and went on: the stop was lost (the SIGTERM
    traceback seen once under load). Now the signal is delivered again once the finalizer has returned."""

    class Frame:
        def __del__(self) -> None:
            signal.raise_signal(signal.SIGTERM)  # lands inside the finalizer

    steps: list[str] = []

    def capture(args: argparse.Namespace) -> int:
        frame = Frame()
        del frame
        steps.append("after the finalizer")
        _until_stopped(steps)
        return 0

    assert _run(monkeypatch, capture, ["capture"]) == 128 + signal.SIGTERM
    assert steps == ["after the finalizer"]
    lines = _stderr_lines(capsys)
    assert len(lines) == 1 and lines[0].startswith("msflash: terminated (SIGTERM); LEDs off"), lines
    assert let_through == []


class _ModuleThatRaisesSignal:
    """A module as colour-science leaves it in ``sys.modules``: an object whose ``__getattr__`` is Python code. CPython
    3.11's ``import`` of it asks for ``__spec__`` and clears whatever that raised; this one sends a signal there."""

    def __init__(self, number: int) -> None:
        self.number = number

    def __getattr__(self, name: str) -> object:
        if name == "__spec__":
            signal.raise_signal(self.number)  # the handler runs here, inside the C code that clears its exception
        raise AttributeError(name)


@pytest.mark.parametrize("number", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_that_c_code_clears_is_delivered_again(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], let_through: list[int], number: int
) -> None:
    """The Ctrl-C sent as ``msflash run`` opened the rig landed in ``import colour`` (colour-science's module object
    has a Python ``__getattr__``; CPython 3.11's import clears what its ``__spec__`` lookup raised): the run went on to
    its end, exit 0, about one run in ten (tests/acquisition/app/test_cli_manners.py). The stop dropped unreceived is
    delivered again and stops the command."""
    monkeypatch.setitem(sys.modules, "msflash_test_module_object", _ModuleThatRaisesSignal(number))
    steps: list[str] = []

    def capture(args: argparse.Namespace) -> int:
        import msflash_test_module_object  # noqa: F401  # type: ignore[import-not-found]

        steps.append("after the import")
        _until_stopped(steps)
        return 0

    expected = 130 if number == signal.SIGINT else 128 + number
    assert _run(monkeypatch, capture, ["capture"]) == expected
    assert steps == ["after the import"]  # the import itself cleared the first delivery: C code, not ours
    lines = _stderr_lines(capsys)
    assert len(lines) == 1 and "LEDs off" in lines[0], lines
    assert let_through == []


def test_a_stop_caught_and_acted_on_is_not_delivered_again() -> None:
    """Whoever ends a command on a stop says it :func:`received` it: dropping it then delivers nothing more."""
    from msflash.acquisition.signals import command_signals, received

    with command_signals() as stop:
        with pytest.raises(KeyboardInterrupt) as raised:
            signal.raise_signal(signal.SIGINT)
        received(raised.value)
        del raised
        gc.collect()
        assert stop.raised == signal.SIGINT and stop.raising is False
    assert stop.late == []


def test_ctrl_c_forces_the_exit_at_the_third_press_whether_or_not_the_first_was_raised(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """After the command finished (:meth:`_Stop.quiet`) no press is raised, and the presses were counted from the
    recorded ones alone: the second Ctrl-C ended the process, its outcome not yet said. The third does, as during the
    command."""
    from msflash.acquisition import signals

    forced: list[int] = []
    monkeypatch.setattr(signals, "_forced_exit", lambda: forced.append(len(stop.late)))
    stop = signals._Stop()
    stop.quiet()
    for _ in range(3):
        stop(signal.SIGINT, None)
    assert stop.late == [signal.SIGINT] * 3 and forced == [3]


@pytest.mark.parametrize("kept", [False, True], ids=["dropped", "kept-in-a-cycle"])
def test_a_ctrl_c_whose_cleanup_failed_is_said_after_the_error(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], kept: bool
) -> None:
    """Ctrl-C, then the cleanup it unwinds fails (the booth stops answering): the error is reported (one line), then
    the stop that error carries as its context — whether nothing else holds it or a frame that stored it does, as the
    capture engine's ``error = err`` (a reference cycle only a collection frees) — never dropped, never Python's own
    KeyboardInterrupt traceback."""
    from msflash.acquisition.errors import BoothError

    def capture(args: argparse.Namespace) -> int:
        try:
            try:
                signal.raise_signal(signal.SIGINT)
            except BaseException as err:
                if kept:
                    error = err  # noqa: F841  # the frame keeps the stop, whose traceback keeps the frame
                raise
        finally:
            raise BoothError("booth on /dev/ttyACM0 stopped answering while the LEDs were switched off")
        return 0

    assert _run(monkeypatch, capture, ["capture"]) == 130
    lines = _stderr_lines(capsys)
    assert lines[0] == "msflash: error: booth on /dev/ttyACM0 stopped answering while the LEDs were switched off"
    assert len(lines) == 2 and lines[1].startswith("msflash: interrupted"), lines


def test_a_terminated_caught_in_an_api_block_is_delivered_again_unless_received() -> None:
    """Inside ``sigterm_as_exit`` (the Python API's capture blocks), code that catches the stop and drops it has not
    stopped: the signal comes back. Said :func:`received`, it does not (the handler has nothing in flight)."""
    from msflash.acquisition.signals import _Stop, received

    with sigterm_as_exit():
        handler = signal.getsignal(signal.SIGTERM)
        assert isinstance(handler, _Stop)
        try:
            signal.raise_signal(signal.SIGTERM)
        except Terminated as stop:
            received(stop)
        assert not handler.in_flight and handler.raised == signal.SIGTERM

    steps: list[str] = []
    with pytest.raises(Terminated), sigterm_as_exit():
        try:
            signal.raise_signal(signal.SIGTERM)
        except Terminated:
            steps.append("dropped")
        _until_stopped(steps)
    assert steps == ["dropped"]

    with pytest.raises(Terminated) as raised, sigterm_as_exit():  # dropped as the block ends: raised as it leaves
        try:
            signal.raise_signal(signal.SIGTERM)
        except Terminated:
            pass
    assert raised.value.code == 128 + signal.SIGTERM


def test_a_stop_delivered_again_too_late_is_said_not_sent_after_the_handlers_are_gone() -> None:
    """The thread that delivers a lost stop again is held back (a starved machine) past the end of the command: the
    stop is recorded and said by the command (exit 143), not sent once Python's own handlers are back — SIGTERM's
    default action would then kill the process after it had returned its status."""
    script = textwrap.dedent(
        """
        import _thread, argparse, signal, sys, threading, time
        from msflash.acquisition import signals
        from msflash.acquisition.app import cli

        def held_back(function, arguments):  # the delivering thread starts 2.5 s late (beyond settle's bound)
            threading.Timer(2.5, function, arguments).start()
        signals._thread = type("Late", (), {"start_new_thread": staticmethod(held_back),
                                            "allocate_lock": staticmethod(_thread.allocate_lock)})

        class ModuleObject:  # as colour-science's: CPython 3.11's import clears what __getattr__('__spec__') raised
            def __getattr__(self, name):
                if name == "__spec__":
                    signal.raise_signal(signal.SIGTERM)
                raise AttributeError(name)
        sys.modules["module_object"] = ModuleObject()

        def capture(args):
            import module_object  # noqa
            return 0

        parser = cli.build_parser(["capture"])
        parser.parse_args = lambda argv: argparse.Namespace(verbose=0, handler=capture)
        cli.build_parser = lambda argv=None: parser
        status = cli.main(["capture"])
        print("main returned", status, flush=True)
        time.sleep(3)  # the held-back thread runs meanwhile
        print("survived", flush=True)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=Path(__file__).parents[3]
    )
    assert done.stdout.splitlines() == ["main returned 143", "survived"], (done.stdout, done.stderr)
    assert done.stderr.startswith("msflash: terminated (SIGTERM)"), done.stderr


def test_ctrl_c_pressed_while_signals_are_held_counts_towards_the_forced_exit(monkeypatch: pytest.MonkeyPatch) -> None:
    """A block that holds the signals (a dask cluster's start) and never returns could not be ended: the presses it
    held were not counted. Now the third press ends the process; a held press delivered afterwards is not counted
    twice."""
    from msflash.acquisition import signals

    forced: list[int] = []
    with signals.command_signals() as stop:
        monkeypatch.setattr(signals, "_forced_exit", lambda: forced.append(stop.presses))
        held: list[int] = []
        with signals.signals_deferred(held):
            signal.raise_signal(signal.SIGINT)
        with pytest.raises(KeyboardInterrupt) as raised:
            signals.deliver_deferred(held)
        signals.received(raised.value)
        assert stop.presses == 1 and forced == []
        with signals.signals_deferred(held):  # the cleanup's close of the cluster hangs; the person insists
            signal.raise_signal(signal.SIGINT)
            assert forced == []
            signal.raise_signal(signal.SIGINT)
        assert forced == [3]
