"""Hostile calibration files: every reader exits 2 with one line naming the file and the field (issue 19).

Before, a 5000-digit integer, deep nesting or ``"names": 5`` escaped the reader as a ValueError,
RecursionError or TypeError (exit 1, "a bug"), and NaN, Infinity and ``1e999`` were read as
numbers (a NaN black level reached ``calibrate linearity``; the next save wrote it as null).
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app import cli

SEQUENCE = Path(__file__).resolve().parents[1] / "data" / "sequences" / "sim-macbeth-fluorescent"
BASE = {"format": "msflash-calibration", "version": 1, "id": "cal-x", "dark": {"black_level": [64.0, 64.0, 64.0]}}


def _with(text: str, insert: str) -> str:
    return text.replace('"version": 1', f'"version": 1, {insert}', 1)


HOSTILE = {
    "truncated": (
        '{"format": "msflash-calibration", "version": 1, "id": "c',
        "calibration.json: line 1 column 55: Unterminated string",
    ),
    "NaN": (
        json.dumps({**BASE, "dark": {"black_level": [float("nan"), 1, 2]}}),
        "field 'dark.black_level[0]' is NaN; expected a finite number",
    ),
    "Infinity": (
        json.dumps({**BASE, "linearity": {"saturation_level": float("inf")}}),
        "field 'linearity.saturation_level' is Infinity; expected a finite number",
    ),
    "overflowing float": (
        _with(json.dumps(BASE), '"site": {"height": -1e999}'),
        "field 'site.height' is -1e999; expected a finite number",
    ),
    "huge integer": (
        _with(json.dumps(BASE), '"n": ' + "9" * 5000),
        "field 'n' is an integer of 5000 digits; expected a finite number",
    ),
    "huge version": (
        json.dumps(BASE).replace('"version": 1', '"version": ' + "9" * 400),
        "field 'version' is an integer of 400 digits",
    ),
    "deep nesting": (
        _with(json.dumps(BASE), '"x": ' + "[" * 150 + "]" * 150),
        "field 'x" + "[0]" * 99 + "' is nested 101 levels deep; expected at most 100",
    ),
    "nesting past the parser": (
        _with(json.dumps(BASE), '"x": ' + "[" * 100_000 + "]" * 100_000),
        "nested too deep to read; expected at most 100 levels",
    ),
    "names a number": (
        json.dumps({**BASE, "leds": {"file": "leds.csv", "unit": "energy", "names": 5}}),
        "field 'leds.names' is 5; expected the columns of leds.csv",
    ),
    "black level of booleans": (
        json.dumps({**BASE, "dark": {"black_level": [True, "a"]}}),
        "field 'dark.black_level' is [True, 'a']; expected a list of numbers",
    ),
    "black level of 40 numbers": (
        json.dumps({**BASE, "dark": {"black_level": [1.0] * 40}}),
        "field 'dark.black_level' has 40 values; expected 1–4",
    ),
    "negative read noise": (
        json.dumps({**BASE, "dark": {"black_level": [1.0], "read_noise_dn": [-2.0]}}),
        "field 'dark.read_noise_dn' holds -2.0; expected numbers ≥ 0",
    ),
    "created_utc a number": (json.dumps({**BASE, "created_utc": 5}), "field 'created_utc' is 5; expected an ISO 8601"),
    "linearity a string": (
        json.dumps({**BASE, "linearity": {"saturation_level": "high"}}),
        "field 'linearity.saturation_level' is 'high'; expected a number or null",
    ),
    "duplicate key": (
        '{"format": "msflash-calibration", "format": "x", "version": 1, "id": "a"}',
        "key 'format' appears twice in one object",
    ),
    "a list": ("[1, 2]", "top level is a list; expected an object"),
}
LEDS = "wavelength_nm,led440\n400,1\n410,2\n420,1\n"


def run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli.main(argv)
    return status, out.getvalue(), err.getvalue()


@pytest.mark.parametrize("reader", ["estimate --calibration", "calibrate --out"])
@pytest.mark.parametrize("case", list(HOSTILE))
def test_a_hostile_calibration_file_exits_2_naming_file_and_field(tmp_path: Path, case: str, reader: str) -> None:
    text, needle = HOSTILE[case]
    cal = tmp_path / "cal"
    cal.mkdir()
    (cal / "calibration.json").write_text(text)
    (cal / "leds.csv").write_text(LEDS)
    export = tmp_path / "led.txt"
    export.write_text("400\t0.1\n410\t1\n420\t0.1\n")
    argv = (
        ["estimate", str(SEQUENCE), "--calibration", str(cal)]
        if reader.startswith("estimate")
        else ["calibrate", "leds", str(export), "--out", str(cal)]
    )
    status, out, err = run(argv)
    assert (status, out) == (2, ""), err
    assert err.count("\n") == 1 and err.startswith(f"msflash: error: {cal / 'calibration.json'}")
    assert needle in err
    assert (cal / "calibration.json").read_text() == text  # the update refused before anything was written


@pytest.mark.parametrize(
    "cell,needle",
    [
        ("1e999", "holds '1e999'; expected a finite number"),
        ("9" * 5000, "holds '9999999999999999999999999999999999999... (5000 characters)'; expected a finite number"),
        ("nan", "is missing (NaN); expected a number (write 0 where the value is zero)"),
        ("-0.5", "column 'led440' at 410 nm is -0.5; expected a non-negative value"),
    ],
)
def test_a_hostile_table_exits_2_naming_table_line_and_column(tmp_path: Path, cell: str, needle: str) -> None:
    cal = tmp_path / "cal"
    cal.mkdir()
    (cal / "calibration.json").write_text(
        json.dumps(
            {"format": "msflash-calibration", "version": 1, "id": "c", "leds": {"file": "leds.csv", "unit": "energy"}}
        )
    )
    (cal / "leds.csv").write_text(LEDS.replace("410,2", f"410,{cell}").replace("420,1", "420,4"))
    status, out, err = run(["flash", str(SEQUENCE), "--mode", "matching", "--calibration", str(cal)])
    assert (status, out) == (2, "") and err.count("\n") == 1
    assert "leds.csv" in err and needle in err


CAMERA = "wavelength_nm,R,G,B\n" + "".join(
    f"{w},{0.2 + w / 1000},{0.5},{0.9 - w / 1000}\n" for w in range(400, 701, 10)
)


def _camera_calibration(cal: Path) -> None:
    """A calibration folder's ``calibration.json`` naming only a camera table, ``camera.csv``."""
    (cal / "calibration.json").write_text(
        json.dumps(
            {
                "format": "msflash-calibration",
                "version": 1,
                "id": "c",
                "camera": {"file": "camera.csv", "unit": "energy"},
            }
        )
    )


