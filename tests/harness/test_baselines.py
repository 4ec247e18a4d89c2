"""The baselines: the authors' estimator (cvxpy port) and plain least squares, on data whose answer is known."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.harness import baselines
from tests.harness.metrics import rmse
from tests.harness.render import HarnessCase, render

WEIGHTS = (0.3, 0.0, 0.8, 0.5, 0.2)
NOISE_FREE = HarnessCase(
    "noise-free",
    "tuning",
    5,
    "Canon 5DMarkII",
    "leds:" + ",".join(map(str, WEIGHTS)),
    "model",
    leds="paper5",
    full_well_e=float("inf"),
    ratio=1.0,
    n_surfaces=30,
)


def _leds(wavelengths: np.ndarray) -> np.ndarray:
    return np.column_stack([np.exp(-0.5 * ((wavelengths - p) / 15) ** 2) for p in (450, 520, 590, 650)])


def test_authors_weights_are_exact_on_noise_free_pixels_without_roughness() -> None:
    rng = np.random.default_rng(0)
    led_only = rng.uniform(0.0, 1.0, (4, 200, 3))
    weights = np.array([0.4, 1.2, 0.1, 0.7])
    ambient = np.tensordot(weights, led_only, axes=1)
    spectra = _leds(np.arange(400, 701, 10.0))
    assert np.allclose(baselines.authors_weights(ambient, led_only, spectra, alpha=0.0), weights, atol=1e-6)


def test_authors_roughness_term_smooths_and_keeps_the_spectrum_non_negative() -> None:
    rng = np.random.default_rng(1)
    led_only = rng.uniform(0.0, 1.0, (4, 50, 3))
    ambient = np.tensordot([0.1, 1.0, 0.0, 0.6], led_only, axes=1) + rng.normal(0, 0.05, (50, 3))
    spectra = _leds(np.arange(400, 701, 10.0))
    roughness = np.diff(np.eye(spectra.shape[0]), axis=0) @ spectra
    free = baselines.authors_weights(ambient, led_only, spectra, alpha=0.0)
    smooth = baselines.authors_weights(ambient, led_only, spectra, alpha=baselines.AUTHORS_ALPHA)
    assert np.linalg.norm(roughness @ smooth) < 0.5 * np.linalg.norm(roughness @ free)
    assert np.all(spectra @ smooth >= -1e-7)


@pytest.mark.parametrize("cfa", [None, "GBRG"])
@pytest.mark.parametrize("unit", ["energy", "photons"])
def test_baselines_recover_an_ambient_made_of_the_leds_from_frames_on_disk(
    cfa: str | None, unit: str, tmp_path: Path
) -> None:
    """Noise-free 16-bit frames of an ambient that is a mix of the LEDs, unequal exposures and
    vignetting: the authors' port (without roughness) and plain least squares return that mix."""
    case = replace(NOISE_FREE, cfa=cfa, unit=unit, exposures="unequal", vignetting=0.6)
    truth = render(case, tmp_path / "s")
    assert rmse(truth.led_spd @ np.array(WEIGHTS), truth.ambient) < 1e-12
    assert rmse(baselines.authors_estimate(truth.directory, alpha=0.0), truth.ambient) < 1e-3
    assert rmse(baselines.lstsq_estimate(truth.directory), truth.ambient) < 1e-3


def test_authors_preprocessing_downsamples_by_four_and_drops_saturated_pixels(tmp_path: Path) -> None:
    case = replace(NOISE_FREE, specular=True, peak=0.9)
    frames = baselines.read_frames(render(case, tmp_path / "s").directory)
    ambient, led_only, valid = baselines.downsampled(frames)
    height, width = frames.ambient.shape[:2]
    assert ambient.shape == ((height // 4) * (width // 4), 3) and led_only.shape == (5,) + ambient.shape
    # The specular strip (6 pixels wide, 2.5× white) clips: its blocks are dropped, the rest kept.
    assert 0 < np.sum(~valid) <= 3 * (height // 4) and frames.saturated.any()
    bayer = baselines.read_frames(render(replace(case, cfa="RGGB"), tmp_path / "b").directory)
    assert baselines.downsampled(bayer)[0].shape == ambient.shape
