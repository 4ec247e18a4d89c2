"""A user's number is plain decimal or scientific ASCII (processing/user_numbers.py), read by one parser for every
option and every user file: Python's ``float``/``int`` read ``1_0`` as 10, ``١٢`` as 12 and ``infinity``/``nan``
as numbers, so ``--weights=1_0,…`` weighted an LED ten times. Real files, ``main()`` in-process, no mocks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import build_parser, main
from msflash.acquisition.sequence.image_files import read_image
from msflash.processing.user_numbers import NotANumber, plain_number, plain_whole_number

HOSTILE = ["1_0", "١٢", "１２", "infinity", "nan", "0x10", "1,5"]
"""What ``float`` or ``int`` read (or a user may type) that is no plain number: underscores, Arabic-Indic and
full-width digits, infinity, NaN, hexadecimal, a decimal comma."""


@pytest.mark.parametrize("text", [*HOSTILE, "", " ", "1e400", "--1", "1.2.3", "٣.٥", "1 0"])
def test_what_is_no_plain_number_is_refused_quoting_it(text: str) -> None:
    with pytest.raises(NotANumber, match="expected a"):
        plain_number(text)


@pytest.mark.parametrize(
    ("text", "value"), [("1.5", 1.5), (" -2 ", -2.0), ("3e-4", 3e-4), (".5", 0.5), ("1.", 1.0), ("+1E+002", 100.0)]
)
def test_plain_numbers_are_read_blanks_around_them_dropped(text: str, value: float) -> None:
    assert plain_number(text) == value


@pytest.mark.parametrize("text", ["1_000", "١٢", "1.0", "1e3", "0b11", "+"])
def test_a_whole_number_is_ascii_digits(text: str) -> None:
    with pytest.raises(NotANumber, match="expected a whole number such as 3"):
        plain_whole_number(text)


OPTIONS = [
    (["synthesize", "{seq}", "--out", "{out}/x.exr", "--weights", "1,{v},0,0,0,0,0"], "--weights"),
    (["estimate", "{seq}", "--bin", "{v}"], "--bin"),
    (["estimate", "{seq}", "--alpha", "{v}"], "--alpha"),
    (["estimate", "{seq}", "--reference-patch", "0,0,{v},4"], "--reference-patch"),
    (["run", "--out", "{out}", "--flash-power", "{v}"], "--flash-power"),
    (["run", "--out", "{out}", "--seed", "{v}"], "--seed"),
    (["run", "--out", "{out}", "--exposure", "{v}"], "--exposure"),
    (["run", "--out", "{out}", "--flicker", "{v}:0.3"], "--flicker"),
    (["run", "--out", "{out}", "--rig", "hw", "--roi", "0,0,{v},8"], "--roi"),
    (["live", "--runs", "{out}", "--port", "{v}"], "--port"),
    (["doctor", "--port", "/dev/null", "--timeout-s", "{v}"], "--timeout-s"),
    (["booth-emulator", "--watchdog-s", "{v}"], "--watchdog-s"),
    (["evaluate", "{seq}", "--chart", "macbeth", "--patch-px", "8", "--border-px", "{v}"], "--border-px"),
    (["study", "failure", "--threshold", "{v}"], "--threshold"),
    (["colour-study", "--depth-m", "{v}"], "--depth-m"),
]


@pytest.mark.parametrize("value", ["1_0", "١٢", "infinity"])
@pytest.mark.parametrize(("words", "option"), OPTIONS, ids=[option for _, option in OPTIONS])
def test_a_number_option_refuses_what_float_reads_but_a_user_does_not_mean(
    words: list[str], option: str, value: str, sequence: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each option was read through ``float`` or ``int``: ``1_0`` as 10, ``١٢`` as 12 (``infinity`` reached some)."""
    line = [
        w.replace("{seq}", str(sequence)).replace("{out}", str(tmp_path / "out")).replace("{v}", value) for w in words
    ]
    assert main(line) == 2
    lines = [text for text in capsys.readouterr().err.splitlines() if text.strip()]
    assert len(lines) == 1 and lines[0].startswith("msflash: error: ") and option in lines[0], lines
    assert value in lines[0]
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_a_list_option_with_blanks_after_its_commas_is_read(sequence: Path, tmp_path: Path) -> None:
    """``--weights "1, 0, 0, …"`` (blanks are separators, as in a CSV row) reads as ``1,0,0,…``."""
    spaced, tight = tmp_path / "spaced.exr", tmp_path / "tight.exr"
    assert main(["synthesize", str(sequence), "--weights", "1, 0.5, 0, 0, 0, 0, 0", "--out", str(spaced)]) == 0
    assert main(["synthesize", str(sequence), "--weights", "1,0.5,0,0,0,0,0", "--out", str(tight)]) == 0
    np.testing.assert_array_equal(read_image(spaced), read_image(tight))  # the pixels: the files' dates may differ


