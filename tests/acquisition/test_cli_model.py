"""``msflash estimate --model led|prior|auto`` (docs/light-prior.md): the JSON says which model and why."""

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
    """CIE F2 under the paper's LEDs: the prior predicts held-out pixels better and comes closer to the truth
    (RMSE 0.083) than the LEDs' own estimate (0.137) and their bound (0.165); its band is the posterior."""
    rendered = render_case(Case("f2", light="F2", seed=3), tmp_path / "f2")
    led = _estimate(capsys, str(rendered.directory), "--model", "led")
    auto = _estimate(capsys, str(rendered.directory), "--model", "auto")
    prior = _estimate(capsys, str(rendered.directory), "--model", "prior")
    assert "model" not in led  # the default output is unchanged
    assert auto["model"] == "prior" and auto["model_choice"]["requested"] == "auto"
    held_out = auto["model_choice"]["held_out_relative_error"]
    assert held_out["prior"] < held_out["led"] * (1 - auto["model_choice"]["margin"])
    assert "predicts held-out pixels better" in auto["model_choice"]["reason"]
    np.testing.assert_allclose(auto["spectrum"], prior["spectrum"])
    np.testing.assert_allclose(auto["led"]["spectrum"], led["spectrum"])
    assert auto["band"].startswith("±1σ posterior") and len(auto["spectrum_std"]) == len(auto["spectrum"])
    assert prior["model"] == "prior" and prior["model_choice"]["requested"] == "prior"
    assert rmse(np.asarray(auto["spectrum"]), rendered.truth) < 0.7 * led_bound(rendered)


@pytest.mark.xfail(
    strict=True,
    reason=(
        "finding: under CIE F11 the held-out pixel errors of the two models are within 1 % (0.0205 and 0.0204, noise "
        "dominates), so auto keeps the LEDs (RMSE 0.434, bound 0.405) though the prior is far closer (0.181): held-out "
        "pixels cannot see what the camera cannot"
    ),
)
def test_auto_takes_the_prior_where_it_is_far_better(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rendered = render_case(Case("f11", light="F11", seed=3), tmp_path / "f11")
    assert _estimate(capsys, str(rendered.directory), "--model", "auto")["model"] == "prior"


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


def test_the_prior_needs_the_cameras_responsivities(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rendered = render_case(Case("nocam", light="A", seed=5), tmp_path / "nocam")
    document = json.loads((rendered.directory / "sequence.json").read_text())
    del document["camera"]["responsivity"]
    (rendered.directory / "sequence.json").write_text(json.dumps(document))
    assert main(["estimate", str(rendered.directory), "--model", "prior"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "responsivit" in err[0] and "Traceback" not in err[0]
