"""Ctrl-C and SIGTERM end msflash with one line (the LEDs are switched off by the ``with`` blocks they unwind)."""

from __future__ import annotations

import argparse
import os
import signal

import pytest

from msflash.acquisition.app import cli
from msflash.led_controller.booth import Terminated, sigterm_as_exit


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
            "msflash: terminated (SIGTERM); LEDs off; frames captured so far are kept (marked incomplete)",
        ),
        (
            KeyboardInterrupt(),
            130,
            "msflash: interrupted; LEDs off; frames captured so far are kept (marked incomplete)",
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