def test_no_option_is_read_by_float_or_int() -> None:
    """One source of truth: every numeric option goes through the plain-number parser (cli_common.number, whole,
    whole_number, number_where, …), none through ``float``/``int``, which read ``1_0`` and ``١٢``."""
    parsers = [build_parser()]
    found: list[str] = []
    count = 0
    while parsers:
        current = parsers.pop()
        for action in current._actions:
            count += 1
            if action.type in (float, int):
                found.append("/".join(action.option_strings) or action.dest)
            if isinstance(action.choices, dict):
                parsers.extend(action.choices.values())
    assert count > 100 and found == []


@pytest.mark.parametrize("value", ["1_0", "١٢", "infinity"])
def test_a_target_table_refuses_such_a_cell_naming_file_line_and_column(
    value: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table = tmp_path / "target.csv"
    rows = [f"{400 + 10 * i},{value if i == 3 else 1}" for i in range(31)]
    table.write_bytes(("\ufeff" + "\r\n".join(["wavelength_nm,target", *rows]) + "\r\n").encode())
    assert main(["run", "--target", str(table), "--out", str(tmp_path / "out")]) == 2
    line = capsys.readouterr().err.strip()
    assert f"target.csv:5: column 'target' holds '{value}'; expected a" in line and "\n" not in line


@pytest.mark.parametrize("value", ["1_0", "١٢", "infinity"])
def test_a_spectrometer_export_refuses_such_a_value_naming_its_line(value: str, tmp_path: Path) -> None:
    from msflash.calibration.errors import CalibrationError
    from msflash.calibration.spectrometer import read_spectrometer_file

    export = tmp_path / "led.txt"
    rows = [f"{400 + i}\t{100 + i}" for i in range(50)]
    rows[20] = f"420\t{value}"
    export.write_bytes("\r\n".join(["Wavelength (nm)\tCounts", *rows, ""]).encode())
    with pytest.raises(CalibrationError, match=rf"led\.txt:22: .*{value}"):
        read_spectrometer_file(export)


def test_a_header_number_with_unicode_digits_is_not_read() -> None:
    from msflash.calibration.spectrometer_header import header_number

    assert header_number("١٠") is None and header_number("1_0") is None and header_number("1,5") == 1.5


def test_the_booth_console_reads_typed_levels_with_the_same_parser(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``levels ١ ١ ١ …`` (Arabic-Indic ones, from a keyboard layout) lit every LED at full: ``float`` reads them."""
    import io

    from msflash.led_controller import BoothEmulator, serve_on_pty

    typed = "levels ١ ١ ١ ١ ١ ١ ١\npset ١ 0 0 0 0 0 0 0\nwdog 1_0\nquit\n"
    monkeypatch.setattr("sys.stdin", io.StringIO(typed))
    with serve_on_pty(BoothEmulator()) as served:
        assert main(["booth", "console", served.port, "--booth-boot-s", "0"]) == 0
        assert served.emulator.levels == (0.0,) * 7
    out = capsys.readouterr().out
    assert "levels '١ ١ ١ ١ ١ ١ ١' are not numbers" in out and "a step number first" in out
    assert "'1_0' is not a number of seconds" in out
