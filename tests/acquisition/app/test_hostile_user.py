"""A hostile user's pass over the command line and the Python API (branch hostile30): what a user types by
accident is refused with one line naming the option or file and what was expected (exit 2), never a
crash, silently other numbers or a lost capture. Each test failed before its fix; real files, ``main()``
in-process, no mocks."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from tests.helpers import write_test_sequence


@pytest.fixture(scope="module")
def base_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_test_sequence(tmp_path_factory.mktemp("hostile") / "seq")


@pytest.fixture
def sequence(base_sequence: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "seq"
    shutil.copytree(base_sequence, copy)
    return copy


def _digests(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()
    }


def _one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("msflash: error: "), err
    return lines[0]


@pytest.mark.parametrize(
    ("command", "target"),
    [
        (["synthesize", "{seq}", "--weights", "1,0,0,0,0,0,0"], "frames/000-ambient.tiff"),
        (["flash", "{seq}", "--mode", "matching"], "frames/001-led.tiff"),
        (["synthesize", "{seq}", "--weights", "1,0,0,0,0,0,0"], "mix.exr"),
    ],
)
def test_an_image_written_into_the_sequence_folder_is_refused_and_no_frame_is_lost(
    sequence: Path, command: list[str], target: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--out SEQ/frames/000-ambient.tiff`` replaced the captured ambient frame by the synthesised image: the
    sequence's first frame was lost (``check`` then called it truncated). Refused before anything is written."""
    before = _digests(sequence)
    words = [word.replace("{seq}", str(sequence)) for word in command]
    assert main([*words, "--out", str(sequence / target)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"--out {sequence / target}" in line and "inside the sequence folder" in line
    assert _digests(sequence) == before
    assert main(["check", str(sequence)]) == 0


def test_an_image_beside_the_sequence_is_still_written(sequence: Path, tmp_path: Path) -> None:
    out = tmp_path / "beside.exr"
    assert main(["synthesize", str(sequence), "--weights", "1,0,0,0,0,0,0", "--out", str(out)]) == 0
    assert out.stat().st_size > 0


@pytest.mark.parametrize(
    "command",
    [["run"], ["capture"], ["calibrate", "camera", "--simulate"], ["study", "surfaces"], ["colour-study"]],
    ids=lambda words: " ".join(words),
)
def test_a_negative_seed_is_refused_naming_the_option(
    command: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--seed -1`` reached numpy's generator: ``run``/``capture`` exited 1 "rig 'sim': expected non-negative
    integer" (a device failure, naming neither the option), ``calibrate camera`` and ``study`` crashed."""
    out = tmp_path / "out"
    assert main([*command, "--seed", "-1", "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "--seed" in line and "expected a whole number ≥ 0" in line
    assert not out.exists()


@pytest.mark.parametrize(("patch", "border"), [("100000", "2"), ("8", "99999999999")])
def test_a_chart_layout_far_larger_than_the_image_is_refused_before_it_is_drawn(
    sequence: Path, patch: str, border: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``evaluate --patch-px 100000`` drew the chart's label map (894 GiB) before checking that it fits the image:
    "unexpected MemoryError — a bug"."""
    words = ["evaluate", str(sequence), "--chart", "macbeth", "--patch-px", patch, "--border-px", border]
    assert main([*words, "--out", str(tmp_path / "eval")]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"--patch-px {patch} --border-px {border}: the macbeth chart is" in line and "but the image is" in line


@pytest.mark.parametrize("patch", ["100000", "7", "0"])
def test_colour_study_refuses_a_patch_side_it_cannot_render_or_measure(
    patch: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``colour-study --patch-px 100000`` crashed (MemoryError drawing the chart); 7 or less with ``--cfa`` was
    refused late, naming a ``--margin-px`` the command does not have."""
    assert main(["colour-study", "--patch-px", patch, "--ambients", "green", "--cfa", "RGGB", "--json"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"argument --patch-px: '{patch}': expected a whole number of pixels, 8-256" in line
