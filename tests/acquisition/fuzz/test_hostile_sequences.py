"""Sequences written by other tools, edited by hand: refused in one line naming the field, on every command.

Found by a hostile pass over the shared samples (docs/reliability.md §4); each case was a wrong exit
(1, blaming something else) or a wrong field before its fix.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from tests.helpers import SAMPLES_DIR

BAYER_12BIT = SAMPLES_DIR / "sample-bayer-fluorescent-12bit"


def _edited(tmp_path: Path, change) -> Path:
    """A writable copy of the 12-bit Bayer sample whose ``sequence.json`` went through ``change``."""
    if not (BAYER_12BIT / "sequence.json").exists():
        pytest.skip(f"sample sequence {BAYER_12BIT} is absent (shared samples not mounted)")
    copy = tmp_path / "sample"
    shutil.copytree(BAYER_12BIT, copy)
    for path in [copy, *copy.rglob("*")]:
        path.chmod(0o755 if path.is_dir() else 0o644)
    document = json.loads((copy / "sequence.json").read_text())
    change(document)
    (copy / "sequence.json").write_text(json.dumps(document))
    return copy


def _refused(capsys: pytest.CaptureFixture, argv: list[str]) -> str:
    status = main(argv)
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2, lines
    errors = [line for line in lines if line.startswith("msflash: error: ")]
    assert len(errors) == 1 and errors[0] == lines[-1], lines
    return errors[0]


COMMANDS = [
    ["estimate", "{seq}", "--json"],
    ["flash", "{seq}", "--mode", "complementary", "--json"],
    ["synthesize", "{seq}", "--weights", "0.1,0,0,0,0,0,0", "--out", "{tmp}/s.exr"],
    ["export", "{seq}", "--to", "dng,csv", "--out", "{tmp}/export"],
    ["check", "{seq}"],
]


@pytest.mark.parametrize("command", COMMANDS, ids=lambda argv: argv[0])
def test_a_responsivity_channel_with_no_positive_value_is_refused_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture, command: list[str]
) -> None:
    # Was: estimate, flash and export exit 1 "the LED-only image of ch0, …, ch6 is empty; expected every
    # LED to add light (is it connected…?)", blaming the booth for a hand-zeroed responsivity.
    sequence = _edited(tmp_path, lambda d: d["camera"]["responsivity"].__setitem__("G", [0.0] * 31))
    argv = [word.format(seq=sequence, tmp=tmp_path) for word in command]
    line = _refused(capsys, argv)
    assert f"{sequence / 'sequence.json'}: camera.responsivity.G has no positive value on 400–700 nm" in line
    assert not (tmp_path / "export").exists() and not (tmp_path / "s.exr").exists()
