"""Compiled fits of the family model (issue 30's speed of ``--model family|auto``).

:func:`processing.family_fit.refine` spends its time in Python around numpy calls on problems of ~30 × ≤ 12 (a
Levenberg–Marquardt step is a dozen calls of a microsecond's work each). Compiled, the same arithmetic
(:mod:`processing.family_kernels_numba`) refines a form — one of :data:`processing.light_forms.KINDS` with its θ —
or a mixture of two side by side, judges every candidate on the held-out folds in one call and runs the greedy
discharge fit and the coarse starts.

**Opt-in** (:func:`prepare`): loading the compiled fits costs a process far more than one estimate saves (the
figures: docs/light-families.md), so only a process that runs many estimates prepares them — the bench, a service, a batch through the Python API. A one-shot ``msflash estimate`` or
a capture session takes the numpy route. ``MSFLASH_KERNELS=numba`` forces the compiled route, ``numpy`` or
:func:`processing.frame_kernels.paused` turn it off. The two routes agree to rounding
(tests/processing/test_family_kernels.py; the harness tables are the same to their last digit): the non-negative
fits are Lawson–Hanson on both, the steps the same formulas.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from functools import lru_cache
from typing import Any

from msflash.processing import frame_kernels


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


_prepared = False


def prepare() -> bool:
    """Load (or compile) the compiled fits now, with :mod:`processing.frame_kernels`' kernels, for a process that
    will run many family estimates (module notes); whether they are available. Not while a camera streams."""
    global _prepared
    frame_kernels.prepare()
    _prepared = _compiled() is not None
    return _prepared


@contextmanager
def as_one_shot() -> Iterator[None]:
    """The numpy fits inside the block, as a process that did not :func:`prepare` takes them (a one-shot
    ``msflash estimate``), even where this process prepared the compiled ones; the frame kernels unchanged."""
    global _prepared
    before, _prepared = _prepared, False
    try:
        yield
    finally:
        _prepared = before


def kernels() -> Any:
    """The compiled fits if this process prepared them (or ``MSFLASH_KERNELS=numba``) and the compiled kernels
    are in use (not ``numpy``, not paused: :func:`processing.frame_kernels.enabled`), else None. Asked once per
    form and candidate (~20 times an estimate): the environment is read only where the answer depends on it."""
    if not _prepared and os.environ.get(frame_kernels.KERNELS_VARIABLE, "").strip().lower() != "numba":
        return None
    return _compiled() if frame_kernels.enabled() else None
