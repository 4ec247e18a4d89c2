"""Whether an estimate may be a miss (> :data:`MISS_RATIO` × the LED bound): the checks behind the warnings
(issue 30, item 4).

The LEDs' and the prior's estimates are checked against the family estimate, which stands in for the truth
(:func:`predicted_ratio`); the family's own check is the spread of the candidates that predict about as well
(:func:`self_check`). Thresholds were chosen on tuning rows (docs/light-families.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msflash.processing.scipy_cores import nnls

MISS_RATIO = 1.3
"""An estimate whose RMSE exceeds this multiple of the LED bound is a miss (the harness's definition)."""
LED_WARNING = 1.13
"""The LEDs' estimate is flagged when its distance from the family's, over the family's LED bound, reaches this
(:func:`predicted_ratio`). Chosen on the tuning rows of both suites (recall and false alarms: docs/measurements.md)."""
PRIOR_WARNING = 1.2
"""The same for the light prior's estimate, chosen likewise (docs/measurements.md)."""
FAMILY_WARNING = 1.05
"""The family's estimate is flagged when its evidence spread (the RMS of the candidates' spread, max-normalised, over
its LED bound) times its held-out error over the LEDs' span's reaches this (:func:`self_check`): a wide spread
where the family gains little over the LEDs. Chosen on the tuning rows of both suites for false alarms ≤ 20 %
(docs/light-families.md): the pixels barely tell a family's misses."""


def paper_rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """The paper's spectrum RMSE: the estimate max-normalised, the truth least-squares scaled onto it."""
    estimate, truth = np.asarray(estimate, float), np.asarray(truth, float)
    peak = float(np.max(np.abs(estimate)))
    energy = float(truth @ truth)
    if not peak > 0 or not energy > 0:
        return math.nan
    normalised = estimate / peak
    return float(np.sqrt(np.mean((normalised - truth * (truth @ normalised) / energy) ** 2)))


def led_bound(led_values: np.ndarray, spectrum: np.ndarray) -> float:
    """:func:`paper_rmse` of the best non-negative fit of ``spectrum`` by the LED spectra (n, k): what they allow."""
    weights, _ = nnls(np.asarray(led_values, float), np.asarray(spectrum, float))
    return paper_rmse(np.asarray(led_values, float) @ weights, spectrum)


@dataclass(frozen=True)
class MissCheck:
    """How far an estimate is predicted to be from the truth, in multiples of the LED bound, and whether that warns."""

    predicted_ratio: float
    """The predicted RMSE over the predicted LED bound (the family's estimate stands in for the truth)."""
    threshold: float
    """The predicted ratio from which the estimate is flagged (chosen on tuning rows)."""
    basis: str
    """What the prediction rests on, in words."""

    @property
    def warned(self) -> bool:
        """Whether the estimate is flagged."""
        return bool(self.predicted_ratio >= self.threshold)

    def message(self, model: str) -> str:
        """The warning's text."""
        return (
            f"the {model} spectrum may be off by more than {MISS_RATIO:g}× what the LEDs allow: {self.basis} "
            f"predicts {self.predicted_ratio:.2f}× the LED bound (flagged from {self.threshold:g}×) — see the band"
        )


def predicted_ratio(
    estimate: np.ndarray, family_spectrum: np.ndarray, led_values: np.ndarray, threshold: float, model: str
) -> MissCheck:
    """The check of another model's estimate against the family's: ``RMSE(estimate, family) / bound(family)``.

    All spectra in one unit on one grid (the sequence's, as the harness scores them).
    """
    bound = led_bound(led_values, family_spectrum)
    distance = paper_rmse(estimate, family_spectrum)
    ratio = distance / bound if bound > 0 else math.inf
    return MissCheck(
        float(ratio), threshold, f"its distance from the family estimate ({model} against the physics families)"
    )


def self_check(
    family_spectrum: np.ndarray, spread: np.ndarray, led_values: np.ndarray, relative_error: float = 1.0
) -> MissCheck:
    """The family estimate's own check: the spread of the candidates that predict about as well, over its LED bound,
    times ``relative_error`` — the chosen candidate's held-out error over the LEDs' span's (noise removed): the
    spread says how far the pixels leave the spectrum open, the ratio how little the family gained over the LEDs."""
    peak = float(np.max(np.abs(family_spectrum)))
    bound = led_bound(led_values, family_spectrum)
    width = float(np.sqrt(np.mean((np.asarray(spread) / peak) ** 2))) if peak > 0 else math.inf
    ratio = width / bound * relative_error if bound > 0 else math.inf
    return MissCheck(
        ratio,
        FAMILY_WARNING,
        "the spread of the families that predict held-out pixels about as well as the chosen one, times its "
        "held-out error over the LEDs' span's",
    )
