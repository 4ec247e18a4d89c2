"""Small inequality-constrained least squares on the k-dimensional LED weights.

Every solver in msflash reduces to one problem on a handful of variables (k LEDs, perhaps a
scale): minimise ``½ xᵀ H x − fᵀ x`` subject to ``G x ≥ h`` with H positive definite. It is
solved exactly, in microseconds, by Lawson & Hanson's reduction to *least distance programming*
(LDP) and one non-negative least squares problem (Lawson & Hanson, *Solving Least Squares
Problems*, 1974, ch. 23), followed by a polish of the active set through its KKT system.

Because the data enter only through H and f, the problems can be built from the sufficient
statistics of docs/architecture.md §8 (the Gram matrix of the LED-only images and their products with the
ambient image), never from the pixels.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np

from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.scipy_cores import NNLS_CORE as _NNLS_CORE
from msflash.processing.scipy_cores import lapack

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
    """The minimiser of a constrained quadratic and what is known about it.

    The objective and the active set are computed when first read: most callers need only ``x``,
    and at these sizes each array operation costs more than its arithmetic.
    """

    x: np.ndarray
    """The minimiser, shape (n,)."""
    slack: np.ndarray
    """``G x − h``, shape (m,)."""
    problem: FactoredQuadratic = field(repr=False)
    linear: np.ndarray = field(repr=False)
    """Its linear term f."""

    @cached_property
    def objective(self) -> float:
        """``½ xᵀ H x − fᵀ x`` at the minimiser."""
        x = self.x
        return float((0.5 * x).dot(self.problem.hessian).dot(x) - self.linear.dot(x))

    @cached_property
    def active(self) -> np.ndarray:
        """Boolean mask of the inequality constraints that hold with equality, shape (m,)."""
        return self.slack <= self.problem.active_limit


def _inverse_factor(hessian: np.ndarray, where: str) -> np.ndarray:
    """R⁻¹ for the upper Cholesky factor R of H = Rᵀ R; raises SolverError naming ``where``.

    The problems have a handful of variables, so an explicit inverse is cheap and accurate. LAPACK
    is called directly (``dpotrf``, ``dtrtri``; why: ``docs/measurements.md``). One sum tells
    finite matrices apart (the exact check runs only when it is not finite, e.g. on overflow).
    """
    if not math.isfinite(np.add.reduce(hessian, axis=None)) and not np.isfinite(hessian).all():
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


def _nnls(matrix: np.ndarray, target: np.ndarray, maxiter: int) -> np.ndarray:
    """``argmin ‖A u − b‖, u ≥ 0`` (as :func:`scipy.optimize.nnls`) for finite float64 inputs."""
    if _NNLS_CORE is None:
        from scipy.optimize import nnls

        return nnls(matrix, target, maxiter=maxiter)[0]
    multipliers, _, info = _NNLS_CORE(matrix, target, maxiter)
    if info == 3:
        raise RuntimeError("Maximum number of iterations reached.")  # as scipy.optimize.nnls
    return multipliers


def least_distance(constraints: np.ndarray, bounds: np.ndarray, where: str = "least distance") -> np.ndarray:
    """Shortest vector z with ``constraints @ z ≥ bounds`` (LDP, Lawson & Hanson ch. 23).

    Raises
    ------
    SolverError
        If the constraints are infeasible.
    """
    m, n = constraints.shape
    if m == 0:
        return np.zeros(n)
    # Python's max/min/sum on the list: a numpy reduction costs several times more on a few dozen
    # numbers. Python's max may skip a NaN, so a NaN (found by the sum) never takes the early exit:
    # it reaches the finiteness test below, as with numpy's NaN-propagating max.
    bound_values = bounds.tolist()
    bound_top = max(bound_values)
    if bound_top <= 0 and not math.isnan(sum(bound_values)):
        return np.zeros(n)
    stacked = np.empty((n + 1, m))
    stacked[:n] = constraints.T
    stacked[n] = bounds
    peak = float(np.maximum.reduce(abs(stacked), axis=None))
    if not math.isfinite(peak):
        raise SpectralDataError(f"{where}: the constraints or the linear term are not finite; expected finite numbers")
    stacked /= max(peak, 1e-300)
    multipliers = _nnls(stacked, _last_unit(n + 1), 50 * m)
    residual = stacked.dot(multipliers)
    # The residual of the NNLS is r = E u − e_{n+1}; z = −r[:n] / r[n] (Lawson & Hanson 23.3).
    # A vanishing r[n] means infeasible; ‖r‖ ≥ |r[n]|, so a vanishing ‖r‖ is caught by it too.
    last = float(residual[n]) - 1.0
    if abs(last) < 1e-12:
        raise SolverError(f"{where}: the constraints cannot all be met; expected a feasible problem")
    z = residual[:n] / -last
    # max |h| without the abs array: max(max h, −min h), both exact (h is finite here).
    bound_peak = max(bound_top, -min(bound_values))
    return _polish(constraints, bounds, z, multipliers > 0, bound_peak)


@lru_cache(maxsize=64)
def _last_unit(size: int) -> np.ndarray:
    """``e_size``: the NNLS target of an LDP with ``size − 1`` variables (cached, read-only)."""
    unit = np.zeros(size)
    unit[-1] = 1.0
    unit.flags.writeable = False
    return unit


def _polish(
    constraints: np.ndarray, bounds: np.ndarray, z: np.ndarray, active: np.ndarray, bound_peak: float
) -> np.ndarray:
    """Re-solve the LDP exactly on its active set; keep the result if it is feasible and optimal.

    NNLS finds the right active set but the point only to its own tolerance. On the active set
    the shortest z solving ``G_A z = h_A`` is ``G_Aᵀ λ`` with ``(G_A G_Aᵀ) λ = h_A``; it is the
    LDP minimiser when ``λ ≥ 0`` and every other constraint holds (to ``10⁻⁹ max(1, max|h|)``,
    ``bound_peak`` being ``max|h|``).
    """
    # ``compress``: the rows of a boolean mask, as ``constraints[active]``, with less dispatch.
    equality = constraints.compress(active, axis=0)
    if not equality.shape[0]:
        return z
    *_, multipliers, info = lapack.dgesv(equality.dot(equality.T), bounds.compress(active))
    # (Python's min on a few numbers: a NaN it might skip would make the candidate NaN, which the
    # feasibility test below rejects, so the outcome is the same as with a NaN-propagating min.)
    if info != 0 or not min(multipliers.tolist()) >= 0:
        return z  # dependent active constraints or a wrong active set: keep the NNLS answer
    candidate = equality.T.dot(multipliers)
    tolerance = 1e-9 * max(1.0, bound_peak)
    return candidate if np.minimum.reduce(constraints.dot(candidate) - bounds) >= -tolerance else z


def minimise_quadratic(
    hessian: np.ndarray,
    linear: np.ndarray,
    constraints: np.ndarray | None = None,
    bounds: np.ndarray | None = None,
    where: str = "quadratic solver",
) -> QuadraticSolution:
    """Minimise ``½ xᵀ H x − fᵀ x`` subject to ``G x ≥ h``.

    ``hessian`` H (n, n) symmetric positive definite, ``linear`` f (n,), ``constraints`` G (m, n)
    or None for an unconstrained problem, ``bounds`` h (m,); ``where`` names the caller in errors.

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
    return FactoredQuadratic.prepare(hessian, constraints, bounds, where).minimise(linear)


