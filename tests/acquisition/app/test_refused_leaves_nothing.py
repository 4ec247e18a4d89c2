"""A command refused for bad input leaves no output folder behind (exit 2, one line, nothing created).

Each case is refused inside the command, after its ``--out`` could have been made: the folder is
claimed while the command runs (``cli_common.claimed_output``) and removed when it was refused.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main

RECORDED = str(Path(__file__).resolve().parents[2] / "data" / "sequences" / "sim-macbeth-fluorescent")

REFUSED = {
    "run, unknown sim camera": ["run", "--sim-camera", "nope"],
    "capture, unknown ambient": ["capture", "--ambient", "nope"],
    "run, replay of nothing": ["run", "--rig", "replay:nowhere"],
    "evaluate, unknown target": ["evaluate", RECORDED, "--chart", "macbeth", "--target", "nope"],
    "study, paper alpha for cameras": [
        "study", "cameras", "--alpha-units", "paper", "--solver", "roughness", "--scheduler", "none",
    ],
    "calibrate camera, unknown camera": ["calibrate", "camera", "--simulate", "--camera", "nope"],
    "calibrate dark, no dark frame": ["calibrate", "dark", RECORDED],
    "colour-study, unknown ambient": ["colour-study", "--ambients", "nope"],
}  # fmt: skip


@pytest.mark.parametrize("argv", REFUSED.values(), ids=REFUSED.keys())
def test_a_refused_command_leaves_no_output_folder(argv: list[str], tmp_path: Path, capsys):
    out = tmp_path / "out" / "deeper"
    status = main([*argv, "--out", str(out)])
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.splitlines()[-1].startswith("msflash: error: ")
    assert not (tmp_path / "out").exists()  # neither the folder nor the parent made for it


def test_synthesize_refused_writes_no_image_and_no_folder(tmp_path: Path, capsys):
    out = tmp_path / "images" / "mix.exr"
    assert main(["synthesize", RECORDED, "--weights", "1,2", "--out", str(out)]) == 2
    assert "--weights has 2 values; expected 7" in capsys.readouterr().err
    assert not (tmp_path / "images").exists()


LONG_NAME = "y" * 300
"""Longer than any Linux filesystem's file name (255 bytes): ``Path.exists`` raises ENAMETOOLONG on it."""

TOO_LONG = {
    "run": ["run"],
    "capture": ["capture"],
    "evaluate": ["evaluate", RECORDED, "--chart", "macbeth"],
    "export": ["export", RECORDED, "--to", "csv"],
}


@pytest.mark.parametrize("where", ["{long}", "a/{long}/b"])
@pytest.mark.parametrize("argv", TOO_LONG.values(), ids=TOO_LONG.keys())
def test_an_out_name_longer_than_the_filesystem_allows_is_refused_in_one_line(
    argv: list[str], where: str, tmp_path: Path, capsys
) -> None:
    # Was: "msflash: run: unexpected OSError: [Errno 36] File name too long" (exit 1, a crash log), and
    # with a/LONG/b the parent "a" made before the refusal stayed behind.
    out = tmp_path / where.format(long=LONG_NAME)
    status = main([*argv, "--out", str(out)])
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2, lines
    assert lines[-1].startswith(f"msflash: error: --out {tmp_path}/")
    assert "yyy…y (300 characters)" in lines[-1] and "longer than the filesystem allows" in lines[-1]
    assert list(tmp_path.iterdir()) == []
