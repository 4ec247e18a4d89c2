"""``msflash estimate --model led|prior|family|auto`` (docs/light-prior.md, docs/light-families.md): the JSON says
which model and why."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from tests.processing.unseen_sequences import Case, led_bound, render_case, rmse


def _estimate(capsys: pytest.CaptureFixture[str], *args: str) -> dict:
    assert main(["estimate", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_auto_says_which_model_it_chose_and_why(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """CIE F2 under the paper's LEDs: a family predicts held-out pixels better than the LEDs' span and comes far
    closer to the truth than the LEDs' own estimate and their bound; the JSON names it, its parameters and the
    evidence."""
    rendered = render_case(Case("f2", light="F2", seed=3), tmp_path / "f2")
    led = _estimate(capsys, str(rendered.directory), "--model", "led")
    auto = _estimate(capsys, str(rendered.directory), "--model", "auto")
    family = _estimate(capsys, str(rendered.directory), "--model", "family")
    prior = _estimate(capsys, str(rendered.directory), "--model", "prior")
    assert "model" not in led  # the default output is unchanged
    assert auto["model"] != "led" and auto["model_choice"]["requested"] == "auto"
    assert auto["model"] == auto["family"]["form"] == family["model"]
    held_out = auto["model_choice"]["held_out_relative_error_noise_removed"]
    assert held_out[auto["model"]] < held_out["led"] * (1 - auto["model_choice"]["margin"])
    choice = auto["model_choice"]  # and the gain is beyond the noise correction's share (light_families.choose)
    assert (
        held_out[auto["model"]] ** 2 + choice["noise_margin"] * choice["noise_share"]
        < (held_out["led"] * (1 - choice["margin"])) ** 2
    )
    assert "predicts held-out pixels better" in auto["model_choice"]["reason"]
    block = auto["family"]
    assert block["family"] in ("thermal", "discharge", "solid_state", "transmitted", "mixture", "prior")
    assert block["parameters"] and all(isinstance(v, float) for v in block["parameters"].values())
    evidence = block["evidence"]
    assert evidence["led"]["model"] == "led" and len(evidence["candidates"]) > 10
    assert {c["family"] for c in evidence["candidates"]} >= {"thermal", "discharge", "solid_state", "transmitted"}
    np.testing.assert_allclose(auto["spectrum"], family["spectrum"])
    np.testing.assert_allclose(auto["led"]["spectrum"], led["spectrum"])
    assert auto["band"].startswith("±1σ of the fitted family") and len(auto["spectrum_std"]) == len(auto["spectrum"])
    assert prior["model"] == "prior" and prior["model_choice"]["requested"] == "prior"
    assert rmse(np.asarray(auto["spectrum"]), rendered.truth) < 0.7 * led_bound(rendered)


def test_a_narrow_band_fluorescent_is_read_as_a_discharge(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """CIE F11 (the rare-earth tri-phosphor lines): issue 17's finding was that the held-out pixels of the LEDs'
    span and the light prior were within 1 %, so auto kept the LEDs (RMSE 0.434, bound 0.405). The discharge
    family — lines at their known wavelengths — predicts them better, and its spectrum is far closer."""
    rendered = render_case(Case("f11", light="F11", seed=3), tmp_path / "f11")
    auto = _estimate(capsys, str(rendered.directory), "--model", "auto")
    assert auto["model"].startswith("discharge/"), auto["model_choice"]
    names = auto["family"]["parameters"]
    assert any("Tb³⁺" in name for name in names) and any("Eu³⁺" in name for name in names)
    assert rmse(np.asarray(auto["spectrum"]), rendered.truth) < 0.5 * led_bound(rendered)


def test_a_tungsten_lamp_is_read_as_a_blackbody_of_its_temperature(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rendered = render_case(Case("a", light="A", seed=3), tmp_path / "a")
    family = _estimate(capsys, str(rendered.directory), "--model", "family")
    assert family["model"] == "thermal/blackbody", family["model_choice"]
    assert family["family"]["parameters"]["kelvin"] == pytest.approx(2856.0, rel=0.02)


def test_auto_keeps_the_leds_where_they_span_the_ambient(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An ambient that is a mix of the LEDs themselves: both models predict alike, so auto keeps the LEDs."""
    from tests.processing import unseen_sequences

    mix = np.array([0.2, 0.5, 0.1, 0.8, 0.3, 0.6, 0.4])
    original = unseen_sequences.light_energy

    def light_energy(name: str, wavelengths: np.ndarray) -> np.ndarray:
        if name == "ledmix":
            return unseen_sequences.paper_leds_energy(wavelengths)[1] @ mix
        return original(name, wavelengths)

    unseen_sequences.light_energy = light_energy
    try:
        rendered = render_case(Case("mix", light="ledmix", seed=4), tmp_path / "mix")
    finally:
        unseen_sequences.light_energy = original
    auto = _estimate(capsys, str(rendered.directory), "--model", "auto")
    assert auto["model"] == "led", auto["model_choice"]
    assert "led" not in auto or auto["led"] is None


