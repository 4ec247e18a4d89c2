"""What the hostile user's pass (docs/reliability.md §8) found but left: option values that begin with '-', numbers
that Python's ``float``/``int`` read but a user did not mean, and ports that do not exist. Each test failed before
its fix; real files, ``main()`` in-process, no mocks."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from tests.helpers import write_test_sequence


@pytest.fixture(scope="module")
def base_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_test_sequence(tmp_path_factory.mktemp("leftovers") / "seq")


@pytest.fixture
def sequence(base_sequence: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "seq"
    shutil.copytree(base_sequence, copy)
    return copy


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
    assert spaced.read_bytes() == joined.read_bytes()


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
