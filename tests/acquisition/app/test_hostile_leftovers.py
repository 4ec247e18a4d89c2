"""What the hostile user's pass (docs/reliability.md §8) found but left: option values that begin with '-', numbers
that Python's ``float``/``int`` read but a user did not mean, and ports that do not exist. Each test failed before
its fix; real files, ``main()`` in-process, no mocks."""

from __future__ import annotations

import io
import os
import tty
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.image_files import read_image


def _one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("msflash: error: "), err
    return lines[0]


def test_weights_that_begin_with_a_minus_are_read_as_with_an_equals_sign(
    sequence: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--weights -5,0,…`` was argparse's "expected one argument" while ``--weights=-5,0,…`` was read."""
    weights = "-0.5,1,0,0,0,0,0"
    spaced, joined = tmp_path / "spaced.exr", tmp_path / "joined.exr"
    assert main(["synthesize", str(sequence), "--weights", weights, "--out", str(spaced)]) == 0
    assert main(["synthesize", str(sequence), f"--weights={weights}", "--out", str(joined)]) == 0
    np.testing.assert_array_equal(read_image(spaced), read_image(joined))  # the pixels: the files' dates may differ


@pytest.mark.parametrize(
    ("words", "named"),
    [
        (["run", "--seed", "-1e3"], "argument --seed: '-1e3': expected a whole number ≥ 0"),
        (["run", "--flash-power", "-inf"], "argument --flash-power: '-inf': expected a positive number"),
        (["run", "--flash-power", "-.5"], "argument --flash-power: '-.5': expected a positive number"),
        (["estimate", "SEQ", "--alpha", "-1e-3"], "--alpha"),
    ],
)
def test_a_negative_value_is_refused_saying_what_the_option_expects(
    words: list[str], named: str, sequence: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each was "expected one argument" (``-1e3``, ``-inf`` do not match argparse's negative-number pattern)."""
    words = [str(sequence) if word == "SEQ" else word for word in words]
    assert main([*words, "--out", str(tmp_path / "out")] if words[0] == "run" else words) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert named in line and "expected one argument" not in line


def test_a_file_named_like_an_option_is_told_how_to_be_written(
    sequence: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["synthesize", str(sequence), "--weights", "1,0,0,0,0,0,0", "--out", "-x.exr"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "argument --out: expected one argument; a value that begins with '-' is written --out=VALUE" in line


def test_no_option_looks_like_a_negative_value() -> None:
    """The parser reads ``-5…``, ``-inf`` and ``-nan`` as values: no option may be spelt so (argparse would then
    take every such word for an option)."""
    from msflash.acquisition.app.cli import NEGATIVE_VALUE, build_parser

    parser = build_parser()
    parsers = [parser]
    names: list[str] = []
    while parsers:
        current = parsers.pop()
        for action in current._actions:
            names += action.option_strings
            for sub in (action.choices or {}).values() if isinstance(action.choices, dict) else ():
                parsers.append(sub)
    assert len(names) > 100
    assert [name for name in names if NEGATIVE_VALUE.match(name)] == []


PORT_COMMANDS = [
    ["booth", "console", "{port}"],
    ["doctor", "--port", "{port}"],
    ["capture", "--rig", "sim", "--booth-port", "{port}", "--out", "{out}"],
    ["run", "--rig", "sim", "--booth-port", "{port}", "--out", "{out}"],
    ["run", "--rig", "hw", "--port", "{port}", "--out", "{out}"],
    ["live", "--booth-port", "{port}", "--runs", "{out}"],
]


@pytest.mark.parametrize("command", PORT_COMMANDS, ids=lambda words: " ".join(words[:2]))
@pytest.mark.parametrize(
    ("port", "said"),
    [
        ("{tmp}/ttyNONE", "no such port; expected an existing serial device"),
        ("{tmp}/file/ttyACM0", "no such port"),
        ("{tmp}/file", "a regular file; expected a serial device"),
        ("{tmp}", "a folder; expected a serial device"),
    ],
    ids=["missing", "under-a-file", "a-file", "a-folder"],
)
def test_every_command_refuses_a_port_that_is_no_device_as_bad_input(
    command: list[str], port: str, said: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``booth console /dev/nonexistent`` and ``run --booth-port /dev/nonexistent`` exited 1 (a device failure, the
    sim rig opened first) while ``doctor --port /dev/nonexistent`` exited 2."""
    (tmp_path / "file").write_text("not a port\n")
    port = port.replace("{tmp}", str(tmp_path))
    out = tmp_path / "out"
    words = [word.replace("{port}", port).replace("{out}", str(out)) for word in command]
    assert main(words) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"'{port}': {said}" in line
    assert not out.exists()


@pytest.fixture
def silent_port() -> Iterator[str]:
    """A pseudo-terminal nobody answers on: a device that exists and stays silent."""
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        yield os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize(
    "command",
    [
        ["booth", "console", "{port}", "--timeout-s", "0.2", "--booth-boot-s", "0"],
        ["doctor", "--port", "{port}", "--timeout-s", "0.2", "--booth-boot-s", "0"],
    ],
    ids=["booth console", "doctor"],
)
def test_a_port_that_exists_but_does_not_answer_is_a_device_failure(
    command: list[str], silent_port: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``doctor --port`` of a silent device exited 2 (bad input) where ``booth console`` exited 1."""
    monkeypatch.setattr("sys.stdin", io.StringIO("quit\n"))
    assert main([word.replace("{port}", silent_port) for word in command]) == 1
    line = _one_error_line(capsys.readouterr().err)
    assert silent_port in line and ("no reply" in line or "nothing answered" in line)
