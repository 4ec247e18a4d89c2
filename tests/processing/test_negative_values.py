"""The one rule for negative values in measured spectra (processing/negative_values.py)."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing.errors import SpectralDataError
from msflash.processing.negative_values import (
    FALSE_REFUSAL,
    NOISE_SIGMAS,
    PEAK_FRACTION,
    clip_negative_noise,
    noise_pairs,
    noise_sigmas,
    tolerance,
)

W = np.arange(350.0, 800.0, 0.5)


def led(noise: float, seed: int = 0, offset: float = 0.0) -> np.ndarray:
    """A 520 nm LED of peak 1, dark-subtracted: noise about ``offset``."""
    return np.exp(-0.5 * ((W - 520) / 10) ** 2) + np.random.default_rng(seed).normal(offset, noise, W.size)


@pytest.mark.parametrize("noise", [0.002, 0.01, 0.03, 0.06])
def test_dark_subtraction_noise_is_clipped_and_reported(noise: float) -> None:
    values = led(noise)
    clipped, report = clip_negative_noise(W, values, ["led520"], "led.txt")
    assert clipped.min() == 0.0 and np.array_equal(clipped[values > 0], values[values > 0])
    (item,) = report
    assert item.count == np.count_nonzero(values < 0) > 0.3 * W.size  # about half the tails
    assert item.most_negative == values.min() and item.at_nm == W[np.argmin(values)]
    sigma, pairs = noise_pairs(values)
    assert item.tolerance == max(PEAK_FRACTION * values.max(), noise_sigmas(W.size, pairs) * sigma)
    assert noise_pairs(values)[0] == pytest.approx(noise, rel=0.25)


def test_the_noise_bound_follows_the_noise_model() -> None:
    """At least 5σ; the Gaussian quantile one of n samples crosses with FALSE_REFUSAL; wider for few pairs."""
    from scipy.stats import norm

    assert noise_sigmas(1, 10**12) == pytest.approx(NOISE_SIGMAS, rel=1e-4)  # one sample: 4.75σ would do
    assert noise_sigmas(3500, 10**12) == pytest.approx(norm.isf(FALSE_REFUSAL / 3500), rel=1e-4)
    assert noise_sigmas(3500, 100) > noise_sigmas(3500, 3000) > noise_sigmas(300, 3000)


def test_a_dim_exports_noise_is_not_measured_low() -> None:
    """Peak/σ = 7: the 10 %-of-peak region alone keeps the pairs below 0.7σ and measures σ a third low."""
    sigmas = [
        noise_pairs(0.07 * led(0.0, s) + np.random.default_rng(s).normal(0.0, 0.01, W.size))[0] for s in range(20)
    ]
    assert np.mean(sigmas) == pytest.approx(0.01, rel=0.1)


def test_the_noise_bound_admits_a_dim_led_the_peak_bound_alone_would_refuse() -> None:
    values = led(0.03)  # peak/noise ~33: -4σ tails at -12 % of the peak
    assert values.min() < -PEAK_FRACTION * values.max()
    assert clip_negative_noise(W, values, ["dim"], "dim.txt")[0].min() == 0.0


def test_an_offset_is_no_noise() -> None:
    """A dark subtracted twice: the tails sit at -10 % of the peak with little noise; differences cancel it."""
    values = led(0.002, offset=-0.1)
    assert noise_pairs(values)[0] < 0.003 and tolerance(values) == pytest.approx(PEAK_FRACTION * values.max())
    with pytest.raises(
        SpectralDataError,
        match=r"^off\.txt:7: column 'led520' at 350 nm is -0\.\d+; expected a "
        r"non-negative value, or measurement noise down to −0\.0[45]\d* .*"
        r"dark subtracted twice",
    ):
        clip_negative_noise(W, values, ["led520"], "off.txt", lines=list(range(7, 7 + W.size)))


def test_every_column_by_its_own_peak_and_noise() -> None:
    table = np.column_stack([led(0.001, 1), 0.01 * led(0.001, 2)])  # the second LED 100× dimmer, same noise
    clipped, report = clip_negative_noise(W, table, ["bright", "dim"], "t.csv")
    assert clipped.shape == table.shape and [r.column for r in report] == ["bright", "dim"]
    table[100, 1] = -0.5  # beyond the dim column's noise and peak bounds
    with pytest.raises(SpectralDataError, match=r"t\.csv: column 'dim' at 400 nm is -0\.5"):
        clip_negative_noise(W, table, ["bright", "dim"], "t.csv")


def test_nothing_negative_is_returned_as_is() -> None:
    values = np.abs(led(0.01))
    clipped, report = clip_negative_noise(W, values, ["x"], "x")
    assert clipped is values and report == ()
