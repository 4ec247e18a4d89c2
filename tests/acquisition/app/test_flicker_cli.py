"""``--flicker`` and ``--anti-flicker`` on ``msflash run``: the sim lamp flickers, the estimate reports and corrects it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.analysis import synthesize_checked, synthesize_sequence
from msflash.processing.flicker import FlickerCheck


def test_a_flickering_lamp_is_found_reported_and_recorded(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    assert main(["run", "--out", str(out), "--flicker", "100:0.3", "--exposure", "2000", "--seed", "2"]) == 0
    err = capsys.readouterr().err
    flicker = json.loads((out / "estimate.json").read_text())["flicker"]
    truth = json.loads((out / "sequence" / "sequence.json").read_text())["msflash"]["true_flicker"]
    assert truth["depth"] == 0.3 and abs(truth["frequency_hz"] - 100) <= 1
    assert flicker["checked"] and flicker["detected"] and flicker["corrected"]
    assert flicker["spread"] > 0.05 and len(flicker["frame_gains"]) == 7
    assert "msflash: flicker: the LED frames saw" in err
    # The run's own estimate fits the mains at the timestamps of the sequence it wrote (its live header has none).
    assert flicker["frequency_hz"] is not None and abs(flicker["frequency_hz"] - truth["frequency_hz"]) < 1.0
    assert "; fitted " in err
    # The recorded sequence tells the same from disk.
    assert main(["estimate", str(out / "sequence")]) == 0
    assert "msflash: flicker: the LED frames saw" in capsys.readouterr().err
    # The flash re-captured live was decided from the corrected statistics: the mix the sequence gives from disk
    # (before, the live decision took the LED images as they were: 0.050, 0.122 against 0.052, 0.128).
    frames = json.loads((out / "sequence" / "sequence.json").read_text())["frames"]
    (recaptured,) = [f["led_levels"] for f in frames if f["role"] == "flash"]
    assert main(["flash", str(out / "sequence"), "--mode", "complementary", "--method", "global", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["flash_weights"] == pytest.approx(recaptured, abs=1e-9)


def test_a_steady_lamp_raises_no_flicker(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    assert main(["run", "--out", str(out), "--exposure", "2000", "--seed", "2"]) == 0
    flicker = json.loads((out / "estimate.json").read_text())["flicker"]
    assert flicker["checked"] and not flicker["detected"] and not flicker["corrected"]
    assert "flicker" not in capsys.readouterr().err


def test_anti_flicker_exposures_are_whole_periods(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    argv = ["capture", "--out", str(out), "--exposure", "23000", "--anti-flicker", "60", "--flicker", "120:0.3"]
    assert main(argv) == 0
    frames = json.loads((out / "sequence" / "sequence.json").read_text())["frames"]
    assert {round(f["exposure_us"], 3) for f in frames} == {round(2e6 / 120, 3)}
    assert main(["capture", "--out", str(tmp_path / "short"), "--exposure", "2000", "--anti-flicker", "50"]) == 0
    assert "shorter than one flicker period (10.00 ms)" in capsys.readouterr().err


def test_the_runs_flash_recapture_is_named_when_no_whole_period_fits(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """In a booth the flash outshines the room: the re-capture's predicted exposure (a few ms) is shorter than a
    flicker period, so it is kept and named (the rounding itself: tests/acquisition/session/test_anti_flicker.py)."""
    argv = ["run", "--out", str(tmp_path / "r"), "--flicker", "100:0.3", "--anti-flicker", "50", "--seed", "1"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "warning: flash exposure" in err and "shorter than one flicker period (10.00 ms, --anti-flicker 50)" in err


@pytest.mark.parametrize(
    "argv, named",
    [
        (["--flicker", "abc"], "--flicker: 'abc': expected HZ:DEPTH"),
        (["--flicker", "100:2"], "expected a percent flicker in (0, 1]"),
        (["--anti-flicker", "55"], "--anti-flicker '55': unknown"),
        (["--rig", "replay:nowhere", "--flicker", "100:0.3"], "--flicker: describes the simulated world's lamp"),
    ],
)
def test_bad_flicker_options_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture, argv: list[str], named: str
) -> None:
    assert main(["run", "--out", str(tmp_path / "r"), *argv]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("msflash: error")]
    assert len(lines) == 1 and named in lines[0]
    assert "Traceback" not in err


def _mean_image(path: Path) -> float:
    import OpenImageIO as oiio

    pixels = oiio.ImageInput.open(str(path)).read_image("float")
    return float(np.mean(pixels))


def test_the_flash_image_of_a_flickering_lamp_holds_its_ambient_once(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """The synthesised flash image takes out the lamp's extra share in each LED frame, as the estimate does: its
    flash part (the image less the ambient frame) is the steady lamp's scene's, where before it kept that share."""
    images = {}
    for name, flicker in (("steady", []), ("flickering", ["--flicker", "100:0.3"])):
        out = tmp_path / name
        assert main(["run", "--out", str(out), "--exposure", "2000", "--seed", "2", *flicker]) == 0
        images[name] = out / "sequence"
    capsys.readouterr()
    flash = tmp_path / "flash.exr"
    argv = ["flash", str(images["flickering"]), "--mode", "complementary", "--method", "global", "--json"]
    assert main([*argv, "--out", str(flash)]) == 0
    weights = np.array(json.loads(capsys.readouterr().out)["flash_weights"])
    steady, flickering = read_sequence(images["steady"]), read_sequence(images["flickering"])
    check = synthesize_checked(flickering, weights)[3]
    assert check is not None and check.corrected

    def flash_part(sequence: Sequence, flicker: FlickerCheck | None = None) -> float:
        image, _, _ = synthesize_sequence(sequence, weights, flicker=flicker)
        return float(np.mean(image) - np.mean(synthesize_sequence(sequence, 0 * weights)[0]))

    truth = flash_part(steady)
    before = abs(flash_part(flickering) / truth - 1)  # the LED frames' extra ambient kept
    after = abs(flash_part(flickering, check) / truth - 1)
    # `flash --out` and `synthesize` (weights given alone) write that image, and say the flicker they took out
    again = tmp_path / "again.exr"
    assert (
        main(["synthesize", str(images["flickering"]), "--weights=" + ",".join(map(str, weights)), "--out", str(again)])
        == 0
    )
    assert "msflash: flicker: the LED frames saw" in capsys.readouterr().err
    assert _mean_image(again) == pytest.approx(_mean_image(flash), rel=1e-6)
    assert before > 0.03 and after < before / 3, (before, after)
