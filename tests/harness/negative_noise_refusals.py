"""How often the negative-noise rule refuses genuine noise, on exports like the round-trip test's.

Run as ``python -m tests.harness.negative_noise_refusals N [SEED]``: N simulated dark-subtracted
LED columns drawn as ``tests/calibration/test_calibration_round_trip.py``'s generator draws them
(300–1000 nm at 0.2–2 nm, a 0.3–1 peak, noise 0.05–3 % twice over), each checked against
:func:`msflash.processing.negative_values.tolerance`. Prints the refused count and the worst ratios.
"""

from __future__ import annotations

import sys

import numpy as np


def refusals(n: int, seed: int = 0) -> tuple[int, list[float]]:
    """How many of ``n`` columns have a value below ``-tolerance``, and their value / tolerance."""
    from msflash.processing.negative_values import tolerance

    rng = np.random.default_rng(seed)
    ratios: list[float] = []
    for _ in range(n):
        start, stop, step = rng.uniform(300, 395), rng.uniform(705, 1000), rng.uniform(0.2, 2.0)
        w = start + step * np.arange(int((stop - start) / step))
        noise = rng.uniform(0.0005, 0.03)
        centre = rng.choice([440.0, 480.0, 500.0, 520.0, 596.0, 636.0, 660.0]) + rng.uniform(-8, 8)
        emission = rng.uniform(0.3, 1.0) * np.exp(-0.5 * ((w - centre) / rng.uniform(6, 20)) ** 2)
        values = emission + rng.normal(0, noise, w.size) - rng.normal(0, noise, w.size)
        bound = tolerance(values)
        if values.min() < -bound:
            ratios.append(float(values.min() / bound))
    return len(ratios), ratios


if __name__ == "__main__":
    count = int(sys.argv[1])
    refused, worst = refusals(count, int(sys.argv[2]) if len(sys.argv) > 2 else 0)
    print(f"{refused}/{count} columns refused; value/bound of the first: {[round(r, 3) for r in worst[:5]]}")
