"""Fuzzing the processing commands' options: ``estimate``, ``flash``, ``synthesize`` and ``export`` on the independent
tool's RGB sample, each run with one to three options set to values they take or, one time in three, to values a user
might type by accident (NaN, 1e309, Arabic digits, hexadecimal, a FIFO, a folder, 300 letters …), ``main()`` in-process, from a working directory holding a
folder and a file named like the names the options take (``D65``, ``A``, ``tungsten``).

Every run must end with exit 0, or exit 2 and one ``msflash: error:`` line; never a crash, and never another exit. A run
whose every value is one the option takes must end with exit 0: the decoys beside it change nothing.
The draws are seeded: a failure names its seed, and ``_case(seed)`` rebuilds the command. Session 21 found a folder
``D65`` beside the command turning the default ``--target D65`` into a refused directory this way."""

from __future__ import annotations

import contextlib
import io
import os
import random
import shutil
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from tests.helpers import SAMPLES_DIR

VALUES = (
    "", "0", "-1", "1e309", "nan", "inf", "-inf", "1e-320", "99999999999999999999", "0x10", "1,2", "1,2,3,4",
    "0,0,0,0", "-1,-1,5,5", "a", "é", "/dev/null", ".", "/nonexistent/x", "fifo", "D65", "A", "tungsten", "5",
    "1.5", " 3", "1_000", "١٢", "Infinity", "+5", "5e3", "0b1", "x" * 300, "--json", "-5e-3", "auto", "none",
    "local", "global", "nonneg", "matching", "physical", "dng,csv", "exr", "D65/", "0.1,0.1,0.1,0.1,0.1,0.1,0.1",
)  # fmt: skip
"""What a user might type into any option: numbers beyond range or not numbers, paths of every kind, names."""

COMMANDS = {
    "estimate": (
        "--solver",
        "--alpha",
        "--bin",
        "--calibration",
        "--method",
        "--tiles",
        "--model",
        "--reference-patch",
    ),
    "flash": ("--mode", "--target", "--bounds", "--solver", "--alpha", "--bin", "--tiles", "--method", "--out"),
    "synthesize": ("--weights", "--out"),
    "export": ("--to", "--out", "--target", "--bin", "--alpha"),
}
"""The options fuzzed per command (``--scheduler``/``--workers`` left out: a batch starts dask)."""

VALID = {
    "--solver": ("lstsq", "nonneg", "roughness", "tikhonov"),
    "--alpha": ("auto", "0.001", "0.01"),
    "--bin": ("1", "2", "4"),
    "--method": ("auto", "global", "local"),
    "--tiles": ("2", "4"),
    "--model": ("led", "prior", "family", "auto"),
    "--reference-patch": ("0,0,16,16",),
    "--mode": ("matching", "complementary"),
    "--target": ("D65", "A", "./A", "FL2", "blackbody:3200"),
    "--bounds": ("physical", "nonnegative", "free"),
    "--weights": ("0.1,0.1,0.1,0.1,0.1,0.1,0.1", "1,0,0,0,0,0,0", "0,0.5,0,0.5,0,0,0"),
    "--to": ("csv", "exr", "dng", "ome-tiff", "csv,exr"),
    "--out": ("{seed}.exr", "{seed}.tiff"),
}
"""Values each option takes, drawn more often than :data:`VALUES` so that most runs get past the parser."""

HOSTILE = 0.35
"""The chance that an option gets a value of :data:`VALUES` rather than one of :data:`VALID`."""

CASES = 64


def _case(seed: int, sequence: Path) -> tuple[list[str], bool]:
    """The command line of draw ``seed``, and whether every value in it was drawn from :data:`VALID`; the required
    options the draw left out get a plain value."""
    draw = random.Random(seed)
    command = draw.choice(sorted(COMMANDS))
    options = COMMANDS[command]
    argv, valid = [command, str(sequence)], True
    for option in draw.sample(options, min(len(options), draw.randint(1, 3))):
        hostile = option not in VALID or draw.random() < HOSTILE
        valid &= not hostile
        choices = ("out-{seed}",) if (command, option) == ("export", "--out") else VALID.get(option, ())
        argv += [option, draw.choice(VALUES) if hostile else draw.choice(choices).format(seed=seed)]
    if draw.random() < 0.3:
        argv.append("--json")
    required = {
        "flash": ("--mode", "complementary"),
        "synthesize": ("--weights", "0.1,0.1,0.1,0.1,0.1,0.1,0.1"),
        "export": ("--to", "csv"),
    }
    if command in required and required[command][0] not in argv:
        argv += list(required[command])
    if command in ("synthesize", "export") and "--out" not in argv:
        argv += ["--out", f"out-{seed}" + (".exr" if command == "synthesize" else "")]
    return argv, valid


@pytest.fixture(scope="module")
def workplace(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A working directory with decoys named like the options' names, and a copy of the RGB sample."""
    place = tmp_path_factory.mktemp("cwd")
    for name in ("D65", "tungsten"):
        (place / name).mkdir()
    (place / "A").write_text("wavelength_nm,value\n400,1\n500,1\n600,1\n700,1\n")  # a light unlike CIE A
    os.mkfifo(place / "fifo")
    sequence = place / "sample"
    shutil.copytree(SAMPLES_DIR / "sample-rgb-tungsten", sequence)
    return place, sequence


@pytest.mark.parametrize("seed", range(CASES))
def test_options_typed_by_accident_end_in_a_result_or_one_error_line(
    seed: int, workplace: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    place, sequence = workplace
    monkeypatch.chdir(place)
    argv, valid = _case(seed, sequence)
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            status = main(argv)
        except SystemExit as stop:  # argparse's own refusals exit here
            status = stop.code if isinstance(stop.code, int) else 2
    lines = [line for line in err.getvalue().splitlines() if line.strip()]
    assert status in (0, 2), (argv, err.getvalue())
    assert "Traceback" not in err.getvalue(), (argv, err.getvalue())
    if status == 2:
        errors = [line for line in lines if line.startswith("msflash: error: ")]
        assert len(errors) == 1, (argv, err.getvalue())
    assert status == 0 or not valid, (argv, err.getvalue())  # values the options take, beside the decoys: a result
