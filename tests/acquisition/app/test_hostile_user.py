"""A hostile user's pass over the command line and the Python API (branch hostile30): what a user types by
accident is refused with one line naming the option or file and what was expected (exit 2), never a
crash, silently other numbers or a lost capture. Each test failed before its fix; real files, ``main()``
in-process, no mocks."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from tests.helpers import SAMPLES_DIR


def _digests(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()
    }


def _one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("msflash: error: "), err
    return lines[0]


@pytest.mark.parametrize(
    ("command", "target"),
    [
        (["synthesize", "{seq}", "--weights", "1,0,0,0,0,0,0"], "frames/000-ambient.tiff"),
        (["flash", "{seq}", "--mode", "matching"], "frames/001-led.tiff"),
        (["synthesize", "{seq}", "--weights", "1,0,0,0,0,0,0"], "mix.exr"),
    ],
)
def test_an_image_written_into_the_sequence_folder_is_refused_and_no_frame_is_lost(
    sequence: Path, command: list[str], target: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--out SEQ/frames/000-ambient.tiff`` replaced the captured ambient frame by the synthesised image: the
    sequence's first frame was lost (``check`` then called it truncated). Refused before anything is written."""
    before = _digests(sequence)
    words = [word.replace("{seq}", str(sequence)) for word in command]
    assert main([*words, "--out", str(sequence / target)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"--out {sequence / target}" in line and "inside the sequence folder" in line
    assert _digests(sequence) == before
    assert main(["check", str(sequence)]) == 0


def test_an_image_beside_the_sequence_is_still_written(sequence: Path, tmp_path: Path) -> None:
    out = tmp_path / "beside.exr"
    assert main(["synthesize", str(sequence), "--weights", "1,0,0,0,0,0,0", "--out", str(out)]) == 0
    assert out.stat().st_size > 0


@pytest.mark.parametrize(
    "command",
    [["run"], ["capture"], ["calibrate", "camera", "--simulate"], ["study", "surfaces"], ["colour-study"]],
    ids=lambda words: " ".join(words),
)
def test_a_negative_seed_is_refused_naming_the_option(
    command: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--seed -1`` reached numpy's generator: ``run``/``capture`` exited 1 "rig 'sim': expected non-negative
    integer" (a device failure, naming neither the option), ``calibrate camera`` and ``study`` crashed."""
    out = tmp_path / "out"
    assert main([*command, "--seed", "-1", "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "--seed" in line and "expected a whole number ≥ 0" in line
    assert not out.exists()


@pytest.mark.parametrize(("patch", "border"), [("100000", "2"), ("8", "99999999999")])
def test_a_chart_layout_far_larger_than_the_image_is_refused_before_it_is_drawn(
    sequence: Path, patch: str, border: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``evaluate --patch-px 100000`` drew the chart's label map (894 GiB) before checking that it fits the image:
    "unexpected MemoryError — a bug"."""
    words = ["evaluate", str(sequence), "--chart", "macbeth", "--patch-px", patch, "--border-px", border]
    assert main([*words, "--out", str(tmp_path / "eval")]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"--patch-px {patch} --border-px {border}: the macbeth chart is" in line and "but the image is" in line


@pytest.mark.parametrize("patch", ["100000", "7", "0"])
def test_colour_study_refuses_a_patch_side_it_cannot_render_or_measure(
    patch: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``colour-study --patch-px 100000`` crashed (MemoryError drawing the chart); 7 or less with ``--cfa`` was
    refused late, naming a ``--margin-px`` the command does not have."""
    assert main(["colour-study", "--patch-px", patch, "--ambients", "green", "--cfa", "RGGB", "--json"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"argument --patch-px: '{patch}': expected a whole number of pixels, 8-256" in line


@pytest.fixture(scope="module")
def read_back(base_sequence: Path):  # type: ignore[no-untyped-def]
    import msflash

    return msflash.read_sequence(base_sequence)


@pytest.mark.parametrize(
    ("options", "named"),
    [
        ({"bin_factor": 0}, "bin_factor (--bin) 0: expected a whole number ≥ 1"),
        ({"bin_factor": -1}, "bin_factor (--bin) -1"),
        ({"bin_factor": 1.5}, "bin_factor (--bin) 1.5"),
        ({"bin_factor": True}, "bin_factor (--bin) True"),
        ({"bin_factor": "4"}, "bin_factor (--bin) '4'"),
        ({"method": "local", "tiles": 0}, "tiles (--tiles) 0: expected a whole number ≥ 1"),
        ({"method": "local", "tiles": (2, 3)}, "tiles (--tiles) (2, 3)"),
        ({"solver": "tikonov"}, "solver (--solver) 'tikonov': unknown; did you mean 'tikhonov'?"),
        ({"alpha": None}, "alpha (--alpha) None: expected a finite number ≥ 0 or 'auto'"),
        ({"alpha": True}, "alpha (--alpha) True"),
        ({"model": "LED"}, "model (--model) 'LED': unknown; did you mean 'led'?"),
    ],
)
def test_estimate_ambient_refuses_what_the_command_line_refuses(read_back, options: dict, named: str) -> None:  # type: ignore[no-untyped-def]
    """The API passed its arguments on unchecked: ``bin_factor=0``/``-1``/``1.5``/``True`` and ``tiles=0`` were
    taken as other numbers silently, ``"4"``, ``(2, 3)`` and ``alpha=None`` failed with a TypeError, a solver's
    name with a plain ValueError, and ``model="LED"`` was called an unknown *method*."""
    import msflash
    from msflash.acquisition.errors import UsageError

    with pytest.raises(UsageError) as caught:
        msflash.estimate_ambient(read_back, **options)
    assert named in str(caught.value)


@pytest.mark.parametrize(
    ("name", "option", "typed", "passed"),
    [("bin_factor", "--bin", "0", 0), ("tiles", "--tiles", "1.5", 1.5), ("alpha", "--alpha", "nan", float("nan"))],
)
def test_the_command_line_and_the_api_apply_one_rule_per_setting(  # type: ignore[no-untyped-def]
    read_back, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, name, option, typed, passed
) -> None:
    """Issue 31: each setting's rule is stated once (``one_sequence.SETTING_RULES``): the command line's exit-2 line
    names the option, the API's UsageError the parameter and its option, and both say what the one rule expects —
    a rule changed in that one place changes both."""
    from dataclasses import replace

    import msflash
    from msflash.acquisition.errors import UsageError
    from msflash.acquisition.session import one_sequence

    rule = one_sequence.SETTING_RULES[name]
    monkeypatch.setitem(one_sequence.SETTING_RULES, name, replace(rule, expected=f"{rule.expected} (the one rule)"))
    assert main(["estimate", str(read_back.directory), option, typed]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert line.endswith(f"argument {option}: '{typed}': expected {rule.expected} (the one rule)"), line
    with pytest.raises(UsageError) as caught:
        msflash.estimate_ambient(read_back, **{name: passed})
    assert str(caught.value) == f"{name} ({option}) {passed!r}: expected {rule.expected} (the one rule)"


@pytest.mark.parametrize(
    ("call", "named"),
    [
        (lambda m, seq, est: m.estimate_ambient(str(seq.directory)), "msflash.estimate_ambient: sequence is str"),
        (lambda m, seq, est: m.solve_flash(seq, None), "msflash.solve_flash: estimate is NoneType None"),
        (lambda m, seq, est: m.solve_flash(seq, est, "complementary", None), "msflash.solve_flash: target is NoneType"),
        (lambda m, seq, est: m.synthesize_flash(str(seq.directory), [0] * 7), "msflash.synthesize_flash: sequence"),
        (lambda m, seq, est: m.render_preview(seq, None), "msflash.render_preview: image is NoneType None"),
        (lambda m, seq, est: m.synthesize_flash(seq, None), "msflash.synthesize_flash: flash is NoneType None"),
    ],
    ids=["path-for-sequence", "no-estimate", "no-target", "path-to-synthesize", "no-image", "no-flash"],
)
def test_the_python_api_names_a_wrong_argument(read_back, call, named: str) -> None:  # type: ignore[no-untyped-def]
    """A path where a sequence belongs, None for the estimate, target or image: AttributeError or TypeError from
    deep inside, naming neither the function nor the parameter."""
    import msflash
    from msflash.acquisition.errors import UsageError

    estimate = msflash.estimate_ambient(read_back)
    with pytest.raises(UsageError) as caught:
        call(msflash, read_back, estimate)
    assert named in str(caught.value) and "\n" not in str(caught.value)


def test_render_preview_refuses_non_finite_pixels(read_back) -> None:  # type: ignore[no-untyped-def]
    """NaN pixels were cast to uint8 under a RuntimeWarning: a preview of arbitrary bytes."""
    import numpy as np

    import msflash
    from msflash.acquisition.errors import UsageError

    image = np.ones(read_back.load_frame(0).shape)
    image.flat[0] = np.nan
    with pytest.raises(UsageError, match=r"image holds 1 NaN or infinite values of \d+; expected finite"):
        msflash.render_preview(read_back, image)


def test_a_bin_halved_to_fit_a_small_frame_stays_even_and_not_below_four(
    sequence: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--bin 6`` on a frame too small for 32 six-pixel blocks was halved to 3 — below the 4 ``--help`` promises,
    and odd, so the estimate lost its noise probe (``noise_correction: none``) and moved: other numbers than the
    4 it should have fallen back to. (``--bin 1000`` ended at 3 too.)"""
    import json

    outputs = {}
    for factor in ("4", "6", "1000"):
        assert main(["estimate", str(sequence), "--bin", factor, "--json"]) == 0
        outputs[factor] = json.loads(capsys.readouterr().out)
    assert outputs["6"]["noise_correction"] == outputs["4"]["noise_correction"]
    assert not outputs["4"]["noise_correction"].startswith("none")
    for factor in ("6", "1000"):
        assert outputs[factor]["spectrum"] == outputs["4"]["spectrum"]


@pytest.mark.parametrize(
    ("option", "value", "expected"),
    [("--max-saturated", "101", "0 ≤ PERCENT < 50"), ("--max-lost", "200", "0 ≤ PERCENT < 100")],
)
def test_a_percentage_out_of_range_is_refused_in_percent(
    option: str, value: str, expected: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--max-saturated 101`` (a percentage) was refused as "max_saturated_fraction 1.01; expected 0 ≤ f < 0.5":
    the range in a unit the user never typed. Now refused when parsed, nothing made."""
    out = tmp_path / "run"
    assert main(["run", option, value, "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"argument {option}: '{value}': expected a percentage, {expected}" in line
    assert not out.exists()


@pytest.fixture(params=["sample-rgb-tungsten", "sample-bayer-fluorescent-12bit"])
def sample(request: pytest.FixtureRequest, tmp_path: Path) -> Path:
    """A copy of one of the two sequences written by an independent tool (no digests: nothing guards the frames)."""
    copy = tmp_path / request.param
    shutil.copytree(SAMPLES_DIR / request.param, copy)
    return copy


def test_a_frame_re_encoded_as_normalised_float_is_refused(sample: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Frame 3 of a 16-bit sequence re-saved as float32 divided by 4095 (an image tool's "normalise"): on the RGB
    sample, whose black level is 0, every value stayed in range and ``estimate`` exited 0 with that LED's frame
    4095 times too dark — other numbers, no word. A sample type other than frame 0's is refused, naming both."""
    import numpy as np
    import tifffile

    frame = sample / "frames" / "003-led.tiff"
    pixels = tifffile.imread(frame)
    photometric = "rgb" if pixels.ndim == 3 else "minisblack"
    tifffile.imwrite(frame, pixels.astype(np.float32) / 4095, photometric=photometric)
    assert main(["estimate", str(sample), "--json"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "frames[3].file 'frames/003-led.tiff' holds float32 samples but frames[0].file" in line
    assert "holds uint16; expected one sample type for all frames" in line


def test_wavelengths_in_micrometres_are_refused(sample: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``wavelengths_nm`` written in µm (0.4–0.7): read as nanometres, estimated, printed as "0.4 nm" lines with a
    warning that the estimate came out 4.6e10 times its LED bound — exit 0."""
    import json

    document = json.loads((sample / "sequence.json").read_text())
    document["wavelengths_nm"] = [w / 1000 for w in document["wavelengths_nm"]]
    (sample / "sequence.json").write_text(json.dumps(document))
    assert main(["estimate", str(sample), "--json"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "wavelengths_nm spans 0.4–0.7; expected nanometres within 100–3000" in line


def test_a_signal_inside_finish_after_the_file_says_complete_is_reported_as_complete(tmp_path: Path) -> None:
    """SIGTERM 2.3 s into ``msflash run --sync booth`` printed "frames captured so far are kept (marked incomplete)"
    while its ``sequence.json`` said ``complete: true`` with all 9 frames: the signal came inside
    ``SequenceWriter.finish`` after the file was replaced and before the writer noted it. The signal is delivered
    here at that very point (a trace function raising KeyboardInterrupt as ``_replace_json`` returns, as Python
    raises it at the next bytecode); the stop line must say what the disk says."""
    import json
    import sys

    import numpy as np

    from msflash.acquisition.app.cli import _stop_line
    from msflash.acquisition.sequence import writer as writer_module
    from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed

    camera = SequenceCamera(model="t", serial=None, pixel_format="RGB16", cfa=None, black_level=0, white_level=65535)
    leds = [SequenceLed("led", np.ones(3))]
    writer_module.forget_latest_sequence()
    writer = writer_module.SequenceWriter(
        tmp_path / "seq",
        wavelengths_nm=np.array([400.0, 500.0, 600.0]),
        spectral_unit="energy",
        camera=camera,
        leds=leds,
    )
    writer.add_frame(np.full((8, 8, 3), 100, np.uint16), "ambient", [0.0], exposure_us=1000.0, gain=1.0)

    def tracer(frame, event, arg):  # type: ignore[no-untyped-def]
        if event == "call" and frame.f_code is writer_module._replace_json.__code__:
            return local
        return None

    def local(frame, event, arg):  # type: ignore[no-untyped-def]
        if event == "return":
            raise KeyboardInterrupt
        return local

    sys.settrace(tracer)
    try:
        with pytest.raises(KeyboardInterrupt):
            writer.finish()
    finally:
        sys.settrace(None)
    assert json.loads((tmp_path / "seq" / "sequence.json").read_text())["complete"] is True
    assert writer_module.latest_sequence_written() == (tmp_path / "seq", True)
    assert "was complete before the stop and stays so" in _stop_line(["run"], "terminated (SIGTERM)")
    writer_module.forget_latest_sequence()


def test_a_replay_refused_before_its_first_frame_leaves_no_empty_run_behind(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Replaying an interrupted recording (complete: false, 2 frames) exited 1 naming the step, as it should, but
    left ``OUT/sequence/sequence.json`` with no frame: the next attempt into the same ``--out`` was refused as
    "already holds a run", and nothing had been captured. A sequence that never got a frame is removed, and with
    it the ``--out`` the command made."""
    import json

    recording = tmp_path / "interrupted"
    shutil.copytree(Path(__file__).parents[2] / "data" / "sequences" / "sim-macbeth-fluorescent", recording)
    document = json.loads((recording / "sequence.json").read_text())
    document.update(complete=False, frames=document["frames"][:2])
    (recording / "sequence.json").write_text(json.dumps(document))
    out = tmp_path / "replayed"
    exposure = str(document["frames"][0]["exposure_us"])  # fixed: the plan is checked once the sequence is begun
    assert main(["capture", "--rig", f"replay:{recording}", "--exposure-us", exposure, "--out", str(out)]) == 1
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("msflash: error: ")]
    assert len(errors) == 1 and "the recording is incomplete" in errors[0]
    assert not out.exists()


@pytest.mark.parametrize(
    ("option", "value"), [("--height", "0"), ("--width", "-1"), ("--height", "32"), ("--repeats", "0")]
)
def test_bench_names_a_frame_size_or_repeat_count_it_cannot_measure(
    option: str, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``bench --height 0`` was refused naming the simulated scene's label array, ``--width -1`` as a width of 0,
    ``--height 32`` as "channel statistics: 4×4 blocks of 8×8", after seconds of setup; none named the option."""
    assert main(["bench", "--part", "processing", "--quick", option, value]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert line.startswith(f"msflash: error: argument {option}: '{value}': expected a whole number")


@pytest.mark.parametrize(
    ("words", "expected"),
    [
        (["pareto", "--patch-px", "100000"], "argument --patch-px: '100000': expected a whole number of pixels, 1-256"),
        (["failure", "--threshold", "nan"], "argument --threshold: 'nan': expected a finite RMSE ≥ 0"),
        (["failure", "--threshold", "-1"], "argument --threshold: '-1': expected a finite RMSE ≥ 0"),
        (["pareto", "--ambient-to-flash", "-1"], "argument --ambient-to-flash: '-1': expected a finite ratio > 0"),
    ],
)
def test_study_options_out_of_range_are_refused_when_parsed(
    words: list[str], expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``study pareto --patch-px 100000`` crashed (MemoryError drawing a 4 TiB chart); ``study failure --threshold
    nan`` (or -1) exited 0 with a confusion table that counted no estimate (or every one) as failed."""
    assert main(["study", *words, "--json"]) == 2
    assert expected in _one_error_line(capsys.readouterr().err)


@pytest.mark.parametrize(
    ("name", "text", "said"),
    [
        ("missing.csv", None, "target illuminant file not found"),
        ("dark.csv", "wavelength_nm,value\n400,0\n700,0\n", "no light"),
    ],
)
def test_run_reads_a_target_file_before_the_rig_opens(
    name: str, text: str | None, said: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``run --target missing.csv`` (or an all-zero file) opened the rig, metered the ambient with the LEDs firing
    and only then refused the file. It is now read when the command line is parsed (its coverage of the camera's
    range still when used); nothing opened, nothing made."""
    target = tmp_path / name
    if text is not None:
        target.write_text(text)
    out = tmp_path / "run"
    assert main(["run", "--target", str(target), "--out", str(out), "--log-serial", str(tmp_path / "serial.log")]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert line.startswith("msflash: error: argument --target: ") and said in line
    assert line.count("--target") == 1, line  # argparse names the option; the message did again
    assert not out.exists() and not (tmp_path / "serial.log").exists()


def test_the_measured_led_snr_takes_each_frames_gain(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Replaying the independent Bayer sample (ambient at gain 1.5, most LED frames at gain 1) warned "no LED signal:
    its frame is no brighter than the ambient frame" for three of its seven LEDs: the measured SNR divided each
    frame by its exposure but not its gain. Every LED of the sample is lit and its estimate tracks the truth."""
    sample = SAMPLES_DIR / "sample-bayer-fluorescent-12bit"
    assert main(["capture", "--rig", f"replay:{sample}", "--out", str(tmp_path / "replayed")]) == 0
    err = capsys.readouterr().err
    assert "no LED signal" not in err and "no signal" not in err, err


@pytest.mark.parametrize("marker", ["run.json", "sequence.json"])
def test_evaluate_refuses_to_write_over_a_run_or_a_sequence(
    sequence: Path, marker: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``evaluate RUN --chart macbeth --out RUN`` wrote the evaluation's report.html, matching.exr, ambient.png …
    over the run's own (exit 0): the run's report was gone."""
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / marker).write_text("{}")
    (folder / "report.html").write_text("the run's report")
    assert main(["evaluate", str(sequence), "--chart", "macbeth", "--out", str(folder)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"--out {folder}: holds a" in line and f"({marker})" in line
    assert (folder / "report.html").read_text() == "the run's report"
    assert sorted(p.name for p in folder.iterdir()) == sorted([marker, "report.html"])


@pytest.mark.parametrize("kept", [5, 7])
def test_an_interrupted_sequence_names_the_leds_it_never_captured(
    tmp_path: Path, kept: int, capsys: pytest.CaptureFixture[str]
) -> None:
    """The independent RGB sample cut after ``kept`` frames and marked incomplete, as an interrupted capture leaves
    it: ``estimate`` refused it with the solve's "rank 4 < 7 LEDs"; it now names the LEDs without a frame."""
    import json

    sequence = tmp_path / "cut"
    shutil.copytree(SAMPLES_DIR / "sample-rgb-tungsten", sequence)
    document = json.loads((sequence / "sequence.json").read_text())
    names = [led["name"] for led in document["leds"]]
    document["complete"] = False
    document["frames"] = document["frames"][:kept]
    (sequence / "sequence.json").write_text(json.dumps(document))
    assert main(["estimate", str(sequence)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    never = names[kept - 1 :]
    assert ("LEDs " if len(never) > 1 else "LED ") + ", ".join(never) in line
    assert "incomplete" in line and "rank" not in line


@pytest.mark.parametrize("where", ["file/runs", "proc"])
def test_live_refuses_a_runs_folder_it_cannot_make_before_serving(
    tmp_path: Path, where: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``live --runs /proc/x`` (or a path under a file) served the page and failed only when a sequence was fired.
    Refused before any socket or device is opened; a folder the check makes to find out is removed again."""
    (tmp_path / "file").write_text("not a folder")
    runs = tmp_path / "file" / "runs" if where == "file/runs" else Path("/proc/msflash-runs")
    assert main(["live", "--rig", "sim", "--port", "0", "--runs", str(runs)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"--runs {runs}: cannot make the folder" in line


def test_live_leaves_no_runs_folder_behind_when_it_only_checked(tmp_path: Path) -> None:
    """The check makes the folder (and its parents) and removes what it made: nothing left until a run is fired."""
    from msflash.acquisition.app.cli_common import check_folder_can_be_made

    runs = tmp_path / "a" / "b" / "runs"
    check_folder_can_be_made(runs, "--runs")
    assert list(tmp_path.iterdir()) == []
