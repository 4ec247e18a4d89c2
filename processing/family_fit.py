"""Fitting a family's form to a scene's data term by variable projection (issue 30, item 2).

Each form's θ is searched over a coarse grid of starts (:func:`start_atoms`), then refined by a bounded
Levenberg–Marquardt on the variable-projection residual with Kaufman's Jacobian (:func:`refine`); the amplitudes
are non-negative least squares at every θ. The discharge dictionary is fitted greedily (:func:`fit_discharge`),
two fits of two families jointly (:func:`fit_mixture`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Any

import numpy as np

from msflash.processing import family_kernels
from msflash.processing.light_forms import FIXED, NONE, Form, discharge_atoms, kernel_grid
from msflash.processing.scipy_cores import lapack
from msflash.processing.spectra import WavelengthGrid
from msflash.processing.spectral_data_term import Whitened, nonnegative_fit

MAX_DISCHARGE_ATOMS = 6
"""Most atoms the greedy discharge fit keeps."""

ASK: Any = object()
"""The fits' ``compiled`` default: ask :func:`processing.family_kernels.kernels` (a caller fitting many forms asks
once and passes its answer — the compiled fits, or None for the numpy ones)."""


def _kernels(compiled: Any) -> Any:
    return family_kernels.kernels() if compiled is ASK else compiled


@dataclass(frozen=True)
class Fit:
    """A form fitted to a scene: ``e = atoms @ amplitudes``."""

    name: str
    """``family/form``, e.g. ``solid_state/phosphor white`` (``led``, ``prior`` for the two baselines)."""
    family: str
    theta: np.ndarray
    atoms: np.ndarray
    amplitudes: np.ndarray
    objective: float
    n_parameters: int
    form: Form | None = None
    atom_names: tuple[str, ...] = ()
    seconds: float = 0.0
    """Wall time spent fitting and judging this candidate (for the accuracy-against-compute chart)."""

    def with_seconds(self, seconds: float) -> Fit:
        """This fit with :attr:`seconds` set (``dataclasses.replace``'s result, without its field-by-field rebuild:
        a family estimate makes ~40 of these)."""
        timed = object.__new__(Fit)
        timed.__dict__.update(self.__dict__, seconds=seconds)
        return timed

    @cached_property
    def spectrum(self) -> np.ndarray:
        """e (photons, the LEDs' units): computed once (a family estimate reads each candidate's several times), and
        read-only."""
        spectrum = self.atoms @ self.amplitudes
        spectrum.flags.writeable = False
        return spectrum

    def parameters(self) -> dict[str, float]:
        """The fitted parameters by name (nonlinear in physical units, then the amplitudes)."""
        out = self.form.describe(self.theta) if self.form is not None else {}
        names = self.atom_names or (
            ("amplitude",) if self.amplitudes.size == 1 else tuple(f"band {i}" for i in range(self.amplitudes.size))
        )
        out.update({n if n == "amplitude" else f"{n} amplitude": float(a) for n, a in zip(names, self.amplitudes)})
        return out


REFINE_ITERATIONS = 25
"""Most Levenberg–Marquardt steps of a form's refinement (:func:`refine`)."""
REFINE_TOLERANCE = 1e-6
""":func:`refine` stops when a step gains, or its linear model promises, less than this fraction of the residual."""


@lru_cache(maxsize=64)
def start_atoms(form: Form, grid: WavelengthGrid) -> tuple[np.ndarray, ...]:
    """The atoms of each of the form's coarse starts on ``grid``, computed once per grid (they do not depend on the
    scene)."""
    out = []
    for start in form.starts:
        atoms = form.atoms(grid, np.array(start, float))
        atoms.flags.writeable = False
        out.append(atoms)
    return tuple(out)


@lru_cache(maxsize=64)
def _stacked_starts(form: Form, grid: WavelengthGrid) -> tuple[np.ndarray, np.ndarray]:
    """:func:`start_atoms` side by side, and where each start's columns begin (C-ordered, computed once)."""
    atoms = start_atoms(form, grid)
    stacked = np.ascontiguousarray(np.hstack(atoms)) if atoms else np.zeros((grid.size, 0))
    offsets = np.concatenate([[0], np.cumsum([a.shape[1] for a in atoms])]).astype(np.int64)
    stacked.flags.writeable = False
    return stacked, offsets


