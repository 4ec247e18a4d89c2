"""The command line's last line of defence (issue 19): hostile input exits 2 with one line naming
the file and the field; an unexpected exception exits 1 with one line naming the command and a
crash log holding the traceback; numpy's warnings come with an explanation."""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import CRASH_LOG_ENV, main
from msflash.acquisition.session import one_sequence


def _huge_integer(seq: Path) -> str:
    text = (seq / "sequence.json").read_text()
    # A literal 5000-digit integer in a numeric field (json.dumps cannot write one: Python refuses to convert it).
    return text.replace('"exposure_us": ', '"exposure_us": ' + "9" * 5000 + ', "was": ', 1)


def _nested_100k(seq: Path) -> str:
    return "[" * 100_000 + "]" * 100_000


def _unknown_key_900_deep(seq: Path) -> str:
    document = json.loads((seq / "sequence.json").read_text())
    value: object = 1
    for _ in range(900):
        value = {"k": value}
    document["x_vendor"] = value
    return json.dumps(document)


def _non_utf8_frame_name(seq: Path) -> str:
    document = json.loads((seq / "sequence.json").read_text())
    old = seq / document["frames"][1]["file"]
    new_name = b"\xff\xfe-led.tiff"
    os.rename(old, os.fsencode(seq / "frames") + b"/" + new_name)
    document["frames"][1]["file"] = "frames/" + os.fsdecode(new_name)  # a surrogate-escaped name
    return json.dumps(document)


def _symlink_loop_frame(seq: Path) -> str:
    document = json.loads((seq / "sequence.json").read_text())
    frame = seq / document["frames"][1]["file"]
    frame.unlink()
    frame.symlink_to(frame.name)
    return json.dumps(document)


def _too_big_for_a_float(seq: Path) -> str:
    text = (seq / "sequence.json").read_text()
    return text.replace('"gain": ', '"gain": ' + "9" * 400 + ', "was": ', 1)


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (_huge_integer, "field 'frames[0].exposure_us' is an integer of 5000 digits"),
        (_nested_100k, "nested too deep"),
        (_unknown_key_900_deep, "x_vendor.k.k"),
        (_non_utf8_frame_name, "frames[1].file"),
        (_symlink_loop_frame, "frames[1].file"),
        (_too_big_for_a_float, "frames[0].gain is an integer of 400 digits"),
    ],
    ids=[
        "5000-digit-integer",
        "nested-100k",
        "unknown-key-900-deep",
        "non-utf8-frame-name",
        "symlink-loop",
        "400-digit-integer",
    ],
)
def test_hostile_sequence_exits_2_with_one_line(
    sequence: Path, make: Callable[[Path], str], field: str, capsys: pytest.CaptureFixture[str]
) -> None:
    (sequence / "sequence.json").write_text(make(sequence))
    assert main(["estimate", str(sequence)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("msflash: error: "), err[:2000]
    assert f"{sequence / 'sequence.json'}:" in err and field in err and "expected" in err


@pytest.mark.parametrize("value", ["inf", "nan", "-1"])
def test_booth_emulator_refuses_a_non_finite_watchdog(value: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["booth-emulator", "--watchdog-s", value]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--watchdog-s" in err


def test_unexpected_exception_exits_1_with_one_line_and_a_crash_log(
    sequence: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def broken(directory: object) -> None:
        raise ZeroDivisionError("a bug deep inside")

    monkeypatch.setattr(one_sequence, "read_sequence", broken)
    monkeypatch.setenv(CRASH_LOG_ENV, str(tmp_path / "crashes"))
    assert main(["estimate", str(sequence)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err.startswith("msflash: estimate: unexpected ZeroDivisionError: a bug deep inside")
    logs = list((tmp_path / "crashes").iterdir())
    assert len(logs) == 1 and str(logs[0]) in err
    log = logs[0].read_text()
    assert "Traceback (most recent call last)" in log and "in broken" in log and "ZeroDivisionError" in log
    assert "estimate" in log


def test_crash_log_falls_back_when_its_directory_cannot_be_made(
    sequence: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setattr(one_sequence, "read_sequence", lambda directory: {}[directory])
    monkeypatch.setenv(CRASH_LOG_ENV, str(blocker / "crashes"))
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    assert main(["estimate", str(sequence)]) == 1
    err = capsys.readouterr().err
    assert "unexpected KeyError" in err
    logs = list(tmp_path.glob("crash-*.log"))
    assert len(logs) == 1 and str(logs[0]) in err


def test_numpy_warnings_are_explained_in_one_line(
    sequence: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    real = one_sequence.read_sequence

    def warns(directory: object) -> object:
        np.log(np.zeros(1))  # RuntimeWarning: divide by zero encountered in log
        return real(directory)

    monkeypatch.setattr(one_sequence, "read_sequence", warns)
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        assert main(["estimate", str(sequence), "--json"]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "divide by zero" in line]
    assert len(lines) == 1 and lines[0].startswith("msflash: warning: ") and "NaN" in lines[0]
    assert "np.log" not in err  # no source line


def test_a_capture_interrupted_before_its_first_frame_says_what_is_missing(
    sequence: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``complete: false`` with no frame at all: the estimate's one error names the missing frame, not the
    estimate's inner workings (it said the stream 'was made without tiles')."""
    document = json.loads((sequence / "sequence.json").read_text())
    document.update(complete=False, frames=[])
    (sequence / "sequence.json").write_text(json.dumps(document))
    assert main(["estimate", str(sequence)]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith(f"msflash: error: {sequence / 'sequence.json'}: ") and "expected" in last, last
    assert "ambient" in last and "tiles" not in last, last
