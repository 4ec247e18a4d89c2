"""Issue 33, item 4: CLI manners — "did you mean" for every name typed, stop lines true to what happened,
and the default solver's constraint described as it is."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.app.options import SOLVER_CONSTRAINTS
from msflash.processing.ambient import AMBIENT_METHODS
from tests.helpers import SAMPLES_DIR

SAMPLE = SAMPLES_DIR / "sample-rgb-tungsten"
REPO = Path(__file__).resolve().parents[3]


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = main(list(argv))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.mark.parametrize(
    ("argv", "meant"),
    [
        (["run", "--ambient", "tungstn"], "tungsten"),
        (["run", "--ambient", "D66"], "D65"),
        (["run", "--sim-camera", "NikonD10"], "NikonD100"),
        (["run", "--scene", "chart11"], "chart110"),
        (["run", "--leds", "6x"], None),  # not an integer: argparse's own line, one line all the same
        (["run", "--rig", "sym"], "sim"),
        (["run", "--rig", "aravis-fake", "--fake-camera", "gain-ra"], "gain-raw"),
        (["run", "--solver", "tikonov"], "tikhonov"),
        (["run", "--target", "D66"], "D65"),
        (["run", "--export", "ome-tif"], "ome-tiff"),
        (["runn"], "run"),
        (["estimate", str(SAMPLE), "--model", "prir"], "prior"),
        (["estimate", str(SAMPLE), "--solver", "nonnegative"], "nonneg"),
        (["export", str(SAMPLE), "--to", "omt-tiff"], "ome-tiff"),
        (["flash", str(SAMPLE), "--mode", "complimentary"], "complementary"),
        (["evaluate", str(SAMPLE), "--chart", "macbth"], "macbeth"),
        (["study", "tabel1"], "table1"),
        (["calibrate", "led"], "leds"),
        (["live", "--rig", "aravis-fak"], "aravis-fake"),
    ],
)
def test_a_mistyped_name_gets_one_line_with_what_was_meant_and_nothing_is_made(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, argv: list[str], meant: str | None
) -> None:
    argv = [*argv, "--out", str(tmp_path / "out")] if argv[0] in ("run", "export") else argv
    status, out, err = run(capsys, *argv)
    assert status == 2, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("msflash: error: ") and "Traceback" not in err
    if meant is not None:
        assert f"did you mean '{meant}'" in last, last
    assert len(last) < 700, last  # one readable line, not a list of every name there is
    assert not (tmp_path / "out").exists()


def test_run_with_a_bad_ambient_is_refused_before_any_frame_and_leaves_no_folder(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    status, _, err = run(capsys, "run", "--ambient", "tungstn", "--out", str(tmp_path / "run"))
    assert status == 2 and "did you mean 'tungsten'" in err
    assert "capturing" not in err and list(tmp_path.iterdir()) == []


@pytest.mark.aravis
def test_a_mistyped_camera_feature_is_matched_against_what_the_camera_offers(sfnc_fake_camera: Any) -> None:
    from msflash.acquisition.devices.aravis.camera_features import apply_feature
    from msflash.acquisition.errors import CameraSettingError

    with pytest.raises(CameraSettingError, match=r"no feature BlackLevl; did you mean 'BlackLevel'"):
        apply_feature(sfnc_fake_camera, "BlackLevl", "5", "--feature BlackLevl=5")


# -- stop lines ------------------------------------------------------------------------------------
def test_ctrl_c_while_the_rig_opens_says_nothing_was_captured_and_leaves_no_folder(tmp_path: Path) -> None:
    """A real ``msflash run`` interrupted once it says it is opening the rig. Whatever it had reached when
    the signal landed, the last line says what is on disk: no folder and "no frame was captured", or the
    sequence it began."""
    out = tmp_path / "run"
    with subprocess.Popen(
        [sys.executable, "-m", "msflash.acquisition.app.cli", "run", "--rig", "sim", "--out", str(out)],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    ) as process:
        assert process.stderr is not None
        lines = []
        for line in process.stderr:
            lines.append(line)
            if "opening rig" in line:
                process.send_signal(signal.SIGINT)
                break
        lines += process.stderr.readlines()
        assert process.wait(timeout=120) == 130, "".join(lines)
    last = lines[-1].strip()
    if (out / "sequence" / "sequence.json").exists():
        assert f"in {out / 'sequence'}" in last, last
    else:
        assert last == "msflash: interrupted; LEDs off; stopped before the sequence began: no frame was captured"
        assert not out.exists()
    assert "frames captured so far are kept" not in "".join(lines[:-1])


@pytest.mark.parametrize(
    ("command", "line"),
    [
        ("devices", "msflash: interrupted"),
        ("doctor", "msflash: interrupted"),
        ("calibrate", "msflash: interrupted"),
        ("booth", "msflash: interrupted; LEDs off"),
        ("live", "msflash: interrupted; LEDs off"),
    ],
)
def test_commands_that_capture_nothing_claim_no_frames(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], command: str, line: str
) -> None:
    import argparse

    from msflash.acquisition.app import cli

    def stopped(args: argparse.Namespace) -> int:
        raise KeyboardInterrupt

    parser = cli.build_parser()
    monkeypatch.setattr(parser, "parse_args", lambda argv: argparse.Namespace(verbose=0, handler=stopped))
    monkeypatch.setattr(cli, "build_parser", lambda argv=None: parser)
    assert cli.main([command]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == line


# -- the solver's constraint, as it is ----------------------------------------------------------------
def test_the_solver_words_cover_every_solver_and_say_weights_are_free(capsys: pytest.CaptureFixture[str]) -> None:
    assert set(SOLVER_CONSTRAINTS) == set(AMBIENT_METHODS)
    with pytest.raises(SystemExit):
        main(["estimate", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "non-negative with roughness penalty" not in help_text
    assert "tikhonov: least squares with a squared roughness penalty; the spectrum I·w kept ≥ 0, each weight free" in (
        help_text
    )


def test_a_negative_weight_in_the_report_is_explained_by_the_solver_it_names(tmp_path: Path) -> None:
    """Whatever the signs of the weights it shows, the report says what the solver constrains: the spectrum, not
    each weight (the paper's eq. 6) — the issue saw −0.046 beside a solver called "non-negative"."""
    out = tmp_path / "run"
    assert main(["run", "--rig", "sim", "--out", str(out), "--ambient", "fluorescent"]) == 0
    summary = json.loads((out / "run.json").read_text())
    assert summary["solver"] == "tikhonov"
    report = (out / "report.html").read_text()
    assert "solved by tikhonov: least squares with a squared roughness penalty" in report
    assert "A weight may be negative where neighbouring LEDs overlap" in report
    assert "non-negative solver" not in report
