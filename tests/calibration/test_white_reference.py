"""``msflash calibrate leds --white SEQ``: the LEDs' power ratios as the camera sees a white reference.

Sequences come from the sim rig (``--scene white``: a flat white filling the frame, with a radial
falloff), whose recorded LED spectra hold the true ratios; the spectrometer exports given to the
command have the right shapes but wrong ratios, as when the probe moved between LEDs.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app import cli
from msflash.acquisition.sequence.image_files import write_image
from msflash.acquisition.sequence.reader import read_sequence
from msflash.calibration.errors import CalibrationError
from msflash.calibration.files import load_calibration
from msflash.calibration.white_reference import parse_roi, white_led_responses
from tests.helpers import forget_digests


def _capture(root: Path, scene: str, cfa: str | None = None) -> Path:
    argv = ["capture", "--rig", "sim", "--scene", scene, "--ambient", "tungsten", "--seed", "4", "--out", str(root)]
    assert cli.main(argv + (["--cfa", cfa] if cfa else [])) == 0
    return root / "sequence"


@pytest.fixture(scope="module")
def white(tmp_path_factory) -> Path:
    return _capture(tmp_path_factory.mktemp("white") / "rgb", "white")


def _peak_ratios(values: np.ndarray) -> np.ndarray:
    peaks = values.max(axis=0)
    return peaks / peaks.max()


def _exports(sequence: Path, folder: Path, seed: int = 3) -> tuple[list[str], np.ndarray]:
    """One spectrometer export per LED: the true shape at a random scale; and the true peak ratios."""
    leds = read_sequence(sequence).led_spectra().to_unit("energy")
    scales = np.random.default_rng(seed).uniform(0.1, 1.0, leds.count)
    files = []
    for k, name in enumerate(leds.names):
        path = folder / f"{name}.csv"
        values = leds.values[:, k] / leds.values[:, k].max() * scales[k]
        np.savetxt(
            path,
            np.column_stack([leds.wavelengths_nm, values]),
            delimiter=",",
            header="wavelength_nm,value",
            comments="",
        )
        files.append(str(path))
    return files, _peak_ratios(leds.values)


def _run(capsys, *argv: str) -> dict:
    capsys.readouterr()
    assert cli.main(["calibrate", "leds", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_exports_with_wrong_ratios_get_the_ratios_the_camera_sees(white, tmp_path, capsys):
    files, truth = _exports(white, tmp_path)
    payload = _run(capsys, *files, "--white", str(white), "--out", str(tmp_path / "cal"))
    calibration = load_calibration(tmp_path / "cal")
    recovered = _peak_ratios(calibration.led_spectra.values)
    assert np.max(np.abs(recovered / truth - 1)) < 0.01  # 0.1 % measured; noise and grid only
    assert list(payload["relative_power"]) == list(read_sequence(white).led_spectra().names)
    assert np.allclose(list(payload["relative_power"].values()), recovered)
    source = calibration.leds["relative_power_source"]
    assert source["white_sequence"].endswith("sequence.json")
    assert source["camera_responsivities"].startswith("sequence")  # no camera section in the new calibration
    assert max(source["share_spread"].values()) < 0.01 and source["warnings"] == []
    assert calibration.leds["peaks_nm"] and calibration.leds["relative_power_note"] is None


def test_white_alone_rescales_the_calibrations_led_shapes(white, tmp_path, capsys):
    files, truth = _exports(white, tmp_path, seed=8)
    out = str(tmp_path / "cal")
    _run(capsys, *files, "--out", out)  # the spectrometer's wrong ratios
    assert np.max(np.abs(_peak_ratios(load_calibration(out).led_spectra.values) / truth - 1)) > 0.2
    _run(capsys, "--white", str(white), "--out", out)
    calibration = load_calibration(out)
    assert np.max(np.abs(_peak_ratios(calibration.led_spectra.values) / truth - 1)) < 0.01
    assert calibration.leds["sources"] == files  # the LED section is kept, the power added


def test_white_without_any_shapes_uses_the_sequences_own(white, tmp_path, capsys):
    payload = _run(capsys, "--white", str(white), "--out", str(tmp_path / "cal"))
    truth = _peak_ratios(read_sequence(white).led_spectra().values)
    assert np.allclose(list(payload["relative_power"].values()), truth, rtol=0.01)


def test_bayer_white_reference(tmp_path, capsys):
    sequence = _capture(tmp_path / "bayer", "white", cfa="RGGB")
    files, truth = _exports(sequence, tmp_path)
    _run(capsys, *files, "--white", str(sequence), "--out", str(tmp_path / "cal"))
    assert np.max(np.abs(_peak_ratios(load_calibration(tmp_path / "cal").led_spectra.values) / truth - 1)) < 0.01


_RAW_CHART_PASSES_AS_WHITE = pytest.mark.xfail(
    strict=True,
    reason=(
        "finding (issue 30, raw frames; calibration/white_reference.py): on the sim rig's raw mosaic the chart's "
        "LED shares vary 9–24 % over the sub-blocks, but the noise subtracted from that spread comes from the "
        "standard errors of each region's samples — the chart's own patches, and on a mosaic a quarter or half "
        "of the samples per channel — 17–26 %, so every spread reads 0 and the chart passes as a white reference "
        "(RGB: 8–20 % against 10–13 %, refused)"
    ),
)


@pytest.mark.parametrize("cfa", ["none", pytest.param("RGGB", marks=_RAW_CHART_PASSES_AS_WHITE)])
def test_a_coloured_scene_is_refused_as_a_white_reference(tmp_path, capsys, cfa):
    chart = _capture(tmp_path / "chart", "chart110", cfa)
    assert cli.main(["calibrate", "leds", "--white", str(chart), "--out", str(tmp_path / "cal")]) == 2
    error = capsys.readouterr().err
    assert "share of the light varies" in error and "--white-roi" in error and str(chart) in error


def test_uneven_led_is_warned_about(white, tmp_path):
    """One LED lighting the reference with a left-to-right ramp (another position in the booth)."""
    sequence = read_sequence(white)
    copy = tmp_path / "uneven"
    copy.mkdir()
    (copy / "sequence.json").write_text(sequence.path.read_text())
    forget_digests(copy)  # its frames are rewritten below, one of them changed
    (copy / "frames").mkdir()
    ambient_index = sequence.indices("ambient")[0]
    led = sequence.indices("led")[2]
    black = sequence.camera.black_level
    # The ambient's part of the LED frame, at that frame's exposure (auto exposure gives them different ones).
    ambient = black + (sequence.load_frame(ambient_index).astype(float) - black) * (
        sequence.frames[led].exposure_us / sequence.frames[ambient_index].exposure_us
    )
    for index, frame in enumerate(sequence.frames):
        pixels = sequence.load_frame(index)
        if index == led:
            # across the columns, of RGB frames or of the sim rig's raw mosaic alike
            ramp = np.linspace(0.8, 1.2, pixels.shape[1]).reshape((1, -1) + (1,) * (pixels.ndim - 2))
            pixels = np.clip(np.rint(ambient + (pixels - ambient) * ramp), 0, sequence.camera.white_level).astype(
                np.uint16
            )
        write_image(copy / frame.file, pixels)
    result = white_led_responses(read_sequence(copy))
    name = sequence.leds[2].name
    assert [w for w in result.warnings if f"LED '{name}'" in w] and len(result.warnings) == 1
    assert 0.02 < result.share_spread[2] < 0.08


def test_bad_white_inputs(white, tmp_path, capsys):
    out = str(tmp_path / "cal")
    assert cli.main(["calibrate", "leds", "--out", out]) == 2
    assert "expected spectrometer exports FILES…, --white SEQ, or both" in capsys.readouterr().err
    assert cli.main(["calibrate", "leds", "--white", str(white), "--white-roi", "90,10,64,64", "--out", out]) == 2
    assert "reaches outside the 128×96 frame" in capsys.readouterr().err
    files, _ = _exports(white, tmp_path)
    assert cli.main(["calibrate", "leds", *files[:3], "--white", str(white), "--out", out]) == 2
    assert "the sequence has 7 LEDs but 3 LED spectra" in capsys.readouterr().err
    for text in ("1,2,3", "a,b,c,d", "-1,0,10,10", "0,0,1,10"):
        with pytest.raises(CalibrationError, match="expected X,Y,W,H"):
            parse_roi(text)
