"""Compiled refinements of the family model's forms (issue 30's speed of ``--model family|auto``).

:func:`processing.family_fit.refine` spends its time in Python around numpy calls on problems of ~30 × ≤ 12 (a
Levenberg–Marquardt step is a dozen calls of a microsecond's work each). With numba loaded in the process the same
arithmetic runs compiled (:mod:`processing.family_kernels_numba`): a form is one of the kinds of :attr:`processing.light_forms.Form.kind` with its θ,
a mixture two of them side by side. The route follows :mod:`processing.frame_kernels`: compiled where that module's
kernels are in use (:func:`processing.frame_kernels.enabled`: numba loaded — the bench, large stacks — and not
paused or turned off by ``MSFLASH_KERNELS=numpy``), numpy otherwise; importing numba for one estimate costs more
than it saves. The two routes agree to rounding (tests/processing/test_family_kernels.py): the non-negative fits are
Lawson–Hanson on both, the steps the same formulas.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any


@lru_cache(maxsize=1)
def _compiled() -> Any:
    """The compiled module, warmed on a tiny problem (compiled or loaded from numba's cache once), or None."""
    try:
        from msflash.processing import family_kernels_numba
    except ImportError:
        return None
    import numpy as np

    from msflash.processing.light_forms import BANDS, BLACKBODY, FIXED

    nm = np.linspace(400.0, 700.0, 4)
    flat = np.ones((4, 3))
    fixed = np.ones((4, 1))
    for kind, theta in ((BANDS, np.array([500.0, 50.0])), (FIXED, np.zeros(0))):
        family_kernels_numba.refine(
            kind, fixed, theta.size, BLACKBODY, fixed, nm, 1.0, flat, flat, np.eye(4), np.ones(4),
            np.concatenate([theta, [8.0]]), np.concatenate([theta - 1, [7.0]]), np.concatenate([theta + 1, [9.0]]),
            2, 1e-6,
        )  # fmt: skip
    family_kernels_numba.greedy_discharge(np.eye(4), np.ones(4), 2)
    family_kernels_numba.block_costs(np.eye(4), np.array([0, 2, 4], np.int64), np.ones(4))
    folds = np.zeros(1, np.int64)
    square, row = np.eye(4)[None], np.ones((1, 4))
    family_kernels_numba.held_out(
        np.eye(4), np.array([0, 2, 4], np.int64), square, row, folds, square, row, np.ones(1), square, row,
        np.ones(1), np.eye(4),
    )  # fmt: skip
    return family_kernels_numba


def kernels() -> Any:
    """The compiled refinement if this process uses compiled kernels (module notes), else None."""
    from msflash.processing import frame_kernels

    return _compiled() if frame_kernels.enabled() else None
