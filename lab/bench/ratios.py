"""Speed as interleaved ratios, and peak memory: how ``msflash bench`` measures against its targets.

A ratio pairs one run of the measured function with one run of a reference (a copy of the same
frames into a pre-allocated buffer) a few milliseconds apart, ``pairs`` times in turn (ABAB…): the
median of the per-pair ratios holds while other load comes and goes on a shared machine, where
the best of separate runs pairs the luckiest copy with the luckiest estimate. The spread (quartiles,
extremes) says how far to trust it. Peak memory is what numpy allocates during one run, over the
frames' bytes (tracemalloc tracks numpy's allocations).
"""

from __future__ import annotations

import time
import tracemalloc
from collections.abc import Callable
from typing import Any

import numpy as np

MIN_PAIRS = 15
"""Pairs a ratio needs before its target is judged (issue 21: ≥ 15)."""


def interleaved_ratio(function: Callable[[], Any], reference: Callable[[], Any], pairs: int) -> dict[str, Any]:
    """``function``'s time ÷ ``reference``'s over ``pairs`` pairs run in turn: median, quartiles, extremes.

    Both are run once first (compilation, caches, the thread pool), untimed.

    Examples
    --------
    >>> figure = interleaved_ratio(lambda: sum(range(2000)), lambda: sum(range(1000)), 3)
    >>> sorted(figure), figure["pairs"]
    (['max', 'median', 'min', 'pairs', 'q1', 'q3'], 3)
    """
    reference()
    function()
    ratios = []
    for _ in range(max(pairs, 1)):
        start = time.perf_counter()
        reference()
        middle = time.perf_counter()
        function()
        ratios.append((time.perf_counter() - middle) / max(middle - start, 1e-9))
    q1, median, q3 = (float(value) for value in np.percentile(ratios, [25, 50, 75]))
    return {
        "median": median,
        "q1": q1,
        "q3": q3,
        "min": float(min(ratios)),
        "max": float(max(ratios)),
        "pairs": len(ratios),
    }


def against_target(figure: dict[str, Any], target: float) -> dict[str, Any]:
    """The figure with its target (an upper bound on the median) and whether it is met; a figure of fewer
    than :data:`MIN_PAIRS` pairs is not judged (``met`` None).

    Examples
    --------
    >>> against_target({"median": 1.5, "pairs": 15}, 2.0)["met"], against_target({"median": 1.5, "pairs": 3}, 2.0)["met"]
    (True, None)
    """
    judged = figure.get("pairs", MIN_PAIRS) >= MIN_PAIRS
    return {**figure, "target": f"≤ {target:g}", "met": bool(figure["median"] <= target) if judged else None}


def peak_bytes(function: Callable[[], Any]) -> int:
    """The peak of memory allocated (numpy's included) while ``function`` runs, above what was held before."""
    function()  # compiled kernels, caches and pools are not the run's memory
    tracemalloc.start()
    try:
        function()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return int(peak)