@pytest.mark.parametrize("command", ["estimate", "flash", "export"])
def test_a_camera_channel_with_no_positive_value_exits_2_naming_table_and_column(tmp_path: Path, command: str) -> None:
    # Was: estimate, flash and export exit 1 "ambient estimate: the LED-only image of led0, …, led6 is
    # empty; expected every LED to add light (is it connected…?)" for a hand-zeroed camera.csv column.
    cal = tmp_path / "cal"
    cal.mkdir()
    _camera_calibration(cal)
    (cal / "camera.csv").write_text(CAMERA.replace(",0.5,", ",0,"))
    extra = {"estimate": [], "flash": ["--mode", "matching"], "export": ["--to", "csv", "--out", str(tmp_path / "x")]}
    status, out, err = run([command, str(SEQUENCE), "--calibration", str(cal), *extra[command]])
    assert (status, out) == (2, "") and err.count("\n") == 1, err
    assert err.startswith(f"msflash: error: {cal / 'camera.csv'}: column 'G' has no positive value on 400–700 nm")
    assert not (tmp_path / "x").exists()


def test_a_table_that_is_a_directory_is_named_as_one(tmp_path: Path) -> None:
    # Was: "…/camera.csv is missing; expected the CSV table beside it" for a directory of that name.
    cal = tmp_path / "cal"
    (cal / "camera.csv").mkdir(parents=True)
    _camera_calibration(cal)
    status, out, err = run(["estimate", str(SEQUENCE), "--calibration", str(cal)])
    assert (status, out) == (2, "") and err.count("\n") == 1, err
    assert f"{cal / 'camera.csv'}: is a directory; expected a spectral table" in err


def test_a_blind_column_is_never_written(tmp_path: Path) -> None:
    from msflash.calibration.errors import CalibrationError
    from msflash.calibration.files import CalibrationSet, save_calibration
    from msflash.processing.spectra import Spectra

    grid = np.arange(400.0, 701.0, 10.0)
    values = np.column_stack([np.ones_like(grid), np.zeros_like(grid), np.ones_like(grid)])
    camera = Spectra.from_samples(grid, values, ("R", "G", "B"), kind="responsivity", unit="energy")
    with pytest.raises(CalibrationError, match="column 'G' has no positive value on 400–700 nm .*\\(not written\\)"):
        save_calibration(CalibrationSet(camera_responsivities=camera), tmp_path / "cal")
    assert not (tmp_path / "cal" / "calibration.json").exists()
