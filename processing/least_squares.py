"""Small inequality-constrained least squares on the k-dimensional LED weights.

Every solver in msflash reduces to one problem on a handful of variables (k LEDs, perhaps a
scale): minimise ``½ xᵀ H x − fᵀ x`` subject to ``G x ≥ h`` with H positive definite. It is
solved exactly, in microseconds, by Lawson & Hanson's reduction to *least distance programming*
(LDP) and one non-negative least squares problem (Lawson & Hanson, *Solving Least Squares
Problems*, 1974, ch. 23), followed by a polish of the active set through its KKT system.

Because the data enter only through H and f, the problems can be built from the sufficient
statistics of DESIGN §8 (the Gram matrix of the LED-only images and their products with the
ambient image), never from the pixels.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack
from scipy.optimize import nnls

from processing.errors import SolverError

_FEASIBILITY_TOLERANCE = 1e-9
_recorders: list[list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]] = []


@contextmanager
def recording_problems() -> Iterator[list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]]:
    """Collect every problem ``(H, f, G, h)`` solved inside the ``with`` block.

    The benchmark uses it to hand exactly the same problems to a general-purpose solver.
    """
    problems: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    _recorders.append(problems)
    try:
        yield problems
    finally:
        _recorders.remove(problems)


@dataclass(frozen=True)
class QuadraticSolution:
    """The minimiser of a constrained quadratic and what is known about it."""

    x: np.ndarray
    """The minimiser, shape (n,)."""
    objective: float
    """``½ xᵀ H x − fᵀ x`` at the minimiser."""
    active: np.ndarray
    """Boolean mask of the inequality constraints that hold with equality, shape (m,)."""


def _inverse_factor(hessian: np.ndarray, where: str) -> np.ndarray:
    """R⁻¹ for the upper Cholesky factor R of H = Rᵀ R; raises SolverError naming ``where``.

    The problems have a handful of variables, so an explicit inverse is cheap and accurate. LAPACK
    is called directly (``dpotrf``, ``dtrtri``): for 8×8 matrices numpy's wrappers cost ~20 µs
    each in checks, the routines themselves ~1 µs.
    """
    if not np.isfinite(hessian).all():
        raise SolverError(f"{where}: the normal matrix has non-finite entries; expected finite data")
    factor, info = lapack.dpotrf(hessian, lower=0, clean=1)
    if info != 0:
        raise SolverError(
            f"{where}: the normal matrix is not positive definite (the LED-only images are linearly "
            "dependent or empty); expected independent LED frames"
        )
    inverse, info = lapack.dtrtri(factor, lower=0)
    if info != 0:
        raise SolverError(f"{where}: the Cholesky factor is singular; expected independent LED frames")
    return inverse


def least_distance(constraints: np.ndarray, bounds: np.ndarray, where: str = "least distance") -> np.ndarray:
    """Shortest vector z with ``constraints @ z ≥ bounds`` (LDP, Lawson & Hanson ch. 23).

    Raises
    ------
    SolverError
        If the constraints are infeasible.
    """
    m, n = constraints.shape
    if m == 0 or (bounds <= 0).all():
        return np.zeros(n)
    stacked = np.empty((n + 1, m))
    stacked[:n] = constraints.T
    stacked[n] = bounds
    stacked /= max(float(abs(stacked).max()), 1e-300)
    target = np.zeros(n + 1)
    target[n] = 1.0
    multipliers, _ = nnls(stacked, target, maxiter=50 * m)
    residual = stacked @ multipliers
    residual[n] -= 1.0
    if abs(residual[n]) < 1e-12 or float(residual @ residual) < 1e-24:
        raise SolverError(f"{where}: the constraints cannot all be met; expected a feasible problem")
    z = -residual[:n] / residual[n]
    return _polish(constraints, bounds, z, multipliers > 0)


def _polish(constraints: np.ndarray, bounds: np.ndarray, z: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Re-solve the LDP exactly on its active set; keep the result if it is feasible and optimal.

    NNLS finds the right active set but the point only to its own tolerance. On the active set
    the shortest z solving ``G_A z = h_A`` is ``G_Aᵀ λ`` with ``(G_A G_Aᵀ) λ = h_A``; it is the
    LDP minimiser when ``λ ≥ 0`` and every other constraint holds.
    """
    if not active.any():
        return z
    equality = constraints[active]
    *_, multipliers, info = lapack.dgesv(equality @ equality.T, bounds[active])
    if info != 0 or multipliers.min() < 0:
        return z  # dependent active constraints or a wrong active set: keep the NNLS answer
    candidate = equality.T @ multipliers
    tolerance = 1e-9 * max(1.0, float(abs(bounds).max()))
    return candidate if ((constraints @ candidate - bounds) >= -tolerance).all() else z


def minimise_quadratic(
    hessian: np.ndarray,
    linear: np.ndarray,
    constraints: np.ndarray | None = None,
    bounds: np.ndarray | None = None,
    where: str = "quadratic solver",
) -> QuadraticSolution:
    """Minimise ``½ xᵀ H x − fᵀ x`` subject to ``G x ≥ h``.

    Parameters
    ----------
    hessian
        H, shape (n, n), symmetric positive definite.
    linear
        f, shape (n,).
    constraints
        G, shape (m, n), or None for an unconstrained problem.
    bounds
        h, shape (m,).
    where
        Names the caller in error messages.

    Raises
    ------
    SolverError
        If H is not positive definite or the constraints are infeasible.

    Examples
    --------
    >>> sol = minimise_quadratic(np.eye(2), np.array([1.0, -1.0]), np.eye(2), np.zeros(2))
    >>> np.round(sol.x, 12).tolist()
    [1.0, 0.0]
    """
    hessian = np.asarray(hessian, dtype=float)
    linear = np.asarray(linear, dtype=float)
    n = linear.size
    if constraints is None:
        constraints = np.zeros((0, n))
        bounds = np.zeros(0)
    constraints = np.asarray(constraints, dtype=float)
    bounds = np.asarray(bounds, dtype=float)
    for recorder in _recorders:
        recorder.append((hessian.copy(), linear.copy(), constraints.copy(), bounds.copy()))
    inverse_factor = _inverse_factor(hessian, where)
    # z = R x − d with d = R⁻ᵀ f turns the objective into ½‖z‖² − const (Lawson & Hanson 23.4).
    shift = inverse_factor.T @ linear
    constraints_z = constraints @ inverse_factor
    bounds_z = bounds - constraints_z @ shift
    z = least_distance(constraints_z, bounds_z, where)
    x = inverse_factor @ (z + shift)
    slack = constraints @ x - bounds
    scale = np.maximum(1.0, abs(bounds))
    if (slack < -1e-7 * scale).any():
        raise SolverError(f"{where}: constraint violated by {-slack.min():.3g} after solving; expected feasibility")
    active = slack <= _FEASIBILITY_TOLERANCE * scale
    objective = float(0.5 * x @ hessian @ x - linear @ x)
    return QuadraticSolution(x=x, objective=objective, active=active)
