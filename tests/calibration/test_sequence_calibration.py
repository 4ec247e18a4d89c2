"""``msflash calibrate camera --sequence``: chart sequences recorded from the sim rig (NikonD100 world).

Two sequences of the Macbeth chart, ambients tungsten and daylight (the two known broadband
lights), each with the 7 LED frames; the prior never contains NikonD100 (``--prior-exclude``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app import cli
from msflash.acquisition.sequence.reader import read_sequence
from msflash.calibration.camera_response import responsivity_rmse
from msflash.calibration.chart_sequence import resolve_light, sequence_measurements
from msflash.calibration.errors import CalibrationError
from msflash.calibration.files import load_calibration
from msflash.lab.study.camera_calibration import flash_delta_e
from msflash.processing import datasets


def _record(root: Path, ambient: str, seed: int, cfa: str | None = None) -> Path:
    out = root / f"{ambient}-{cfa or 'rgb'}"
    argv = [
        "capture",
        "--rig",
        "sim",
        "--scene",
        "macbeth",
        "--ambient",
        ambient,
        "--seed",
        str(seed),
        "--out",
        str(out),
    ]
    if cfa:
        argv += ["--cfa", cfa]
    assert cli.main(argv) == 0
    return out / "sequence"


@pytest.fixture(scope="module")
def rgb_sequences(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("chart-rgb")
    return [_record(root, "tungsten", 1), _record(root, "daylight", 2)]


def _calibrate(sequences: list[Path], out: Path, capsys, *extra: str) -> dict:
    argv = [
        "calibrate",
        "camera",
        "--sequence",
        *map(str, sequences),
        "--light",
        "tungsten",
        "--light",
        "daylight",
        "--prior-exclude",
        "NikonD100",
        "--out",
        str(out),
        "--json",
        *extra,
    ]
    capsys.readouterr()  # drop what capture printed
    assert cli.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_sequences_recover_the_sim_camera_within_the_bound(rgb_sequences, tmp_path, capsys):
    payload = _calibrate(rgb_sequences, tmp_path / "cal", capsys)
    calibration = load_calibration(tmp_path / "cal")
    truth = read_sequence(rgb_sequences[0]).camera_responsivities().to_unit("photons")
    recovered = calibration.camera_responsivities
    rmse = responsivity_rmse(recovered, truth)
    assert rmse == pytest.approx(payload["rmse_vs_sequence_responsivity"])
    assert rmse <= 0.05
    # The unknown powers: tungsten of sequence 0, then the LEDs and daylight of sequence 1.
    assert set(payload["light_scales"]) == {"0: tungsten", "1: LEDs", "1: daylight"}
    assert all(v > 0 for v in payload["light_scales"].values())
    assert calibration.camera["prior_excluded"] == ["NikonD100"]
    assert len(calibration.camera["frames"]) == 16  # 2 × (7 LED differences + the ambient)
    # Flash mixes solved with the recovered vs the true responsivities.
    chart = datasets.macbeth().resample(truth.grid)
    _, worst = flash_delta_e(truth, recovered.resample(truth.grid), chart)
    assert worst <= 1.0


def test_smoothness_also_runs_and_the_prior_is_not_worse(rgb_sequences, tmp_path, capsys):
    """Measured: prior 0.0162, smoothness 0.0152. Before the sim's LEDs were made as bright as a flash
    (each LED ≥ the ambient, instead of all seven together 2×) the LED frames were noisier and the
    prior helped more: 0.0204 against 0.0266. Within 10 % of each other now, both well under 0.05."""
    prior = _calibrate(rgb_sequences, tmp_path / "a", capsys)["rmse_vs_sequence_responsivity"]
    smooth = _calibrate(rgb_sequences, tmp_path / "b", capsys, "--method", "smoothness")
    assert smooth["rmse_vs_sequence_responsivity"] <= 0.05
    assert prior <= smooth["rmse_vs_sequence_responsivity"] * 1.10


def test_bayer_sequences(tmp_path_factory, tmp_path, capsys):
    root = tmp_path_factory.mktemp("chart-bayer")
    sequences = [_record(root, "tungsten", 3, "RGGB"), _record(root, "daylight", 4, "RGGB")]
    payload = _calibrate(sequences, tmp_path / "cal", capsys)
    assert payload["rmse_vs_sequence_responsivity"] <= 0.05


def test_leds_only_without_lights(rgb_sequences, tmp_path, capsys):
    argv = [
        "calibrate",
        "camera",
        "--sequence",
        str(rgb_sequences[0]),
        "--prior-exclude",
        "NikonD100",
        "--out",
        str(tmp_path / "cal"),
        "--json",
    ]
    assert cli.main(argv) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["light_scales"] == {}
    assert payload["rmse_vs_sequence_responsivity"] <= 0.08


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--light", "tungsten"], "--light given 1 times for 2 sequences"),
        (["--light", "tungsten", "--light", "moonlight"], "--light 'moonlight': not a known light"),
        (["--light", "tungsten", "--light", "missing.csv"], "missing.csv: light file not found"),
        (["--light", "tungsten", "--light", "daylight", "--patch-px", "5"], "is not uniform in the ambient image"),
        (
            ["--light", "tungsten", "--light", "daylight", "--patch-px", "4", "--border-px", "1"],
            "patches read the same colour as another patch",
        ),
        (["--light", "daylight", "--light", "tungsten"], "expected the right --light"),
        (
            ["--light", "tungsten", "--light", "daylight", "--patch-px", "30"],
            "the macbeth chart is 130×194 pixels but the image is 46×62",
        ),
        (
            ["--light", "tungsten", "--light", "daylight", "--prior-exclude", "NoSuchCam"],
            "not among the 34 paper cameras",
        ),
        (["--light", "tungsten", "--light", "daylight", "--simulate"], "exclude each other"),
    ],
)
def test_bad_command_lines_exit_2_with_one_line(rgb_sequences, tmp_path, capsys, extra, message):
    argv = ["calibrate", "camera", "--sequence", *map(str, rgb_sequences), "--out", str(tmp_path / "cal"), *extra]
    assert cli.main(argv) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert error.startswith("msflash: error:") and message in error


def test_bad_light_csv_names_the_file(tmp_path):
    bad = tmp_path / "lamp.csv"
    bad.write_text("wavelength_nm,value\n400,1\n410,nan\n")
    with pytest.raises(CalibrationError, match="lamp.csv") as caught:
        resolve_light(str(bad), datasets.macbeth().grid)
    # Named once, with the line: it read "…/lamp.csv: …/lamp.csv:3: …" (prefixed twice).
    assert str(caught.value).startswith(f"{bad}:3: column 'value' is missing")
    narrow = tmp_path / "narrow.csv"
    narrow.write_text("wavelength_nm,value\n440,1\n450,2\n460,1\n")
    with pytest.raises(CalibrationError) as caught:
        resolve_light(str(narrow), datasets.macbeth().grid)
    assert str(caught.value).count(str(narrow)) == 1 and "cannot resample" in str(caught.value)


def test_unusable_frames_are_refused(rgb_sequences):
    sequence = read_sequence(rgb_sequences[0])
    chart = datasets.macbeth().resample(sequence.grid, outside="edge")

    def nothing(shape, excluded):
        return np.full(shape, -1, dtype=np.int64)

    with pytest.raises(CalibrationError, match=r"001-led.tiff: only 0 of 24 chart patches"):
        sequence_measurements([sequence], [None], chart, nothing)
    with pytest.raises(CalibrationError, match="1 lights for 2 sequences"):
        sequence_measurements([sequence, sequence], [None], chart, nothing)
