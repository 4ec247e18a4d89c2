"""``msflash calibrate`` end to end through ``acquisition.app.cli.main``, and ``--calibration`` in estimate/flash."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app import cli
from msflash.calibration.files import load_calibration
from msflash.processing import datasets

SEQUENCE = Path(__file__).resolve().parents[1] / "data" / "sequences" / "sim-macbeth-fluorescent"


SEQUENCE_LEDS = tuple(led["name"] for led in json.loads((SEQUENCE / "sequence.json").read_text())["leds"])
"""The recorded sequence's names of the paper's LEDs (recorded before they were named after their measured peaks)."""


def write_leds(directory: Path) -> list[str]:
    leds = datasets.paper_leds()
    files = []
    for index, name in enumerate(SEQUENCE_LEDS):  # the exports named as the booth names its channels
        path = directory / f"{name}.txt"
        rows = "\n".join(f"{w:g}\t{v:.8g}" for w, v in zip(leds.wavelengths_nm, leds.values[:, index]))
        path.write_text(f"# PR-715 export\nWavelength (nm)\tRadiance\n{rows}\n")
        files.append(str(path))
    return files


def test_leds_then_estimate_with_calibration(tmp_path, capsys):
    out = tmp_path / "cal"
    assert cli.main(["calibrate", "leds", *write_leds(tmp_path), "--out", str(out), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert [round(item["peak_nm"] / 10) * 10 for item in payload["leds"]][:2] == [440, 480]
    calibration = load_calibration(out)
    assert calibration.led_spectra.names == SEQUENCE_LEDS
    assert (out / "leds.png").exists()
    sequence = tmp_path / "seq"
    shutil.copytree(SEQUENCE, sequence)
    assert cli.main(["estimate", str(sequence), "--json", "--calibration", str(out)]) == 0
    captured = capsys.readouterr()
    assert f"LED spectra from calibration {calibration.id}" in captured.err
    assert len(json.loads(captured.out)["ambient_weights"]) == 7


def test_camera_simulate_then_flash_with_calibration(tmp_path, capsys):
    out = tmp_path / "cal"
    assert cli.main(["calibrate", "camera", "--simulate", "--camera", "Nikon D700", "--out", str(out), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["rmse_vs_truth"] < 0.05
    assert cli.main(["flash", str(SEQUENCE), "--mode", "complementary", "--json", "--calibration", str(out)]) == 0
    captured = capsys.readouterr()
    assert "camera responsivities from calibration" in captured.err
    weights = np.array(json.loads(captured.out)["flash_weights"])
    assert weights.shape == (7,) and np.all((weights >= 0) & (weights <= 1))


def test_bad_spectrometer_file_exits_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("nm,v\n400,1\n410,nan\n420,0\n")
    assert cli.main(["calibrate", "leds", str(bad), "--out", str(tmp_path / "cal")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("msflash: error:") and "bad.csv:3" in err[0]


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["calibrate", "camera", "--out", "X"], "expected --sequence SEQ… (recorded chart sequences) or --simulate"),
        (["calibrate", "dark", str(SEQUENCE), "--out", "X"], "no 'dark' frame"),
        (["calibrate", "leds", "missing.csv", "--out", "X"], "missing.csv: cannot be read"),
        (["calibrate"], "expected one of leds, camera, chart, dark, linearity"),
    ],
)
def test_usage_errors(argv, needle, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("msflash: error:") and needle in err[0]


def test_bad_calibration_dir_for_estimate(tmp_path, capsys):
    assert cli.main(["estimate", str(SEQUENCE), "--calibration", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "calibration.json: cannot be read" in err[0]


@pytest.mark.parametrize("what", ["leds", "camera"])
def test_a_calibration_directory_another_msflash_is_writing_is_refused(
    what: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One writer per calibration directory (issue 19, build 3): a calibrate into a folder held by another
    msflash exits 2 naming the holder, and leaves the folder as it was."""
    import os

    from msflash.acquisition.sequence.folder_claim import claim_folder

    out = tmp_path / "cal"
    arguments = {"leds": [*write_leds(tmp_path)], "camera": ["--simulate", "--camera", "Nikon D700"]}[what]
    with claim_folder(out, "msflash calibrate (the other one)"):
        assert cli.main(["calibrate", what, *arguments, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"in use by msflash process {os.getpid()}" in err, err
    assert not (out / "calibration.json").exists()
    # Released, the same command runs.
    assert cli.main(["calibrate", what, *arguments, "--out", str(out)]) == 0