@dataclass(frozen=True)
class FactoredQuadratic:
    """The part of ``min ½ xᵀ H x − fᵀ x, G x ≥ h`` that does not depend on f, factored once.

    :func:`minimise_quadratic` prepares it for every call. A caller that solves many problems with
    the same H, G and h — the matching flash of one LED set and camera, whose Hessian and bound
    rows are fixed — prepares it once and pays per solve only for what depends on f: the
    Cholesky factor, its check and the transformed constraint rows are the bulk of a solve's fixed
    cost at these sizes (k ≈ 8 variables: numpy-call overhead, not arithmetic).
    """

    hessian: np.ndarray
    """H, shape (n, n)."""
    constraints: np.ndarray
    """G, shape (m, n) (m may be 0)."""
    bounds: np.ndarray
    """h, shape (m,)."""
    inverse_factor: np.ndarray
    """R⁻¹ for H = Rᵀ R (upper R)."""
    constraints_z: np.ndarray
    """``G R⁻¹``: the constraint rows in the LDP variable z = R x − R⁻ᵀ f."""
    violation_limit: np.ndarray
    """``−10⁻⁷ max(1, |h|)``: slack below this after solving is an error."""
    active_limit: np.ndarray
    """``10⁻⁹ max(1, |h|)``: slack at or below this marks an active constraint."""
    where: str
    """Names the caller in error messages."""

    @classmethod
    def prepare(
        cls,
        hessian: np.ndarray,
        constraints: np.ndarray | None = None,
        bounds: np.ndarray | None = None,
        where: str = "quadratic solver",
    ) -> FactoredQuadratic:
        """Factor H and transform G (see :func:`minimise_quadratic` for the arguments).

        Raises
        ------
        SolverError
            If H is not positive definite.
        """
        hessian = np.asarray(hessian, dtype=float)
        if constraints is None:
            constraints = np.zeros((0, hessian.shape[0]))
            bounds = np.zeros(0)
        constraints = np.asarray(constraints, dtype=float)
        bounds = np.asarray(bounds, dtype=float)
        inverse_factor = _inverse_factor(hessian, where)
        scale = np.maximum(1.0, abs(bounds))
        return cls(
            hessian,
            constraints,
            bounds,
            inverse_factor,
            constraints.dot(inverse_factor),
            -1e-7 * scale,
            _FEASIBILITY_TOLERANCE * scale,
            where,
        )

    def with_hessian(self, hessian: np.ndarray, where: str | None = None) -> FactoredQuadratic:
        """The same constraints with another H, factored (for problems whose H changes per solve).

        ``where`` renames the caller in error messages (default: keep this problem's).

        Raises
        ------
        SolverError
            If H is not positive definite.
        """
        where = self.where if where is None else where
        hessian = np.asarray(hessian, dtype=float)
        inverse_factor = _inverse_factor(hessian, where)
        return FactoredQuadratic(
            hessian,
            self.constraints,
            self.bounds,
            inverse_factor,
            self.constraints.dot(inverse_factor),
            self.violation_limit,
            self.active_limit,
            where,
        )

    def minimise(self, linear: np.ndarray) -> QuadraticSolution:
        """The minimiser for the linear term f, shape (n,).

        Raises
        ------
        SolverError
            If the constraints are infeasible.
        """
        linear = np.asarray(linear, dtype=float)
        hessian, constraints, bounds = self.hessian, self.constraints, self.bounds
        for recorder in _recorders:
            recorder.append((hessian.copy(), linear.copy(), constraints.copy(), bounds.copy()))
        inverse_factor, where = self.inverse_factor, self.where
        # z = R x − d with d = R⁻ᵀ f turns the objective into ½‖z‖² − const (Lawson & Hanson 23.4).
        # (``.dot`` rather than ``@``: the same BLAS call with less dispatch, which is most of the
        # cost at this size.)
        shift = inverse_factor.T.dot(linear)
        constraints_z = self.constraints_z
        bounds_z = bounds - constraints_z.dot(shift)
        z = least_distance(constraints_z, bounds_z, where)
        x = inverse_factor.dot(z + shift)
        slack = constraints.dot(x) - bounds
        if np.count_nonzero(slack < self.violation_limit):
            raise SolverError(f"{where}: constraint violated by {-slack.min():.3g} after solving; expected feasibility")
        return QuadraticSolution(x, slack, self, linear)

    def minimise_each(self, linears: np.ndarray) -> np.ndarray:
        """The minimisers for many linear terms, the columns of ``linears`` (n, N): (n, N).

        Problems that differ only in f often share their active set (the band's draws scattered around
        one estimate). Each full solve's active set A is tried on every column still open at once, on
        its KKT system: with ``z``-rows ``B = G_A R⁻¹`` and ``s = R⁻ᵀ f``, ``(B Bᵀ) λ = h_A − B s`` and
        ``x = R⁻¹ (s + Bᵀ λ)``. A column whose multipliers are non-negative and whose x meets every
        constraint (to the tolerance of :meth:`minimise`'s polish) has its exact minimiser (the KKT
        conditions are sufficient for a convex problem); the others go on to the next full solve. The
        answers are those of :meth:`minimise` column by column, to rounding.

        Raises
        ------
        SolverError
            If the constraints are infeasible.
        """
        linears = np.asarray(linears, dtype=float)
        solutions = np.empty_like(linears)
        open_columns = np.arange(linears.shape[1])
        while open_columns.size:
            column, open_columns = open_columns[0], open_columns[1:]
            solution = self.minimise(linears[:, column])
            solutions[:, column] = solution.x
            active = solution.active
            if not open_columns.size or not active.any():
                continue
            rows_z = self.constraints_z.compress(active, axis=0)
            shifts = self.inverse_factor.T @ linears[:, open_columns]
            *_, multipliers, info = lapack.dgesv(
                rows_z @ rows_z.T, self.bounds.compress(active)[:, None] - rows_z @ shifts
            )
            if info != 0:
                continue  # dependent active constraints: full solves for the rest
            candidates = self.inverse_factor @ (shifts + rows_z.T @ multipliers)
            slack = self.constraints @ candidates - self.bounds[:, None]
            met = np.all(multipliers >= 0, axis=0) & np.all(slack >= -self.active_limit[:, None], axis=0)
            for recorder in _recorders:
                for accepted in open_columns[met]:
                    recorder.append(
                        (self.hessian.copy(), linears[:, accepted].copy(), self.constraints.copy(), self.bounds.copy())
                    )
            solutions[:, open_columns[met]] = candidates[:, met]
            open_columns = open_columns[~met]
        return solutions
