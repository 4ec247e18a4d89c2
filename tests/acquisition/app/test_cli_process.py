"""``msflash estimate|flash|synthesize`` through ``acquisition.app.cli.main`` (docs/architecture.md §7)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.image_files import read_image, write_image
from tests.helpers import forget_digests, led_mix, write_test_sequence

N_LEDS = 7
MIX = [0.2, 0.05, 0.4, 0.3, 0.6, 0.1, 0.25]
"""Ambient weights of an in-span ambient."""
QUANTISED = 2e-3
"""Weights from noise-free but 16-bit-quantised frames."""


@pytest.fixture(scope="module")
def base_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_test_sequence(tmp_path_factory.mktemp("seq") / "tungsten")


@pytest.fixture(scope="module")
def mix_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_test_sequence(tmp_path_factory.mktemp("seq") / "mix", led_mix(MIX))


@pytest.fixture(scope="module")
def bayer_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_test_sequence(
        tmp_path_factory.mktemp("seq") / "bayer",
        led_mix(MIX),
        cfa="GRBG",
        gains=[1.0, 2.0, 1.0, 1.0, 1.5, 1.0, 1.0, 3.0],
    )


@pytest.fixture
def sequence_copy(base_sequence: Path, tmp_path: Path) -> Path:
    target = tmp_path / "copy"
    shutil.copytree(base_sequence, target)
    return target


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = main(list(argv))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def edit_document(directory: Path, change: Callable[[dict], None]) -> None:
    path = directory / "sequence.json"
    document = json.loads(path.read_text())
    change(document)
    path.write_text(json.dumps(document))


def assert_bad_input(status: int, out: str, err: str, *names: str) -> None:
    assert status == 2, err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("msflash: error: ")
    for name in names:
        assert name in lines[0], f"{name!r} not named in {lines[0]!r}"
    assert out == ""


# -- bad input ---------------------------------------------------------------------------------
def _truncate_led(document: dict) -> None:
    document["leds"][2]["spd"] = document["leds"][2]["spd"][:-3]


def _nan_led(document: dict) -> None:
    document["leds"][1]["spd"][5] = float("nan")


def _outside(document: dict) -> None:
    document["frames"][3]["file"] = "../outside.tiff"


def _newer(document: dict) -> None:
    document["version"] = 2


@pytest.mark.parametrize(
    ("change", "names"),
    [
        (_truncate_led, ("leds[2].spd", "sequence.json")),
        (_nan_led, ("leds[1].spd", "sequence.json")),
        (_outside, ("frames[3].file", "outside the sequence directory")),
        (_newer, ("version", "sequence.json")),
    ],
    ids=["led-grid-mismatch", "nan-in-spectrum", "frame-outside-directory", "newer-version"],
)
@pytest.mark.parametrize("command", [["estimate"], ["flash", "--mode", "complementary"]], ids=["estimate", "flash"])
def test_bad_sequence_document(capsys, sequence_copy: Path, change, names, command) -> None:
    edit_document(sequence_copy, change)
    assert_bad_input(*run(capsys, command[0], str(sequence_copy), *command[1:], "--json"), *names)


def test_missing_frame_file(capsys, sequence_copy: Path) -> None:
    (sequence_copy / "frames" / "004-led.tiff").unlink()
    assert_bad_input(*run(capsys, "estimate", str(sequence_copy)), "frames[4].file", "004-led.tiff", "missing")


def test_frames_of_different_sizes(capsys, sequence_copy: Path) -> None:
    forget_digests(sequence_copy)  # replaced behind the writer's back: a digest would refuse it first
    path = sequence_copy / "frames" / "003-led.tiff"
    write_image(path, read_image(path)[:-4, :-2])
    assert_bad_input(*run(capsys, "estimate", str(sequence_copy), "--json"), "003-led.tiff", "000-ambient.tiff")


def test_missing_sequence_directory(capsys, tmp_path: Path) -> None:
    assert_bad_input(*run(capsys, "estimate", str(tmp_path / "nowhere")), "sequence.json")


@pytest.mark.parametrize("weights", ["1,2,3", ",".join(["0.5"] * (N_LEDS + 1))])
def test_wrong_weights_count(capsys, base_sequence: Path, tmp_path: Path, weights: str) -> None:
    out = tmp_path / "x.exr"
    assert_bad_input(
        *run(capsys, "synthesize", str(base_sequence), "--weights", weights, "--out", str(out)),
        "--weights",
        f"expected {N_LEDS}",
    )
    assert not out.exists()


def test_non_numeric_weights(capsys, base_sequence: Path, tmp_path: Path) -> None:
    assert_bad_input(
        *run(capsys, "synthesize", str(base_sequence), "--weights", "a,b", "--out", str(tmp_path / "x.exr")),
        "--weights",
    )


@pytest.mark.parametrize("alpha", ["-1", "nan", "inf", "1e400", "smooth"])
@pytest.mark.parametrize("command", [["estimate"], ["flash", "--mode", "complementary"]], ids=["estimate", "flash"])
def test_bad_alpha_names_the_option_and_what_is_expected(capsys, base_sequence: Path, alpha: str, command) -> None:
    """'--alpha -1' printed "invalid _alpha value" (a Python function name); 'inf' reached the solver
    (exit 1, 'the normal matrix has non-finite entries; expected finite data')."""
    status, out, err = run(capsys, command[0], str(base_sequence), *command[1:], f"--alpha={alpha}")
    assert_bad_input(status, out, err, "--alpha", f"'{alpha}'", "expected a finite number ≥ 0 or 'auto'")
    assert "_alpha" not in err


@pytest.mark.parametrize("suffix", [".exr", ".tiff"])
@pytest.mark.parametrize(
    "command",
    [["synthesize", "--weights", "1,0,0,0,0,0,0"], ["flash", "--mode", "matching"]],
    ids=["synthesize", "flash"],
)
def test_unwritable_out_is_bad_input_naming_out(
    capsys, base_sequence: Path, tmp_path: Path, suffix: str, command
) -> None:
    """--out under a regular file: a FileExistsError traceback from mkdir (or, where the directory
    exists but cannot be written, an error naming write_image's hidden temporary file)."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    out = blocker / "deeper" / f"x{suffix}"
    status, stdout, err = run(capsys, command[0], str(base_sequence), *command[1:], "--out", str(out))
    assert_bad_input(
        status, stdout, err, f"--out {out}", f"{blocker} is not a directory", "expected a writable file path"
    )
    assert ".tmp" not in err


@pytest.mark.parametrize(
    "command",
    [["synthesize", "--weights", "1,0,0,0,0,0,0"], ["flash", "--mode", "matching"]],
    ids=["synthesize", "flash"],
)
def test_unknown_out_type_is_refused(capsys, base_sequence: Path, tmp_path: Path, command) -> None:
    out = tmp_path / "x.jpg"
    assert_bad_input(
        *run(capsys, command[0], str(base_sequence), *command[1:], "--out", str(out)),
        f"--out {out}",
        "expected .exr (linear float) or .tiff (16-bit raw)",
    )
    assert not out.exists()


def test_clipped_raw_tiff_output_is_reported(capsys, base_sequence: Path, tmp_path: Path) -> None:
    """Large weights clip the 16-bit raw output at the white level; that was silent."""
    out = tmp_path / "bright.tiff"
    status, stdout, err = run(
        capsys, "synthesize", str(base_sequence), "--weights", "1000,0,0,0,0,0,0", "--out", str(out)
    )
    assert status == 0, err
    raw = read_image(out)
    white = json.loads((base_sequence / "sequence.json").read_text())["camera"]["white_level"]
    clipped = int(np.count_nonzero((raw >= white) | (raw <= 0)))
    assert clipped > 0.1 * raw.size
    assert f"warning: {clipped} of the {raw.size} samples of {out} ({clipped / raw.size:.2%}) are clipped" in err
    status, stdout, err = run(
        capsys, "synthesize", str(base_sequence), "--weights", "0.1,0,0,0,0,0,0", "--out", str(tmp_path / "fine.tiff")
    )
    assert status == 0 and "clipped" not in err


def test_flash_without_responsivity(capsys, sequence_copy: Path) -> None:
    edit_document(sequence_copy, lambda d: d["camera"].pop("responsivity"))
    assert_bad_input(*run(capsys, "flash", str(sequence_copy), "--mode", "matching"), "camera.responsivity")


@pytest.mark.parametrize("method", ["global", "auto"])
def test_dark_ambient_is_refused_by_estimate_and_flash(capsys, sequence_copy: Path, method: str) -> None:
    """An ambient frame of read noise about the black level (light off, lens capped): estimate printed
    a noise 'spectrum' normalised to a full-height plot (exit 0), matching blew its ~1e-10 weights up
    to a full-drive mix, and complementary returned a ~5e-6 drive flash that 'reached' D65."""
    document = json.loads((sequence_copy / "sequence.json").read_text())
    black = document["camera"]["black_level"]
    path = sequence_copy / "frames" / "000-ambient.tiff"
    shape = read_image(path).shape
    forget_digests(sequence_copy)
    noise = np.random.default_rng(0).normal(0.0, 2.0, shape)
    write_image(path, np.rint(black + noise).astype(np.uint16))
    dark = ("frames[0].file", "000-ambient.tiff", "the ambient image holds no light", "black level")
    assert_bad_input(*run(capsys, "estimate", str(sequence_copy), "--method", method), *dark, "to estimate")
    assert_bad_input(*run(capsys, "estimate", str(sequence_copy), "--method", method, "--json"), *dark)
    for mode, goal in (("matching", "to match"), ("complementary", "to complement")):
        assert_bad_input(*run(capsys, "flash", str(sequence_copy), "--mode", mode, "--method", method), *dark, goal)


# -- happy paths -------------------------------------------------------------------------------
def test_estimate_json(capsys, base_sequence: Path) -> None:
    status, out, err = run(capsys, "estimate", str(base_sequence), "--json")
    assert status == 0, err
    lines = out.splitlines()
    assert len(lines) == 1
    payload = json.loads(lines[0])
    assert len(payload["spectrum"]) == len(payload["wavelengths_nm"]) == 31
    assert len(payload["ambient_weights"]) == N_LEDS
    assert payload["wavelengths_nm"][0] == 400.0 and payload["wavelengths_nm"][-1] == 700.0
    assert max(payload["spectrum"]) > 0


def test_estimate_json_recovers_led_mix(capsys, mix_sequence: Path) -> None:
    # Energy units in the file: the spectrum comes back in energy, proportional to the LED mix's energy SPD.
    status, out, err = run(capsys, "estimate", str(mix_sequence), "--json", "--solver", "nonneg")
    assert status == 0, err
    payload = json.loads(out)
    np.testing.assert_allclose(payload["ambient_weights"], MIX, atol=QUANTISED)
    assert payload["spectral_unit"] == "energy"


def test_estimate_bayer_with_differing_gains(capsys, bayer_sequence: Path) -> None:
    status, out, err = run(capsys, "estimate", str(bayer_sequence), "--json", "--solver", "lstsq")
    assert status == 0, err
    np.testing.assert_allclose(json.loads(out)["ambient_weights"], MIX, atol=QUANTISED)


def test_estimate_text(capsys, base_sequence: Path) -> None:
    status, out, err = run(capsys, "estimate", str(base_sequence))
    assert status == 0, err
    assert "ambient weights:" in out and "700.0 nm" in out


@pytest.mark.parametrize("mode", ["complementary", "matching"])
def test_flash_json(capsys, base_sequence: Path, mode: str) -> None:
    status, out, err = run(capsys, "flash", str(base_sequence), "--mode", mode, "--json")
    assert status == 0, err
    payload = json.loads(out)
    assert payload["mode"] == mode
    assert len(payload["ambient_weights"]) == N_LEDS
    weights = np.array(payload["flash_weights"])
    assert weights.shape == (N_LEDS,)
    assert np.all((weights >= 0) & (weights <= 1))
    if mode == "complementary":
        assert payload["scale"] >= 0
    else:
        assert weights.max() == pytest.approx(1.0)


def test_synthesize_writes_a_readable_exr(capsys, base_sequence: Path, tmp_path: Path) -> None:
    out = tmp_path / "x.exr"
    status, stdout, err = run(
        capsys, "synthesize", str(base_sequence), "--weights", "0,0.5,0,1,0,0,0.25", "--out", str(out)
    )
    assert status == 0, err
    image = read_image(out)
    ambient = read_image(base_sequence / "frames" / "000-ambient.tiff")
    assert image.shape == ambient.shape
    assert np.all(np.isfinite(image)) and image.max() > 0
    zero = tmp_path / "zero.exr"
    assert (
        run(capsys, "synthesize", str(base_sequence), "--weights", ",".join(["0"] * N_LEDS), "--out", str(zero))[0] == 0
    )
    assert np.all(read_image(out) >= read_image(zero) - 1e-3 * read_image(zero).max())  # adding light only adds


def test_a_closed_stdout_pipe_ends_quietly(tmp_path: Path) -> None:
    """`msflash estimate SEQ | head -1`: no traceback when the reader goes away."""
    import subprocess
    import sys

    from tests.helpers import SAMPLES_DIR

    sequence = SAMPLES_DIR / "sample-rgb-tungsten"
    if not (sequence / "sequence.json").exists():
        pytest.skip(f"shared sample {sequence} is absent (CI puts shared/ beside the clone)")
    reader = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.readline()"], stdin=subprocess.PIPE)
    writer = subprocess.run(
        [sys.executable, "-m", "msflash.acquisition.app.cli", "estimate", str(sequence)],
        stdout=reader.stdin,
        stderr=subprocess.PIPE,
        text=True,
        timeout=120,
    )
    reader.stdin.close()
    reader.wait(timeout=10)
    assert "Traceback" not in writer.stderr
    assert writer.returncode in (0, 141)


@pytest.mark.parametrize("options", [["--method", "global"], ["--method", "local"], [], ["--model", "prior"]])
def test_every_estimate_route_reports_its_notes_through_one_place(
    capsys, base_sequence: Path, monkeypatch: pytest.MonkeyPatch, options: list[str]
) -> None:
    """The global, tiled and light-model routes report the flicker note and the payload's warnings through one
    ``one_sequence._reported`` (each wrote the same five lines before): once per estimate, each warning on stderr."""
    from msflash.acquisition.session import one_sequence

    calls = []
    real = one_sequence._reported

    def counted(*args):  # noqa: ANN002, ANN202 — the module's own reporter, counted
        calls.append(args)
        return real(*args)

    monkeypatch.setattr(one_sequence, "_reported", counted)
    assert main(["estimate", str(base_sequence), *options, "--json"]) == 0
    captured = capsys.readouterr()
    warnings = json.loads(captured.out)["warnings"]
    assert len(calls) == 1
    assert [line for line in captured.err.splitlines() if line.startswith("msflash: warning:")] == [
        f"msflash: warning: {warning}" for warning in warnings
    ]
