"""Per-case metrics and their aggregates: spectrum RMSE over the LED bound, band coverage, the
warning confusion table.

RMSE is the paper's (:func:`tests.processing.unseen_sequences.rmse`: the estimate max-normalised,
the truth least-squares scaled onto it). The LED bound is that RMSE for the best non-negative LED
fit of the truth (``scipy.optimize.nnls``): what the LEDs allow at best. A case is a *miss* when
its RMSE exceeds :data:`MISS_FACTOR` × the bound.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from tests.processing.unseen_sequences import rmse

MISS_FACTOR = 1.3
"""An estimate whose RMSE exceeds this multiple of the LED bound is a miss (issue 17)."""
COVERAGE_TARGETS = {"1σ": (0.55, 0.80), "2σ": (0.90, 1.0)}
"""Wanted share of wavelengths where the truth lies within ±1σ and ±2σ of the estimate."""

__all__ = [
    "MISS_FACTOR",
    "COVERAGE_TARGETS",
    "rmse",
    "led_bound",
    "band_coverage",
    "Confusion",
    "confusion",
    "Summary",
    "summarise",
]


def led_bound(led_spd: np.ndarray, truth: np.ndarray) -> float:
    """RMSE of the best non-negative fit of ``truth`` (n,) by the LED spectra ``led_spd`` (n, k)."""
    fit, _ = nnls(np.asarray(led_spd, float), np.asarray(truth, float))
    return rmse(led_spd @ fit, truth)


def band_coverage(estimate: np.ndarray, std: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Shares of wavelengths where the truth lies within ±1σ and within ±2σ of the estimate.

    The estimate and its band are normalised by the same factor (the estimate's largest absolute
    value), and the truth least-squares scaled onto the normalised estimate, as in :func:`rmse`.

    >>> band_coverage(np.array([1.0, 1.0, 1.0, 1.0]), np.array([0.1, 0.1, 0.1, 0.1]), np.array([1.0, 1.05, 0.85, 1.1]))
    (0.75, 1.0)
    """
    estimate, std, truth = (np.asarray(v, float) for v in (estimate, std, truth))
    peak = float(np.max(np.abs(estimate)))
    normalised, band = estimate / peak, std / peak
    scaled = truth * (truth @ normalised) / (truth @ truth)
    distance = np.abs(scaled - normalised)
    return float(np.mean(distance <= band)), float(np.mean(distance <= 2 * band))


@dataclass(frozen=True)
class Confusion:
    """Warnings against misses over a set of cases."""

    warned_misses: int
    silent_misses: int
    warned_good: int
    silent_good: int

    @property
    def recall(self) -> float:
        """Share of misses that carried a warning (NaN without misses)."""
        misses = self.warned_misses + self.silent_misses
        return self.warned_misses / misses if misses else math.nan

    @property
    def false_alarm_rate(self) -> float:
        """Share of non-misses that carried a warning (NaN without non-misses)."""
        good = self.warned_good + self.silent_good
        return self.warned_good / good if good else math.nan


def confusion(ratios: Sequence[float], warned: Sequence[bool], factor: float = MISS_FACTOR) -> Confusion:
    """Count warned / silent misses (ratio > ``factor``) and non-misses.

    >>> confusion([0.9, 1.5, 2.0, 1.1], [False, True, False, True])
    Confusion(warned_misses=1, silent_misses=1, warned_good=1, silent_good=1)
    """
    miss = np.asarray(ratios, float) > factor
    warn = np.asarray(warned, bool)
    return Confusion(
        int(np.sum(miss & warn)), int(np.sum(miss & ~warn)), int(np.sum(~miss & warn)), int(np.sum(~miss & ~warn))
    )


@dataclass(frozen=True)
class Summary:
    """Mean and worst of RMSE ÷ LED bound over cases, and the share of misses."""

    count: int
    failed: int
    mean: float
    worst: float
    miss_rate: float


def summarise(ratios: Sequence[float]) -> Summary:
    """Aggregate ratios; NaN entries are failed cases (no estimate) and count as failures only.

    >>> summarise([1.0, 2.0, float("nan")])
    Summary(count=3, failed=1, mean=1.5, worst=2.0, miss_rate=0.5)
    """
    values = np.asarray(ratios, float)
    ok = values[np.isfinite(values)]
    if not ok.size:
        return Summary(values.size, values.size, math.nan, math.nan, math.nan)
    return Summary(
        values.size, int(values.size - ok.size), float(ok.mean()), float(ok.max()), float(np.mean(ok > MISS_FACTOR))
    )