def _start_costs(form: Form, grid: WavelengthGrid, problem: Whitened, compiled: Any = ASK) -> np.ndarray:
    """J at each coarse start (single-atom forms in one product: the amplitude is in closed form; the others by
    the compiled fits where :mod:`processing.family_kernels` is in use)."""
    stacked, offsets = _stacked_starts(form, grid)
    designs = problem.root @ stacked
    if offsets.size > 1 and offsets[-1] == offsets.size - 1:  # one atom a start
        energies = np.einsum("ij,ij->j", designs, designs)
        projections = np.clip(designs.T @ problem.target, 0.0, None)
        with np.errstate(divide="ignore", invalid="ignore"):
            gains = np.where(energies > 0, projections**2 / energies, 0.0)
        costs = float(problem.target @ problem.target) - gains + problem.constant
        return np.where(np.isfinite(costs), costs, math.inf)
    compiled = _kernels(compiled)
    if compiled is not None and offsets.size > 1:
        return compiled.block_costs(designs, offsets, problem.target) + problem.constant
    return np.array([problem.amplitudes(a)[1] for a in start_atoms(form, grid)])


@lru_cache(maxsize=16)
def _all_starts(forms: tuple[Form, ...], grid: WavelengthGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
    """Every form's coarse starts side by side, the single-atom forms' and the others' apart (C-ordered, computed
    once): ``(single, multi, multi offsets, spans)``, ``spans[i]`` where form i's costs lie among the single-atom
    starts' (``True, start, stop``) or the others' (``False, start, stop``, start indices of the offsets)."""
    singles, multis, spans = [], [], []
    single_count, multi_offsets = 0, [0]
    for form in forms:
        stacked, offsets = _stacked_starts(form, grid)
        if offsets.size > 1 and offsets[-1] == offsets.size - 1:
            singles.append(stacked)
            spans.append((True, single_count, single_count + offsets.size - 1))
            single_count += offsets.size - 1
        else:
            multis.append(stacked)
            spans.append((False, len(multi_offsets) - 1, len(multi_offsets) - 1 + offsets.size - 1))
            base = multi_offsets[-1]
            multi_offsets.extend(base + int(o) for o in offsets[1:])
    empty = np.zeros((grid.size, 0))
    single = np.ascontiguousarray(np.hstack(singles)) if singles else empty
    multi = np.ascontiguousarray(np.hstack(multis)) if multis else empty
    for array in (single, multi):
        array.flags.writeable = False
    return single, multi, np.array(multi_offsets, np.int64), tuple(spans)


def start_costs(
    forms: tuple[Form, ...], grid: WavelengthGrid, problem: Whitened, compiled: Any = ASK
) -> list[np.ndarray]:
    """:func:`_start_costs` of every form; where :mod:`processing.family_kernels` is in use, in two products and one
    compiled call for all of them (the same formulas: the closed form for single-atom starts, the non-negative fit
    for the others)."""
    compiled = _kernels(compiled)
    if compiled is None:
        return [_start_costs(form, grid, problem, None) for form in forms]
    single, multi, offsets, spans = _all_starts(forms, grid)
    designs = problem.root @ single
    energies = np.einsum("ij,ij->j", designs, designs)
    projections = np.clip(designs.T @ problem.target, 0.0, None)
    with np.errstate(divide="ignore", invalid="ignore"):
        gains = np.where(energies > 0, projections**2 / energies, 0.0)
    costs = float(problem.target @ problem.target) - gains + problem.constant
    single_costs = np.where(np.isfinite(costs), costs, math.inf)
    multi_costs = (
        compiled.block_costs(problem.root @ multi, offsets, problem.target) + problem.constant
        if offsets.size > 1
        else np.zeros(0)
    )
    return [(single_costs if alone else multi_costs)[start:stop] for alone, start, stop in spans]


def _difference_tangent(
    atoms_of: Callable[[np.ndarray], np.ndarray],
    theta: np.ndarray,
    spectrum: np.ndarray,
    amplitudes: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
) -> np.ndarray:
    """``∂(B(θ) a)/∂θ`` by forward differences of the atoms (amplitudes held), stepping inwards at a bound."""
    steps = 1e-4 * np.maximum(upper - lower, 1e-6)
    columns = np.empty((spectrum.size, theta.size))
    for j in range(theta.size):
        step = steps[j] if theta[j] + steps[j] <= upper[j] else -steps[j]
        moved = theta.copy()
        moved[j] += step
        shifted = atoms_of(moved) @ amplitudes
        columns[:, j] = (shifted - spectrum) / step if np.all(np.isfinite(shifted)) else 0.0
    return columns


def _solve_positive(matrix: np.ndarray, right: np.ndarray) -> np.ndarray | None:
    """``matrix⁻¹ right`` for a symmetric positive definite matrix (Cholesky), or None when it is not."""
    _, solution, info = lapack.dposv(matrix, right)
    return solution if info == 0 else None


def refine(
    atoms_of: Callable[[np.ndarray], np.ndarray],
    problem: Whitened,
    theta: np.ndarray,
    bounds: tuple[tuple[float, float], ...],
    iterations: int = REFINE_ITERATIONS,
    tangent_of: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """θ refined by bounded Levenberg–Marquardt on the variable-projection residual ``R B(θ) a(θ) − z``.

    The Jacobian is Kaufman's: ``P⊥ R ∂(B a)/∂θ``, the derivative of the spectrum at the current amplitudes with
    the span of the active atoms projected out (Golub & Pereyra 2003, §3) — one evaluation of the atoms' tangent
    per step (``tangent_of(θ, a)`` in closed form, else forward differences of the atoms alone) rather than a
    non-negative fit per parameter. Steps are projected onto the bounds. Written out rather than scipy's
    minimisers: their Fortran calls OpenBLAS, whose threads' wake-ups on a busy machine cost far more than these
    problems (r ≈ 30 residuals, ≤ 12 parameters) take (docs/measurements.md).
    """
    lower = np.array([b[0] for b in bounds], float)
    upper = np.array([b[1] for b in bounds], float)
    theta = np.clip(np.asarray(theta, float), lower, upper)

    def state(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
        atoms = atoms_of(t)
        design = problem.root @ atoms
        amplitudes, norm2 = nonnegative_fit(design, problem.target)
        return (atoms, design, amplitudes, norm2) if math.isfinite(norm2) else None

    current = state(theta)
    if current is None:
        return theta
    damping, growth = 1e-3, 2.0
    for _ in range(iterations):
        atoms, design, amplitudes, cost = current
        spectrum = atoms @ amplitudes
        if tangent_of is not None:
            tangent = tangent_of(theta, amplitudes)
        else:
            tangent = _difference_tangent(atoms_of, theta, spectrum, amplitudes, lower, upper)
        jacobian = problem.root @ tangent
        active = amplitudes > 0
        if active.any():
            span = design[:, active]
            coefficients = _solve_positive(span.T @ span, span.T @ jacobian)
            if coefficients is None:
                coefficients = np.linalg.lstsq(span, jacobian, rcond=None)[0]
            jacobian = jacobian - span @ coefficients
        residual = design @ amplitudes - problem.target
        normal = jacobian.T @ jacobian
        gradient = jacobian.T @ residual
        diagonal = np.diag(normal) + 1e-12 * max(float(np.trace(normal)), 1e-300)
        improved = False
        while damping < 1e10:
            step = _solve_positive(normal + np.diag(damping * diagonal), -gradient)
            if step is None or not np.all(np.isfinite(step)):
                damping, growth = damping * growth, growth * 2
                continue
            candidate = np.clip(theta + step, lower, upper)
            taken = candidate - theta
            predicted = -2.0 * float(taken @ gradient) - float(taken @ normal @ taken)
            if predicted <= REFINE_TOLERANCE * cost:
                break  # the model promises no real gain: converged (or pinned at a bound)
            trial = state(candidate)
            if trial is not None and trial[3] < cost:
                gain = (cost - trial[3]) / predicted
                improved = cost - trial[3] > REFINE_TOLERANCE * max(cost, 1e-300)
                theta, current = candidate, trial
                damping = max(damping * max(1 / 3, 1 - (2 * gain - 1) ** 3), 1e-9)
                growth = 2.0
                break
            damping, growth = damping * growth, growth * 2
        if not improved:
            break
    return theta


def fit_form(
    form: Form,
    grid: WavelengthGrid,
    problem: Whitened,
    refined: bool = True,
    costs: np.ndarray | None = None,
    compiled: Any = ASK,
) -> Fit:
    """The form's best θ over its coarse starts (``costs``: their J, when computed already, :func:`start_costs`),
    then refined (:func:`refine`), and its amplitudes (``compiled``: :data:`ASK`)."""
    compiled = _kernels(compiled)
    costs = _start_costs(form, grid, problem, compiled) if costs is None else costs
    best = np.array(form.starts[int(np.argmin(costs))], float)
    compiled = compiled if refined and form.kind != NONE else None
    if compiled is not None:
        parts = ((form.kind, None), (NONE, None))
        best, atoms, amplitudes, objective = _compiled_refine(
            compiled, parts, best.size, grid, problem, best, form.bounds
        )
    else:
        if refined:
            closed = form.tangent
            tangent = None if closed is None else (lambda t, a: closed(grid, t, a))
            best = refine(lambda t: form.atoms(grid, t), problem, best, form.bounds, tangent_of=tangent)
        atoms = form.atoms(grid, best)
        amplitudes, objective = problem.amplitudes(atoms)
    return Fit(
        f"{form.family}/{form.name}",
        form.family,
        best,
        atoms,
        amplitudes,
        objective,
        len(form.parameters) + atoms.shape[1],
        form,
        form.atom_names,
    )


def fit_discharge(
    grid: WavelengthGrid, problem: Whitened, most: int = MAX_DISCHARGE_ATOMS, compiled: Any = ASK
) -> list[Fit]:
    """Greedy fits of the discharge dictionary with 1…``most`` atoms (each the best atom added to the last;
    ``compiled``: :data:`ASK`)."""
    dictionary, names = discharge_atoms(grid)
    designs = problem.root @ dictionary
    compiled = _kernels(compiled)
    order = (
        [int(i) for i in compiled.greedy_discharge(np.ascontiguousarray(designs), problem.target, most)]
        if compiled is not None
        else _greedy(designs, problem.target, most)
    )
    chosen: list[int] = []
    fits = []
    for size, best_atom in enumerate(order, start=1):
        chosen.append(best_atom)
        atoms = dictionary[:, chosen]
        amplitudes, objective = problem.amplitudes(atoms)
        used = amplitudes > 0
        fits.append(
            Fit(
                f"discharge/{size} atoms",
                "discharge",
                np.zeros(0),
                atoms[:, used],
                amplitudes[used],
                objective,
                int(used.sum()),
                None,
                tuple(names[i] for i, u in zip(chosen, used) if u),
            )
        )
    return fits


def _greedy(designs: np.ndarray, target: np.ndarray, most: int) -> list[int]:
    """The discharge atoms in the order the greedy fit adds them (each the one whose non-negative fit with those
    before leaves the least residual)."""
    chosen: list[int] = []
    for _ in range(min(most, designs.shape[1])):
        best_value, best_atom = math.inf, -1
        for atom in range(designs.shape[1]):
            if atom in chosen:
                continue
            _, value = nonnegative_fit(designs[:, [*chosen, atom]], target)
            if value < best_value:
                best_value, best_atom = value, atom
        chosen.append(best_atom)
    return chosen


def fit_mixture(first: Fit, second: Fit, grid: WavelengthGrid, problem: Whitened, compiled: Any = ASK) -> Fit:
    """Two fits of two families together: their atoms side by side, the nonlinear parameters refined jointly
    (``compiled``: :data:`ASK`)."""
    split = first.theta.size
    width = first.atoms.shape[1]

    def atoms_of(theta: np.ndarray) -> np.ndarray:
        a = first.atoms if first.form is None else first.form.atoms(grid, theta[:split])
        b = second.atoms if second.form is None else second.form.atoms(grid, theta[split:])
        return np.hstack([a, b])

    def part(fit: Fit, theta: np.ndarray, amplitudes: np.ndarray) -> np.ndarray:
        if fit.form is None or not theta.size:
            return np.zeros((grid.size, theta.size))
        if fit.form.tangent is not None:
            return fit.form.tangent(grid, theta, amplitudes)
        lower = np.array([b[0] for b in fit.form.bounds], float)
        upper = np.array([b[1] for b in fit.form.bounds], float)
        atoms_of_part = lambda t: fit.form.atoms(grid, t)  # noqa: E731
        return _difference_tangent(atoms_of_part, theta, atoms_of_part(theta) @ amplitudes, amplitudes, lower, upper)

    def tangent_of(theta: np.ndarray, amplitudes: np.ndarray) -> np.ndarray:
        return np.hstack(
            [part(first, theta[:split], amplitudes[:width]), part(second, theta[split:], amplitudes[width:])]
        )

    theta = np.concatenate([first.theta, second.theta])
    bounds = (first.form.bounds if first.form else ()) + (second.form.bounds if second.form else ())

    compiled = _kernels(compiled) if theta.size else None
    parts = (_part(first), _part(second))
    if compiled is not None and all(kind != NONE for kind, _ in parts):
        theta, atoms, amplitudes, objective = _compiled_refine(
            compiled, parts, split, grid, problem, theta, bounds, iterations=15
        )
    else:
        if theta.size:
            theta = refine(atoms_of, problem, theta, bounds, iterations=15, tangent_of=tangent_of)
        atoms = atoms_of(theta)
        amplitudes, objective = problem.amplitudes(atoms)
    names = tuple(f"{first.name}: {n}" for n in (first.atom_names or [f"{i}" for i in range(first.atoms.shape[1])]))
    names += tuple(f"{second.name}: {n}" for n in (second.atom_names or [f"{i}" for i in range(second.atoms.shape[1])]))
    return Fit(
        f"mixture/{first.name} + {second.name}",
        "mixture",
        theta,
        atoms,
        amplitudes,
        objective,
        first.n_parameters + second.n_parameters,
        _mixture_form(first, second, bounds, atoms_of),
        names,
    )


def _part(fit: Fit) -> tuple[int, np.ndarray | None]:
    """A fit as a part of the compiled refinement: its form's kind, or fixed atoms (no θ)."""
    if fit.form is None:
        return FIXED, fit.atoms
    return fit.form.kind, None


def _compiled_refine(
    compiled: object,
    parts: tuple[tuple[int, np.ndarray | None], tuple[int, np.ndarray | None]],
    split: int,
    grid: WavelengthGrid,
    problem: Whitened,
    theta: np.ndarray,
    bounds: tuple[tuple[float, float], ...],
    iterations: int = REFINE_ITERATIONS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """:func:`refine` by the compiled kernel (:mod:`processing.family_kernels`) of one part or two side by side
    (``θ[:split]`` the first's): the refined θ, its atoms, their non-negative amplitudes and J."""
    (kind_a, fixed_a), (kind_b, fixed_b) = parts
    empty = np.zeros((grid.size, 0))
    a = empty if fixed_a is None else np.ascontiguousarray(fixed_a, float)
    b = empty if fixed_b is None else np.ascontiguousarray(fixed_b, float)
    nm, slit, basis, water = kernel_grid(grid)
    lower, upper = _bound_arrays(bounds)
    theta, atoms, amplitudes, norm2 = compiled.refine(  # type: ignore[attr-defined]
        kind_a, a, split, kind_b, b, nm, slit, basis, water,
        np.ascontiguousarray(problem.root, float), np.ascontiguousarray(problem.target, float),
        np.ascontiguousarray(theta, float), lower, upper, iterations, REFINE_TOLERANCE,
    )  # fmt: skip
    return theta, atoms, amplitudes, float(norm2) + problem.constant


@lru_cache(maxsize=128)
def _bound_arrays(bounds: tuple[tuple[float, float], ...]) -> tuple[np.ndarray, np.ndarray]:
    """θ's lower and upper bounds as arrays, made once per form or mixture (the compiled refinement only reads them;
    left writeable, as numba compiles read-only arrays as another type)."""
    return np.array([b[0] for b in bounds], float), np.array([b[1] for b in bounds], float)


def _mixture_form(first: Fit, second: Fit, bounds: tuple, atoms_of: Callable[[np.ndarray], np.ndarray]) -> Form:
    parameters = tuple(f"{first.name} {p}" for p in (first.form.parameters if first.form else ())) + tuple(
        f"{second.name} {p}" for p in (second.form.parameters if second.form else ())
    )
    return Form("mixture", "mixture", parameters, bounds, (), lambda grid, th: atoms_of(th))
