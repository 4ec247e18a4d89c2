"""scipy's compiled LAPACK and NNLS routines, without importing ``scipy.linalg`` or ``scipy.optimize``.

Importing either package costs about twice ``import numpy`` (they pull in scipy's array-API layer,
numpy.testing, numpy.f2py, scipy.fft, scipy.special…), yet the estimator calls only a few LAPACK
routines and the NNLS core, which live in two extension modules that need nothing but numpy:
``scipy.linalg._flapack`` (what :mod:`scipy.linalg.lapack` re-exports) and
``scipy.optimize._slsqplib`` (what :func:`scipy.optimize.nnls` calls). They are loaded on their
own and registered under their own names, so a later ``import scipy.linalg`` reuses them.

Both are private to scipy: each is used only after it solves a known problem correctly; otherwise
(or when scipy's layout changes) the public modules are imported instead.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np


def _extension(name: str) -> ModuleType | None:
    """The extension module ``name`` (``package.sub._module``) loaded without running its package's ``__init__``.

    Returns None when it cannot be found or loaded that way.
    """
    if name in sys.modules:
        return sys.modules[name]
    package, _, _ = name.rpartition(".")
    try:
        package_spec = importlib.util.find_spec(package)
        if package_spec is None or not package_spec.submodule_search_locations:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, list(package_spec.submodule_search_locations))
        if spec is None or spec.loader is None or not isinstance(spec.loader, importlib.machinery.ExtensionFileLoader):
            return None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except Exception:  # noqa: BLE001 - any surprise means: use the public module
        return None
    return sys.modules.setdefault(name, module)


def _checked_lapack() -> Any:
    """``scipy.linalg._flapack`` if it solves a 2×2 system and factors a 2×2 matrix; else :mod:`scipy.linalg.lapack`."""
    module = _extension("scipy.linalg._flapack")
    try:
        if module is None:
            raise ImportError("scipy.linalg._flapack does not load on its own")
        matrix = np.array([[4.0, 2.0], [2.0, 3.0]])
        *_, solution, info = module.dgesv(matrix, np.array([[2.0], [1.0]]))
        factor, info_factor = module.dpotrf(matrix, lower=0, clean=1)
        expected = (
            info == 0
            and info_factor == 0
            and np.allclose(solution.ravel(), [0.5, 0.0], rtol=0, atol=1e-12)
            and np.allclose(factor, [[2.0, 1.0], [0.0, np.sqrt(2.0)]], rtol=0, atol=1e-12)
        )
    except Exception:  # noqa: BLE001 - any surprise means: use the public module
        expected = False
    if expected:
        return module
    from scipy.linalg import lapack as public

    return public


def _checked_nnls_core() -> Callable[[np.ndarray, np.ndarray, int], tuple] | None:
    """The routine behind :func:`scipy.optimize.nnls` if it answers a known problem correctly, else None."""
    module = _extension("scipy.optimize._slsqplib")
    if module is None:
        return None
    try:
        core = module.nnls
        x, _, info = core(np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([2.0, 1.0, -1.0]), 6)
        expected = np.allclose(x, [1.5, 0.0], rtol=0, atol=1e-12) and info == 1
    except Exception:  # noqa: BLE001 - any surprise means: do not use it
        return None
    return core if expected else None


lapack = _checked_lapack()
"""The LAPACK routines of :mod:`scipy.linalg.lapack` (``dgesv``, ``dsyevd``, ``dpotrf``, ``dtrtri``…), same signatures."""

NNLS_CORE = _checked_nnls_core()
"""``core(A, b, maxiter) -> (x, rnorm, info)`` for finite, float64, C-ordered inputs (info 3: out of iterations), or None."""


def nnls(matrix: np.ndarray, target: np.ndarray, maxiter: int | None = None) -> tuple[np.ndarray, float]:
    """``(x, ‖A x − b‖)`` with ``x = argmin ‖A x − b‖, x ≥ 0``, as :func:`scipy.optimize.nnls` answers.

    ``matrix`` A is m × n, ``target`` b m values (or an m × 1 column); ``maxiter`` defaults to 3 n.

    Raises
    ------
    RuntimeError
        When the iteration limit is reached (as scipy's).

    >>> x, residual = nnls(np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([2.0, 1.0, 1.0]))
    >>> np.round(x, 9).tolist(), round(residual, 6)
    ([1.5, 1.0], 0.707107)
    """
    if NNLS_CORE is None:
        from scipy.optimize import nnls as public

        return public(matrix, target, maxiter=maxiter)
    a = np.asarray_chkfinite(matrix, dtype=np.float64, order="C")
    b = np.asarray_chkfinite(target, dtype=np.float64)
    if a.ndim != 2:
        raise ValueError(f"Expected a 2D array, but the shape of A is {a.shape}")
    if b.ndim == 2 and b.shape[1] == 1:
        b = b.ravel()
    if b.ndim != 1 or b.shape[0] != a.shape[0]:
        raise ValueError(f"Incompatible dimensions: A is {a.shape}, b is {b.shape}")
    x, residual, info = NNLS_CORE(a, b, maxiter or 3 * a.shape[1])
    if info == 3:
        raise RuntimeError("Maximum number of iterations reached.")
    return x, float(residual)
