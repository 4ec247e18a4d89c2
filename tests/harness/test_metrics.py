"""The harness's metric functions on inputs whose answers are known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.harness import metrics


def test_band_coverage_counts_wavelengths_within_one_and_two_sigma() -> None:
    # Offsets orthogonal to the truth (they sum to zero), so the least-squares scaling keeps it as is:
    # distances of 0.5σ, 1.5σ, 2.5σ and 1.5σ.
    truth = np.ones(4)
    estimate = truth + np.array([0.05, -0.15, 0.25, -0.15])
    assert metrics.band_coverage(estimate, np.full(4, 0.1), truth) == (0.25, 0.75)


def test_band_coverage_scales_the_band_with_the_estimate() -> None:
    truth = np.linspace(1.0, 2.0, 11)
    estimate = truth * (1 + 0.05 * np.sin(np.arange(11)))
    std = np.full(11, 0.04)
    reference = metrics.band_coverage(estimate, std, truth)
    assert metrics.band_coverage(1e3 * estimate, 1e3 * std, 1e-3 * truth) == reference
    assert reference != metrics.band_coverage(estimate, 1e3 * std, truth)


def test_band_coverage_of_a_wrong_estimate_without_a_band_is_nil() -> None:
    truth = np.array([0.2, 0.5, 1.0])
    assert metrics.band_coverage(np.array([0.5, 0.5, 1.0]), np.zeros(3), truth) == (0.0, 0.0)


def test_confusion_counts_and_rates() -> None:
    ratios = [0.8, 1.29, 1.31, 2.0, 5.0, 1.0]
    warned = [True, False, True, False, True, False]
    matrix = metrics.confusion(ratios, warned)
    assert matrix == metrics.Confusion(warned_misses=2, silent_misses=1, warned_good=1, silent_good=2)
    assert matrix.recall == pytest.approx(2 / 3)
    assert matrix.false_alarm_rate == pytest.approx(1 / 3)


def test_confusion_rates_are_undefined_without_cases_of_a_kind() -> None:
    assert math.isnan(metrics.confusion([1.0, 1.1], [True, False]).recall)
    assert math.isnan(metrics.confusion([2.0], [True]).false_alarm_rate)


def test_summary_counts_failures_apart() -> None:
    summary = metrics.summarise([1.0, 1.4, math.nan, 0.9])
    assert (summary.count, summary.failed) == (4, 1)
    assert summary.mean == pytest.approx(1.1) and summary.worst == 1.4
    assert summary.miss_rate == pytest.approx(1 / 3)


def test_led_bound_is_zero_in_the_leds_span_and_positive_outside() -> None:
    wavelengths = np.arange(400, 701, 10.0)
    leds = np.column_stack([np.exp(-0.5 * ((wavelengths - p) / 20) ** 2) for p in (450, 550, 650)])
    assert metrics.led_bound(leds, leds @ np.array([0.3, 1.0, 0.5])) < 1e-9
    assert metrics.led_bound(leds, np.ones_like(wavelengths)) > 0.05
