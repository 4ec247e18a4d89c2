"""``import msflash``'s functions compute what the command line prints (issue 30, item 6).

``msflash.estimate_ambient`` used to return processing's photons while ``estimate --json`` printed the
sequence's unit (energy: the API's curve 0.61× the command's at 400 nm, 1.06× at 700 nm, normalised),
and ``msflash.read_sequence`` refused the run folder every command takes.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

import msflash
from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import RecordingError


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("api") / "run"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["capture", "--out", str(out), "--seed", "2", "--leds", "5"]) == 0
    return out


def _printed(*argv: str) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        assert main(list(argv)) == 0
    return json.loads(out.getvalue())


def test_read_sequence_takes_what_the_commands_take(run_folder: Path, tmp_path: Path) -> None:
    folders = {
        msflash.read_sequence(path).directory
        for path in (run_folder, run_folder / "sequence", run_folder / "sequence" / "sequence.json", str(run_folder))
    }
    assert folders == {run_folder / "sequence"}
    with pytest.raises(RecordingError, match=f"{tmp_path.name}: holds no sequence|expected a sequence folder"):
        msflash.read_sequence(tmp_path)


@pytest.mark.parametrize(
    ("options", "argv"),
    [
        ({}, ()),
        ({"method": "global"}, ("--method", "global")),
        ({"solver": "nonneg"}, ("--solver", "nonneg")),
        ({"model": "prior"}, ("--model", "prior")),
    ],
    ids=["default", "global", "nonneg", "prior"],
)
def test_the_estimate_is_the_commands_to_the_last_digit_in_its_unit(run_folder: Path, options: dict, argv) -> None:
    sequence = msflash.read_sequence(run_folder)
    solver = options.pop("solver", "tikhonov")
    estimate = msflash.estimate_ambient(sequence, solver, **options)
    printed = _printed(
        "estimate", str(run_folder), "--json", *(("--solver", solver) if solver != "tikhonov" else ()), *argv
    )
    assert estimate.spectrum.unit == printed["spectral_unit"] == sequence.spectral_unit == "energy"
    assert estimate.spectrum.values[:, 0].tolist() == printed["spectrum"]
    assert estimate.spectrum_std.tolist() == printed["spectrum_std"]
    assert estimate.ambient_weights.tolist() == printed["ambient_weights"]
    assert list(estimate.warnings) == printed["warnings"] and estimate.band_meaning == printed["band"]
    # and the flash solved from it is the command's
    flash = msflash.solve_flash(sequence, estimate, "matching")
    assert np.all((flash.flash_weights >= 0) & (flash.flash_weights <= 1))
