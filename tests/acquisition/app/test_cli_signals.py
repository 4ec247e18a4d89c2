"""Ctrl-C and SIGTERM end msflash with one line (the LEDs are switched off by the ``with`` blocks they unwind)."""

from __future__ import annotations

import argparse
import os
import signal

import pytest

from msflash.acquisition.app import cli
from msflash.acquisition.signals import Terminated, sigterm_as_exit


def test_a_real_sigterm_inside_the_guard_unwinds_as_terminated() -> None:
    with pytest.raises(Terminated) as raised, sigterm_as_exit():
        os.kill(os.getpid(), signal.SIGTERM)
    assert raised.value.code == 128 + signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) is not None  # the previous handler is back


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
