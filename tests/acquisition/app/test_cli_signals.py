"""Ctrl-C and SIGTERM end msflash with one line (the LEDs are switched off by the ``with`` blocks they unwind)."""

from __future__ import annotations

import argparse
import os
import select
import signal
import socket
import threading

import pytest

from msflash.acquisition.app import cli
from msflash.acquisition.signals import Terminated, hold_stopping_signals, sigterm_as_exit


def test_a_real_sigterm_inside_the_guard_unwinds_as_terminated() -> None:
    with pytest.raises(Terminated) as raised, sigterm_as_exit():
        os.kill(os.getpid(), signal.SIGTERM)
    assert raised.value.code == 128 + signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) is not None  # the previous handler is back


def test_a_held_signal_waits_for_the_release_even_when_another_thread_receives_it() -> None:
    """A process-directed SIGTERM may land on any thread that does not block it (OpenBLAS's, OpenImageIO's…);
    Python then runs its handler in the main thread at once. Holding it by the main thread's signal mask alone let
    it through, between an export's staging folder being made and its cleanup taking charge (a flake that left
    ``.NAME.*.export-tmp`` behind)."""
    go = threading.Event()
    other = threading.Thread(target=go.wait)  # made before the hold, as libraries' threads are
    other.start()
    steps: list[str] = []
    arrived, wakeup = socket.socketpair()  # Python's C handler writes each signal's number here as it lands
    wakeup.setblocking(False)
    previous_wakeup = signal.set_wakeup_fd(wakeup.fileno())
    try:
        with pytest.raises(Terminated), sigterm_as_exit():
            release = hold_stopping_signals()
            try:
                assert other.ident is not None
                signal.pthread_kill(other.ident, signal.SIGTERM)  # delivered to that thread, not to the main one
                assert select.select([arrived], [], [], 120)[0], "the signal never arrived"  # a hang guard
                for _ in range(10_000):  # bytecodes in the main thread: a handler due now runs here
                    pass
                steps.append("held until the release")
            finally:
                release()  # the held signal is raised here
    finally:
        signal.set_wakeup_fd(previous_wakeup)
        arrived.close()
        wakeup.close()
        go.set()
        other.join()
    assert steps == ["held until the release"]


@pytest.mark.parametrize(
    ("raised", "status", "line"),
    [
        (
            Terminated(143),
            143,
            "msflash: terminated (SIGTERM); LEDs off; stopped before the sequence began: no frame was captured",
        ),
        (
            KeyboardInterrupt(),
            130,
            "msflash: interrupted; LEDs off; stopped before the sequence began: no frame was captured",
        ),
    ],
)
def test_the_cli_says_how_it_was_stopped(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, raised: BaseException, status: int, line: str
) -> None:
    def stopped(args) -> int:  # what a capture's handler does when the signal lands
        raise raised

    parser = cli.build_parser()
    monkeypatch.setattr(parser, "parse_args", lambda argv: argparse.Namespace(verbose=0, handler=stopped))
    monkeypatch.setattr(cli, "build_parser", lambda argv=None: parser)
    assert cli.main(["capture"]) == status
    assert capsys.readouterr().err.strip().splitlines()[-1] == line


@pytest.mark.parametrize("finished", [False, True])
def test_the_stop_line_says_whether_the_sequence_was_complete(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, tmp_path, finished: bool
) -> None:
    """Ctrl-C after a sequence finished (say, while the report is drawn) does not claim it was marked
    incomplete: the line says what the file says, and names the folder."""
    import numpy as np

    from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed
    from msflash.acquisition.sequence.reader import read_sequence
    from msflash.acquisition.sequence.writer import SequenceWriter

    def stopped(args) -> int:
        camera = SequenceCamera(
            model="t", serial=None, pixel_format="RGB16", cfa=None, black_level=0, white_level=65535
        )
        writer = SequenceWriter(
            tmp_path / "seq",
            wavelengths_nm=np.array([500.0, 600.0]),
            spectral_unit="energy",
            camera=camera,
            leds=[SequenceLed("a", np.array([1.0, 0.0]))],
        )
        writer.add_frame(np.ones((4, 4, 3), dtype=np.uint16), "ambient", [0.0], exposure_us=10.0)
        if finished:
            writer.finish()
        raise KeyboardInterrupt

    parser = cli.build_parser()
    monkeypatch.setattr(parser, "parse_args", lambda argv: argparse.Namespace(verbose=0, handler=stopped))
    monkeypatch.setattr(cli, "build_parser", lambda argv=None: parser)
    assert cli.main(["run"]) == 130
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert read_sequence(tmp_path / "seq").complete is finished
    if finished:
        assert (
            line
            == f"msflash: interrupted; LEDs off; the sequence in {tmp_path / 'seq'} was complete before the stop and stays so"
        )
    else:
        assert (
            line
            == f"msflash: interrupted; LEDs off; frames captured so far are kept (marked incomplete) in {tmp_path / 'seq'}"
        )
