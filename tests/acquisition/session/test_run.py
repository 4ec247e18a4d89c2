"""`msflash run` and `msflash capture` on the sim rig, end to end (SimulatedCamera + emulator on a pty)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import rig as rig_module

# The sim world's spectrum RMSE is ~0.15–0.26 (the best LED fit of its ambients is 0.16–0.21);
# 0.35 catches a broken estimator without pinning noise.
SPECTRUM_RMSE_LIMIT = 0.35


@pytest.fixture(scope="module")
def tungsten_run(tmp_path_factory: pytest.TempPathFactory) -> tuple:
    out = tmp_path_factory.mktemp("run") / "demo"
    status = main(["run", "--out", str(out), "--ambient", "tungsten"])
    return status, out


def test_run_writes_a_complete_sequence_with_a_flash_frame(tungsten_run: tuple) -> None:
    status, out = tungsten_run
    assert status == 0
    sequence = read_sequence(out / "sequence")
    assert sequence.complete
    assert [f.role for f in sequence.frames] == ["ambient"] + ["led"] * 7 + ["flash"]
    flash = sequence.frames[-1]
    summary = json.loads((out / "run.json").read_text())
    np.testing.assert_allclose(
        flash.led_levels, np.clip(summary["flash"]["complementary"]["flash_weights"], 0, 1), atol=1e-9
    )
    assert any(level > 0 for level in flash.led_levels)


def test_run_outputs_and_accuracy(tungsten_run: tuple) -> None:
    _, out = tungsten_run
    for name in (
        "estimate.json",
        "flash-matching.json",
        "flash-complementary.json",
        "spectra.png",
        "ambient.png",
        "matching.png",
        "complementary.png",
        "flash-capture.png",
        "matching.exr",
        "complementary.exr",
        "report.html",
    ):
        assert (out / name).stat().st_size > 0, name
    estimate = json.loads((out / "estimate.json").read_text())
    assert len(estimate["spectrum"]) == len(estimate["wavelengths_nm"]) == 31
    summary = json.loads((out / "run.json").read_text())
    assert summary["spectrum_rmse_vs_truth"] < SPECTRUM_RMSE_LIMIT
    weights = np.array(summary["flash"]["matching"]["flash_weights"])
    assert weights.max() == pytest.approx(1.0) and weights.min() >= 0


def test_run_refuses_an_existing_run(tungsten_run: tuple, capsys: pytest.CaptureFixture) -> None:
    _, out = tungsten_run
    assert main(["run", "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip().startswith("msflash: error: --out")


def test_capture_mosaic_sequence(tmp_path) -> None:
    assert main(["capture", "--out", str(tmp_path / "c"), "--cfa", "GRBG", "--ambient", "fluorescent"]) == 0
    sequence = read_sequence(tmp_path / "c" / "sequence")
    assert sequence.complete and sequence.camera.cfa == "GRBG"
    assert sequence.load_frame(0).ndim == 2
    assert main(["estimate", str(tmp_path / "c" / "sequence"), "--json"]) == 0


def test_leds_off_and_partial_sequence_kept_when_capture_fails(tmp_path, monkeypatch, capsys) -> None:
    """A camera failure mid-sequence: exit 1, LEDs off on the emulator, frames so far readable."""
    opened = {}
    original = rig_module.open_sim_rig

    def open_and_break(**options):
        rig = original(**options)
        opened["rig"] = rig
        camera = rig.camera
        real_next = camera.next_frame
        calls = {"n": 0}

        def failing_next(timeout_s: float):
            calls["n"] += 1
            if calls["n"] >= 4:  # from step 3 on the camera stays silent: its retakes time out too
                from msflash.acquisition.errors import FrameTimeoutError

                raise FrameTimeoutError("simulated camera: injected timeout")
            return real_next(timeout_s)

        camera.next_frame = failing_next  # fault injection on a real SimulatedCamera instance
        return rig

    monkeypatch.setattr(rig_module, "open_sim_rig", open_and_break)
    out = tmp_path / "broken"
    assert main(["capture", "--exposure", "10000", "--out", str(out)]) == 1  # no previews before the failure
    err = capsys.readouterr().err
    assert "step 3" in err and "3 frame(s) already saved" in err and "(after 2 retake(s) of lost frames)" in err
    sequence = read_sequence(out / "sequence")
    assert not sequence.complete and len(sequence.frames) == 3
    assert opened["rig"].emulator is not None
    assert all(level == 0 for level in opened["rig"].emulator.levels)


def test_a_frame_lost_mid_sequence_is_taken_again_and_said(tmp_path, monkeypatch, capsys, caplog) -> None:
    """The camera reports step 2's frame incomplete once: the capture warns, takes steps 2 on again,
    says which frames are retakes, exits 0 with a complete sequence."""
    from msflash.acquisition.errors import FrameLostError

    original = rig_module.open_sim_rig

    def open_and_lose(**options):
        rig = original(**options)
        real_next = rig.camera.next_frame
        calls = {"n": 0}

        def losing_next(timeout_s: float):
            frame = real_next(timeout_s)
            calls["n"] += 1
            if calls["n"] == 3:
                raise FrameLostError(f"simulated camera: frame {frame.frame_id} for step 2 arrived incomplete")
            return frame

        rig.camera.next_frame = losing_next  # fault injection on a real SimulatedCamera instance
        return rig

    monkeypatch.setattr(rig_module, "open_sim_rig", open_and_lose)
    out = tmp_path / "lossy"
    assert main(["capture", "--exposure", "10000", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "taking step 2 (led:2) again, with the 5 step(s) after it (retake 1 of 2)" in caplog.text
    assert "captured step 2 (led:2) → frames/002-led.tiff (retake 1, after a lost frame)" in err
    sequence = read_sequence(out / "sequence")
    assert sequence.complete and [f.extra.get("retake", 0) for f in sequence.frames] == [0, 0] + [1] * 6


def test_run_decides_the_flash_before_the_reliability_signals(tmp_path, monkeypatch) -> None:
    """`msflash run` drives the flash from FlashSession.decide (weights, flash, exposure predicted from the
    frames as they arrived); the estimate's reliability signals are computed only after the capture."""
    from msflash.acquisition.session import run as run_session
    from msflash.acquisition.session.flash_session import FlashSession
    from msflash.processing.ambient import AmbientModel

    order: list[str] = []

    def recorded(name, real):
        def call(*args, **kwargs):
            order.append(name)
            return real(*args, **kwargs)

        return call

    monkeypatch.setattr(FlashSession, "decide", recorded("decide", FlashSession.decide))
    monkeypatch.setattr(FlashSession, "flash_exposure", recorded("exposure", FlashSession.flash_exposure))
    monkeypatch.setattr(AmbientModel, "reliability", recorded("reliability", AmbientModel.reliability))
    real_capture = run_session.run_capture_with_flash

    def capture(*args, **kwargs):
        entries = real_capture(*args, **kwargs)
        order.append("captured")
        return entries

    monkeypatch.setattr(run_session, "run_capture_with_flash", capture)
    assert main(["run", "--out", str(tmp_path / "r"), "--ambient", "daylight"]) == 0
    assert order[:4] == ["decide", "exposure", "captured", "reliability"]
    summary = json.loads((tmp_path / "r" / "run.json").read_text())
    assert read_sequence(tmp_path / "r" / "sequence").frames[-1].exposure_us == pytest.approx(
        summary["exposure"]["flash_exposure_us"]
    )


def test_an_output_path_where_the_sequence_cannot_be_written_is_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """OUT/sequence is a file: bad output path (exit 2, one line naming it), nothing captured, no traceback."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "sequence").write_text("not a directory\n")
    status = main(["capture", "--exposure-us", "5000", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2
    assert err[-1].startswith(f"msflash: error: {out / 'sequence'}: cannot write the sequence there (")
    assert "expected a writable directory" in err[-1] and not any("captured step" in line for line in err)
    assert (out / "sequence").read_text() == "not a directory\n"
