"""The two independent sample sequences: the estimate tracks the truth about as well as the LEDs allow.

Measured (spectrum RMSE, paper's definition; best = NNLS fit of the truth by the 7 LEDs), with
the estimation's 4×4 block-sum binning (commit 18de8aa) / without it (every pixel, before 18de8aa):

============================  =====  =============  =============  =============  =============
sample                        best   lstsq          nonneg         tikhonov       roughness
============================  =====  =============  =============  =============  =============
sample-rgb-tungsten           0.192  0.189 / 0.259  0.179 / 0.233  0.178 / 0.233  0.236 / 0.246
sample-bayer-fluorescent-12b  0.165  0.194 / 0.312  0.194 / 0.283  0.191 / 0.283  0.227 / 0.279
============================  =====  =============  =============  =============  =============

Without binning the Bayer sample missed the 0.1 margin (noisy LED-only images bias the weights).

Since the estimate is solved on noise-corrected statistics (commit 299ab56), with binning:
tungsten 0.262 / 0.186 / 0.186 / 0.223 (lstsq / nonneg / tikhonov / roughness); the Bayer sample
is unchanged (its corrected Gram matrix is not positive definite, so the observed one is used).
Unconstrained lstsq loses most there: removing the noise's share also removes its implicit ridge.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import nnls

from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import analysis, sequence_spectra
from tests.helpers import SAMPLES_DIR, spectrum_rmse

MARGIN = 0.1
"""How much worse than the best non-negative LED fit of the truth the estimate may be."""
SAMPLES = ("sample-rgb-tungsten", "sample-bayer-fluorescent-12bit")
METHODS = ("lstsq", "nonneg", "tikhonov", "roughness")


def load(name: str):
    directory = SAMPLES_DIR / name
    if not (directory / "sequence.json").exists():
        pytest.skip(f"sample sequence {directory} is absent (shared samples not mounted)")
    truth = json.loads((SAMPLES_DIR / f"{name}.truth.json").read_text())
    return read_sequence(directory), np.asarray(truth["ambient_spd_energy"], dtype=float)


_UNREGULARISED_ON_THE_DARK_BAYER_SAMPLE = pytest.mark.xfail(
    strict=True,
    reason=(
        "finding: plain least squares on the inverse-variance weighted, noise-corrected statistics of the "
        "Bayer sample (ambient ~10 DN a pixel, black 256) scatters: RMSE 0.288 against the best LED fit's 0.165 "
        "(0.340 before issue 30's noise line and probe; 0.194 when the biased observed statistics acted as a "
        "ridge); the regularised solvers stay within the margin: tikhonov 0.173, nonneg 0.178 (0.155, 0.214 before)"
    ),
)


@pytest.mark.parametrize(
    ("name", "method"),
    [
        pytest.param(
            name,
            method,
            marks=_UNREGULARISED_ON_THE_DARK_BAYER_SAMPLE
            if (name, method) == ("sample-bayer-fluorescent-12bit", "lstsq")
            else (),
        )
        for name in SAMPLES
        for method in METHODS
    ],
)
def test_estimate_tracks_truth_within_margin_of_best_led_fit(name: str, method: str) -> None:
    sequence, truth = load(name)
    assert np.allclose(
        sequence.wavelengths_nm, json.loads((SAMPLES_DIR / f"{name}.truth.json").read_text())["wavelengths_nm"]
    )
    leds = sequence.led_spectra().values  # energy, as the truth
    fit, _ = nnls(leds, truth)
    best = spectrum_rmse(leds @ fit, truth)
    estimate = analysis.estimate_sequence(sequence, method)
    rmse = spectrum_rmse(sequence_spectra.spectrum_in_sequence_unit(sequence, estimate.spectrum), truth)
    assert rmse <= best + MARGIN, f"{name} {method}: RMSE {rmse:.3f} vs best LED fit {best:.3f}"


@pytest.mark.parametrize("name", SAMPLES)
def test_samples_read_and_estimate_cleanly(name: str) -> None:
    sequence, _ = load(name)
    estimate = analysis.estimate_sequence(sequence)
    assert estimate.ambient_weights.shape == (7,)
    assert np.all(estimate.spectrum.values >= -1e-12)
    assert estimate.relative_residual < 0.1
    # Every LED fired: no reliability warning (the LED images are dominated by a bright strip,
    # which once fooled a mean/RMS "dead LED" test). The dark Bayer sample's band is wide, and says so.
    band_warnings = [w for w in estimate.warnings if w.startswith("the uncertainty band is wider")]
    assert list(estimate.warnings) == band_warnings
    wide = bool(np.any(estimate.spectrum_std > 0.5 * np.max(estimate.spectrum.values)))
    assert bool(band_warnings) == wide
    # The README promises a saturating specular strip, but no sample pixel reaches the white level.
    assert estimate.saturated_fraction == 0.0


@pytest.mark.parametrize("dead", [0, 4])
def test_a_dead_led_in_a_sample_is_flagged(dead: int) -> None:
    """Replace one LED frame by the ambient frame plus fresh noise of the same size: only that LED is flagged."""
    sequence, _ = load(SAMPLES[0])
    stack = analysis.load_frame_stack(sequence)
    rng = np.random.default_rng(dead)
    ambient = stack.ambient.astype(np.float64)
    noisy = ambient + rng.normal(0.0, np.sqrt(np.maximum(ambient - sequence.camera.black_level, 1.0)))
    frames = list(stack.led_frames)
    frames[dead] = np.clip(np.rint(noisy), 0, 65535).astype(np.uint16)
    broken = analysis.FrameStack(stack.ambient, tuple(frames), stack.spec, stack.ambient_index, stack.led_indices)
    estimate = analysis.estimate_sequence(sequence, stream=analysis.stream_stack(sequence, broken))
    flagged = [w for w in estimate.warnings if "holds noise" in w]
    assert len(flagged) == 1
    assert sequence.leds[dead].name in flagged[0]
    assert all(led.name not in flagged[0] for i, led in enumerate(sequence.leds) if i != dead)