@pytest.mark.parametrize("model", ["prior", "family", "auto"])
def test_the_models_beyond_the_leds_need_the_cameras_responsivities(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], model: str
) -> None:
    rendered = render_case(Case("nocam", light="A", seed=5), tmp_path / "nocam")
    document = json.loads((rendered.directory / "sequence.json").read_text())
    del document["camera"]["responsivity"]
    (rendered.directory / "sequence.json").write_text(json.dumps(document))
    assert main(["estimate", str(rendered.directory), "--model", model]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "responsivit" in err[0] and "Traceback" not in err[0]


def test_every_model_is_checked_against_the_family_evidence(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``models`` holds each model as its own ``--model`` prints it, with its miss check (predicted ratio to the LED
    bound): what the harness's prior, family and led-checked rows read from one ``--model auto`` run."""
    rendered = render_case(Case("d50", light="D50", seed=6), tmp_path / "d50")
    auto = _estimate(capsys, str(rendered.directory), "--model", "auto")
    family = _estimate(capsys, str(rendered.directory), "--model", "family")
    prior = _estimate(capsys, str(rendered.directory), "--model", "prior")
    models = auto["models"]
    assert set(models) == {"led", "prior", "family"}
    np.testing.assert_allclose(models["family"]["spectrum"], family["spectrum"])
    np.testing.assert_allclose(models["family"]["spectrum_std"], family["spectrum_std"])
    np.testing.assert_allclose(models["prior"]["spectrum"], prior["spectrum"])
    assert models["prior"]["warnings"] == prior["warnings"]
    for block in models.values():
        check = block["miss_check"]
        assert check["predicted_ratio_to_led_bound"] >= 0 and check["threshold"] > 0
        assert check["warned"] == (check["predicted_ratio_to_led_bound"] >= check["threshold"])
        assert check["warned"] == any("may be off by more than" in w for w in block["warnings"])
        assert len(block["spectrum_std"]) == len(block["spectrum"])


def test_a_reference_patch_joins_the_evidence(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from tests.harness.physics_cases import physics_cases_of
    from tests.harness.render import REFERENCE_PATCH_FILE, render

    truth = render(physics_cases_of("tuning")[5], tmp_path / "scene")
    rect = ",".join(str(v) for v in json.loads((truth.directory / REFERENCE_PATCH_FILE).read_text()))
    auto = _estimate(capsys, str(truth.directory), "--model", "auto", "--reference-patch", rect)
    evidence = auto["family"]["evidence"]
    assert 0 <= evidence["led"]["reference_patch_relative_error"] < 0.1
    assert all(c["reference_patch_relative_error"] is not None for c in evidence["candidates"])
    for arguments in (["--reference-patch", "150,120,40,40"], ["--reference-patch", "1,2,3"]):
        assert main(["estimate", str(truth.directory), "--model", "auto", *arguments]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--reference-patch" in err[0] and "Traceback" not in err[0]
    assert main(["estimate", str(truth.directory), "--reference-patch", rect]) == 2
    assert "--model prior, family or auto" in capsys.readouterr().err


def test_a_reference_chart_holds_the_estimate_to_known_reflectances(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The harness's scene with a chart of its own surfaces: every patch's LED images are explained by its given
    reflectance (the rectangles land on the right surfaces), and the chart's equations join the evidence."""
    from tests.harness.physics_cases import physics_cases_of
    from tests.harness.render import REFERENCE_CHART_FILE, render

    case = next(c for c in physics_cases_of("tuning") if c.specular and c.cfa is not None)
    truth = render(case, tmp_path / "scene")
    chart = truth.directory / REFERENCE_CHART_FILE
    auto = _estimate(capsys, str(truth.directory), "--model", "family", "--reference-chart", str(chart))
    reference = auto["family"]["reference"]
    patches = len(json.loads(chart.read_text())["patches"])
    assert reference["equations"] == 4 * patches and reference["led_misfit"] < 0.2
    assert all(c["reference_patch_relative_error"] is not None for c in auto["family"]["evidence"]["candidates"])
    document = json.loads(chart.read_text())  # the reflectances handed to the wrong patches
    reflectances = [p["reflectance"] for p in document["patches"]]
    for patch, reflectance in zip(document["patches"], reflectances[1:] + reflectances[:1]):
        patch["reflectance"] = reflectance
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps(document))
    misplaced = _estimate(capsys, str(truth.directory), "--model", "family", "--reference-chart", str(wrong))
    assert misplaced["family"]["reference"]["led_misfit"] > 2 * reference["led_misfit"]
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps({"patches": [{"rect": [0, 0, 16, 16], "wavelengths_nm": [400, 700]}]}))
    assert main(["estimate", str(truth.directory), "--model", "auto", "--reference-chart", str(broken)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "patches[0]" in err[0] and "reflectance" in err[0]


def _light_model_case(name: str, directory: Path) -> tuple[Path, list[str]]:
    """A sequence of the light models' cases and the ``estimate`` options it is read with."""
    if name == "mono":  # the sim's Mono12 camera: one plane, recorded as three alike channels
        assert main(["capture", "--rig", "sim", "--cfa", "mono", "--seed", "3", "--out", str(directory)]) == 0
        return directory / "sequence", []
    cases = {
        "rgb": (Case("a", light="A", seed=5), []),
        "raw": (Case("a", light="A", seed=5, cfa="GRBG"), []),
        "bin 1": (Case("a", light="A", seed=5), ["--bin", "1"]),
        # 400 × 440: --bin 4 gives the estimate 4 × 4 blocks, the light models keep the default 8 × 8
        "bin 4": (Case("a", light="A", seed=5, patch_px=40), ["--bin", "4"]),
        "local": (Case("a", light="A", seed=5, cfa="RGGB"), ["--method", "local", "--tiles", "2"]),
    }
    case, options = cases[name]
    return render_case(case, directory).directory, options


REFERENCES = {
    "patch": (["--reference-patch", "16,16,24,24"], 24),
    "chart": (["--reference-chart", "CHART"], 20),
}
"""A reference of the light models' cases (inside their 80 × 88 and 106 × 112 frames) and its largest crop's side."""


def _reference_options(reference: str | None, directory: Path) -> tuple[list[str], int]:
    """The options of ``reference`` (a chart written beside the sequence) and its crops' largest side (0: none)."""
    if reference is None:
        return [], 0
    options, side = REFERENCES[reference]
    if reference == "chart":
        chart = directory.parent / "chart.json"
        patches = [[4, 4, 16, 16], [40, 30, 20, 18]]
        document = {"patches": [{"rect": r, "wavelengths_nm": [400, 700], "reflectance": [0.6, 0.4]} for r in patches]}
        chart.write_text(json.dumps(document))
        options = [options[0], str(chart)]
    return options, side


@pytest.mark.parametrize("strided", [False, True])
@pytest.mark.parametrize(
    ("case", "model", "reference"),
    [("rgb", "prior", None), ("rgb", "family", None), ("rgb", "auto", None), ("raw", "auto", None)]
    + [("mono", "family", None), ("bin 1", "prior", None), ("bin 4", "family", None), ("local", "auto", None)]
    + [("rgb", "family", "patch"), ("raw", "auto", "chart"), ("mono", "prior", "patch"), ("local", "auto", "chart")],
)
def test_the_light_models_pass_over_each_frame_once(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    case: str,
    model: str,
    reference: str | None,
    strided: bool,
) -> None:
    """Issue 31: ``--model prior|family|auto`` take the channel statistics from the LED estimate's stream (its block
    rows), so each frame is decoded once and never passed over by the channel statistics' own pass — for an RGB,
    a raw and a mono camera, the all-pixel reference (``--bin 1``), another block size and the local method; also
    where the frames are large enough for the LED estimate to probe every few block rows (``strided``, forced). The
    statistics are the frames' own pass's (to the bit; a mono plane replicated, to rounding). With a reference patch
    or chart, no frame stack is built either (main loaded one to crop it): the crops are taken as the frames pass,
    and the channel statistics' own pass sees only them."""
    from msflash.acquisition.sequence.format import Sequence
    from msflash.acquisition.sequence.reader import read_sequence
    from msflash.acquisition.session import analysis
    from msflash.acquisition.session.analysis import block_factor, load_frame_stack
    from msflash.acquisition.session.prior_route import sequence_channel_statistics
    from msflash.processing import block_rows, channel_statistics

    if strided:
        monkeypatch.setattr(block_rows, "PROBE_BLOCKS", 64)
    directory, options = _light_model_case(case, tmp_path / "case")
    reference_options, crop_side = _reference_options(reference, directory)
    capsys.readouterr()
    decoded: list[int] = []
    frames_pass: list[tuple[int, ...]] = []
    stacks: list[int] = []
    real_load, real_pass, real_stack = Sequence.load_frame, channel_statistics._stacked_block_rows, analysis.frame_stack

    def counted_load(self: Sequence, index: int) -> np.ndarray:  # the one reader of a sequence's frames
        decoded.append(index)
        return real_load(self, index)

    def counted_pass(frames: list[np.ndarray], *args: object) -> object:
        frames_pass.extend(frame.shape for frame in frames)
        return real_pass(frames, *args)  # type: ignore[arg-type]

    def counted_stack(layout, pixels):  # noqa: ANN001, ANN202 — every FrameStack is built here
        stacks.append(len(layout.led_indices) + 1)
        return real_stack(layout, pixels)

    monkeypatch.setattr(Sequence, "load_frame", counted_load)
    monkeypatch.setattr(channel_statistics, "_stacked_block_rows", counted_pass)
    monkeypatch.setattr(analysis, "frame_stack", counted_stack)
    _estimate(capsys, str(directory), "--model", model, *options, *reference_options)
    sequence = read_sequence(directory)
    used = [index for index, entry in enumerate(sequence.frames) if entry.role in ("ambient", "led")]
    assert sorted(decoded) == used and stacks == []
    assert all(max(shape[:2]) <= crop_side for shape in frames_pass), frames_pass  # crops only, if any
    assert bool(frames_pass) == (reference is not None)
    monkeypatch.undo()
    stack = load_frame_stack(sequence)
    frames_own = channel_statistics.accumulate_channel_statistics(
        stack.ambient,
        stack.led_frames,
        stack.spec,
        cfa=sequence.camera.cfa,
        bin_factor=block_factor(stack.ambient.shape, sequence.camera.cfa),
    )
    taken = sequence_channel_statistics(sequence, stack)
    assert taken.channels == frames_own.channels and np.array_equal(taken.counts, frames_own.counts)
    for name in ("ff", "fa", "aa"):
        ours, theirs = getattr(taken.moments, name), getattr(frames_own.moments, name)
        if case == "mono":
            np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12 * np.abs(theirs).max())
        else:
            assert np.array_equal(ours, theirs), name


@pytest.mark.parametrize("model", ["prior", "family", "auto"])
def test_the_light_models_read_the_channel_statistics_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, model: str
) -> None:
    """``--model prior`` fits the light prior and checks it against the family evidence; both read one set of
    channel statistics (one pass over the frames for the two, as ``family|auto`` do), and print what they did."""
    from msflash.acquisition.session import prior_route

    rendered = render_case(Case("a", light="A", seed=5), tmp_path / "a")
    before = _estimate(capsys, str(rendered.directory), "--model", model)
    taken = []
    counted = prior_route.sequence_channel_statistics

    def counting(*args: object, **kwargs: object) -> object:
        taken.append(args)
        return counted(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(prior_route, "sequence_channel_statistics", counting)
    after = _estimate(capsys, str(rendered.directory), "--model", model)
    assert len(taken) == 1
    assert after == before
