"""Option values and inputs refused with argparse's or msflash's one line, naming the option or file."""

from __future__ import annotations

from pathlib import Path

import pytest

from msflash.acquisition.app import cli

SIM_SEQUENCE = Path(__file__).resolve().parents[2] / "data" / "sequences" / "sim-macbeth-fluorescent"


@pytest.mark.parametrize("value", ["0", "-3", "two"])
def test_whole_number_options_name_themselves(capsys: pytest.CaptureFixture, value: str) -> None:
    assert cli.main(["local-study", "--tiles", value]) == 2
    assert (
        capsys.readouterr().err.strip().splitlines()[-1]
        == f"msflash: error: argument --tiles: '{value}': expected a whole number ≥ 1"
    )


def test_linearity_refuses_frames_under_different_lights(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A chart sequence (ambient, each LED, the flash) has no common response curve: it stored
    'max deviation 1.62, linear up to 0 DN' with exit 0."""
    assert cli.main(["calibrate", "linearity", str(SIM_SEQUENCE), "--out", str(tmp_path / "cal")]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "the lit frames are under 9 different illuminations" in last
    assert "expected one illumination at several exposures of a uniform target" in last
    assert not (tmp_path / "cal").exists()
