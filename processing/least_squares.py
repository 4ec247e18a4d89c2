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

    The problems have a handful of variables, so an explicit inverse is cheap and accurate, and
    numpy's small-matrix routines cost microseconds where scipy's wrappers cost tens of them.
    """
    if not np.all(np.isfinite(hessian)):
        raise SolverError(f"{where}: the normal matrix has non-finite entries; expected finite data")
    try:
        lower = np.linalg.cholesky(hessian)
    except np.linalg.LinAlgError as err:
        raise SolverError(
            f"{where}: the normal matrix is not positive definite (the LED-only images are linearly "
            "dependent or empty); expected independent LED frames"
        ) from err
    return np.linalg.inv(lower.T)


def least_distance(constraints: np.ndarray, bounds: np.ndarray, where: str = "least distance") -> np.ndarray:
    """Shortest vector z with ``constraints @ z ≥ bounds`` (LDP, Lawson & Hanson ch. 23).

    Raises
    ------
    SolverError
        If the constraints are infeasible.
    """
    n = constraints.shape[1]
    if constraints.shape[0] == 0 or np.all(bounds <= 0):
        return np.zeros(n)
    scale = max(np.max(np.abs(constraints)), np.max(np.abs(bounds)), 1e-300)
    stacked = np.vstack([constraints.T, bounds[None, :]]) / scale
    target = np.zeros(n + 1)
    target[n] = 1.0
    multipliers, _ = nnls(stacked, target, maxiter=50 * stacked.shape[1])
    residual = stacked @ multipliers - target
    if abs(residual[n]) < 1e-12 or np.linalg.norm(residual) < 1e-12:
        raise SolverError(f"{where}: the constraints cannot all be met; expected a feasible problem")
    return -residual[:n] / residual[n]


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
    x = _polish(hessian, linear, constraints, bounds, x, inverse_factor)
    slack = constraints @ x - bounds
    scale = np.maximum(1.0, np.abs(bounds))
    if np.any(slack < -1e-7 * scale):
        raise SolverError(f"{where}: constraint violated by {-slack.min():.3g} after solving; expected feasibility")
    active = slack <= _FEASIBILITY_TOLERANCE * scale
    objective = float(0.5 * x @ hessian @ x - linear @ x)
    return QuadraticSolution(x=x, objective=objective, active=active)


def _polish(hessian: np.ndarray, linear: np.ndarray, constraints: np.ndarray, bounds: np.ndarray,
            x: np.ndarray, inverse_factor: np.ndarray) -> np.ndarray:
    """Re-solve the KKT system on the active set; keep the result if it is feasible and optimal.

    NNLS returns the right active set but only to its own tolerance; the KKT solve gives the
    minimiser to machine precision.
    """
    unconstrained = inverse_factor @ (inverse_factor.T @ linear)
    if constraints.shape[0] == 0:
        return unconstrained
    slack = constraints @ x - bounds
    tolerance = 1e-7 * np.maximum(1.0, np.abs(bounds))
    active = np.flatnonzero(slack <= tolerance)
    n = x.size
    if active.size == 0:
        candidate = unconstrained
        multipliers = np.zeros(0)
    else:
        m = active.size
        kkt = np.zeros((n + m, n + m))
        kkt[:n, :n] = hessian
        kkt[:n, n:] = -constraints[active].T
        kkt[n:, :n] = constraints[active]
        rhs = np.concatenate([linear, bounds[active]])
        try:
            solution = np.linalg.solve(kkt, rhs)
        except np.linalg.LinAlgError:
            return x  # degenerate active set (dependent constraints): keep the NNLS answer
        candidate, multipliers = solution[:n], solution[n:]
    if (constraints @ candidate - bounds >= -tolerance).all() and (
        multipliers.size == 0 or multipliers.min() >= -1e-9 * max(1.0, float(np.abs(multipliers).max()))
    ):
        improvement = 0.5 * (candidate @ hessian @ candidate - x @ hessian @ x) - linear @ (candidate - x)
        if improvement <= 1e-12 * max(1.0, abs(float(0.5 * x @ hessian @ x - linear @ x))):
            return candidate
    return x
