"""``msflash estimate|flash --method auto|global|local`` and ``msflash local-study`` (issue 9)."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import build_parser, main
from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed
from msflash.acquisition.sequence.image_files import read_image
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.lab import cli_local
from msflash.lab.study.local import Scenario, make_scenario
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID

SHAPE = (96, 128)


def write_scenario(directory: Path, scenario: Scenario) -> Path:
    """A complete sequence (energy units, NikonD100 responsivities) holding a simulated scenario's frames."""
    leds = scenario.led_spectra.to_unit("energy")
    responsivity = datasets.isetcam_camera("NikonD100").resample(DEFAULT_GRID)
    camera = SequenceCamera(
        model="test-local",
        serial=None,
        pixel_format="RGB16",
        cfa=None,
        black_level=scenario.spec.black_level,
        white_level=scenario.spec.white_level,
        responsivity={c: responsivity.column(c) for c in ("R", "G", "B")},
    )
    exposure = 1.0 / scenario.spec.ambient_scale
    with SequenceWriter(
        directory,
        wavelengths_nm=DEFAULT_GRID.wavelengths_nm,
        spectral_unit="energy",
        camera=camera,
        leds=[SequenceLed(name, leds.column(name)) for name in leds.names],
    ) as writer:
        writer.add_frame(scenario.ambient, "ambient", [0.0] * leds.count, exposure_us=exposure, gain=1.0)
        for index, frame in enumerate(scenario.led_frames):
            writer.add_frame(frame, "led", list(scenario.spec.led_levels[index]), exposure_us=exposure, gain=1.0)
    return directory


@cache
def _sequences(root: str) -> dict[str, Path]:
    base = Path(root)
    return {
        kind: write_scenario(base / kind, make_scenario(kind, seed, SHAPE))
        for kind, seed in (("uniform", 11), ("boundary", 12))
    }


@pytest.fixture(scope="module")
def sequences(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return _sequences(str(tmp_path_factory.mktemp("local")))


def run_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict:
    status = main(list(argv))
    captured = capsys.readouterr()
    assert status == 0, captured.err
    return json.loads(captured.out)


def test_estimate_global_keeps_the_contract(sequences: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    payload = run_json(capsys, "estimate", str(sequences["boundary"]), "--method", "global", "--json")
    assert payload["method"] == "global" and payload["solver"] == "tikhonov"
    assert len(payload["spectrum"]) == len(payload["wavelengths_nm"]) and len(payload["ambient_weights"]) == 7
    assert "tiles" not in payload


def test_estimate_auto_uniform_is_the_global_estimate(
    sequences: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    global_payload = run_json(capsys, "estimate", str(sequences["uniform"]), "--method", "global", "--json")
    payload = run_json(capsys, "estimate", str(sequences["uniform"]), "--json")  # auto is the default
    assert payload["method"] == "global" and payload["method_requested"] == "auto"
    assert payload["model_selection"]["chosen"] == "global"
    assert payload["model_selection"]["scores"]["global"] == 1.0
    # The same estimate, bit for bit: the global model is the whole frame's (local_route.estimate_sequence_local).
    np.testing.assert_array_equal(payload["spectrum"], global_payload["spectrum"])
    assert "tiles" not in payload


def test_estimate_auto_two_illuminants_goes_local(
    sequences: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    payload = run_json(capsys, "estimate", str(sequences["boundary"]), "--method", "auto", "--tiles", "6", "--json")
    assert payload["method"] == "local"
    tiles = payload["tiles"]
    assert tiles["grid"] == [6, 6]
    weights = np.array(tiles["ambient_weights"])
    assert weights.shape == (6, 6, 7)
    assert np.array(tiles["spectra"]).shape == (6, 6, len(payload["wavelengths_nm"]))
    assert len(tiles["row_edges"]) == 7 and tiles["row_edges"][-1] == SHAPE[0]
    # The docs/architecture.md §7 keys hold the area-weighted mean over the tiles; the global estimate is kept.
    areas = np.outer(np.diff(tiles["row_edges"]), np.diff(tiles["column_edges"]))
    np.testing.assert_allclose(
        payload["ambient_weights"], np.einsum("ts,tsk->k", areas, weights) / areas.sum(), rtol=1e-9
    )
    assert len(payload["spectrum_global"]) == len(payload["spectrum"])
    assert min(v for k, v in payload["model_selection"]["scores"].items() if k != "global") < 0.9


def test_estimate_local_text_output(sequences: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["estimate", str(sequences["boundary"]), "--method", "local", "--tiles", "4"]) == 0
    out = capsys.readouterr().out
    assert "local model, 4x4 tiles" in out and "nm" in out


def test_flash_local_writes_a_spatially_varying_image(
    sequences: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "local.exr"
    payload = run_json(
        capsys,
        "flash",
        str(sequences["boundary"]),
        "--mode",
        "complementary",
        "--method",
        "local",
        "--tiles",
        "4",
        "--bounds",
        "nonnegative",
        "--out",
        str(out),
        "--json",
    )
    assert payload["method"] == "local" and payload["mode"] == "complementary" and payload["scale"] > 0
    tile_weights = np.array(payload["tiles"]["flash_weights"])
    assert tile_weights.shape == (4, 4, 7) and np.all(tile_weights >= 0)
    # Two ambients need two different complements.
    assert np.ptp(tile_weights, axis=(0, 1)).max() > 0.05 * np.abs(tile_weights).max()
    image = read_image(out)
    assert image.shape == (*SHAPE, 3) and np.all(np.isfinite(image))


def test_flash_physical_weights_stay_in_bounds(sequences: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    payload = run_json(
        capsys,
        "flash",
        str(sequences["boundary"]),
        "--mode",
        "complementary",
        "--method",
        "local",
        "--tiles",
        "4",
        "--json",
    )
    assert all(0.0 <= w <= 1.0 for w in payload["flash_weights"])
    assert np.all(
        (np.array(payload["tiles"]["flash_weights"]) >= 0) & (np.array(payload["tiles"]["flash_weights"]) <= 1)
    )


def test_bad_method_is_a_usage_error(sequences: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["estimate", str(sequences["uniform"]), "--method", "patchy"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("msflash: error: ") and "--method" in err


def test_local_study_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parser = build_parser()
    subparsers = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    if "local-study" not in subparsers.choices:
        cli_local.register(subparsers)
    args = parser.parse_args(
        [
            "local-study",
            "--uniform",
            "2",
            "--mixed",
            "1",
            "--no-timing",
            "--out",
            str(tmp_path),
            "--json",
            "--seed0",
            "7",
        ]
    )
    assert args.handler(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["uniform"]["n"] == 2 and summary["boundary"]["n"] == 1 and summary["seed0"] == 7
    assert {"rmse_global", "rmse_auto", "rmse_alone", "global_rate"} <= set(summary["uniform"])
    # A uniform scene's "each ambient alone" capture is the capture itself: the reference is the local
    # model's estimator (denoised statistics) over the whole frame.
    assert summary["uniform"]["rmse_alone"] == summary["uniform"]["rmse_global_denoised"]
    assert summary["two_illuminant"]["n"] == 2 and 0.0 < summary["boundary"]["label_accuracy"] <= 1.0
    assert (tmp_path / "local-study.json").exists() and (tmp_path / "local-study.png").exists()
