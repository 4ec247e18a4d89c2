"""msflash.processing.scipy_cores: scipy's LAPACK and NNLS cores without its packages, answering as the public ones."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

from msflash.processing import scipy_cores


def test_the_cores_load_without_scipy_linalg_or_optimize() -> None:
    code = (
        "import sys; import msflash.processing.scipy_cores as c; "
        "print(c.NNLS_CORE is not None, c.lapack.__name__, 'scipy.linalg' in sys.modules, 'scipy.optimize' in sys.modules)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.split() == ["True", "scipy.linalg._flapack", "False", "False"]


@pytest.mark.parametrize("routine", ["dgesv", "dsyevd", "dpotrf", "dtrtri"])
def test_lapack_routines_are_scipys(routine: str) -> None:
    assert getattr(scipy_cores.lapack, routine) is getattr(scipy.linalg.lapack, routine)


@pytest.mark.parametrize("seed", range(20))
def test_nnls_answers_as_scipys(seed: int) -> None:
    rng = np.random.default_rng(seed)
    matrix, target = rng.normal(size=(12, 1 + seed % 7)), rng.normal(size=12)
    x, residual = scipy_cores.nnls(matrix, target)
    expected, expected_residual = scipy.optimize.nnls(matrix, target)
    np.testing.assert_array_equal(x, expected)
    assert residual == expected_residual


def test_nnls_refuses_what_scipy_refuses() -> None:
    with pytest.raises(ValueError):
        scipy_cores.nnls(np.array([[np.nan, 1.0]]), np.array([1.0]))
    with pytest.raises(ValueError, match="Incompatible dimensions"):
        scipy_cores.nnls(np.eye(3), np.ones(2))
