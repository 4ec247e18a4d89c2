"""The numba kernels behind :mod:`processing.family_kernels` (imported only through it; needs numba).

The same arithmetic as :func:`processing.family_fit.refine` and the forms of :mod:`processing.light_forms`, written
out for numba: a form is a *kind* (:data:`processing.light_forms.KINDS`) and its parameters; a fit refines one
or two parts side by side (a form, or a mixture of two fits). Compiled on first use and cached on disk
(``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from msflash.processing.light_forms import (
    BANDS,
    BLACKBODY,
    C2_NM_K,
    DAYLIGHT,
    FILTER,
    FIXED,
    UNDERWATER,
    daylight_weights,
)

LOG_4000 = math.log(4000.0)
LOG_25000 = math.log(25000.0)


@njit(cache=True)
def _planck(nm, kelvin):
    kelvin = max(kelvin, 100.0)
    top = math.expm1(min(C2_NM_K / (kelvin * 560.0), 700.0))
    out = np.empty(nm.size)
    for i in range(nm.size):
        out[i] = (560.0 / nm[i]) ** 5 * top / math.expm1(min(C2_NM_K / (kelvin * nm[i]), 700.0))
    return out


@njit(cache=True)
def _planck_log_slope(nm, kelvin):
    kelvin = max(kelvin, 100.0)
    x0 = min(C2_NM_K / (kelvin * 560.0), 700.0)
    base = x0 / -math.expm1(-x0)
    out = np.empty(nm.size)
    for i in range(nm.size):
        x = min(C2_NM_K / (kelvin * nm[i]), 700.0)
        out[i] = x / -math.expm1(-x) - base
    return out


_daylight_weights = njit(cache=True)(daylight_weights)


@njit(cache=True)
def _daylight(basis, cct):
    w1, w2 = _daylight_weights(cct)
    out = np.empty(basis.shape[0])
    for i in range(out.size):
        out[i] = max(basis[i, 0] + basis[i, 1] * w1 + basis[i, 2] * w2, 0.0)
    return out


@njit(cache=True)
def _width(kind, n_theta, fixed):
    if kind == FIXED:
        return fixed.shape[1]
    if kind == BANDS:
        return n_theta // 2
    return 1


@njit(cache=True)
def _atoms(kind, theta, fixed, nm, slit, basis, water, out):
    """Write the part's atoms (photons) into ``out`` (n × width)."""
    n = nm.size
    if kind == FIXED:
        out[:, :] = fixed
    elif kind == BLACKBODY:
        shape = _planck(nm, math.exp(theta[0]))
        for i in range(n):
            out[i, 0] = shape[i] * nm[i] / 555.0
    elif kind == DAYLIGHT:
        shape = _daylight(basis, math.exp(theta[0]))
        for i in range(n):
            out[i, 0] = shape[i] * nm[i] / 555.0
    elif kind == BANDS:
        count = theta.size // 2
        for j in range(count):
            variance = (max(theta[count + j], 1e-3) / 2.3548) ** 2 + slit
            for i in range(n):
                offset = nm[i] - theta[j]
                out[i, j] = math.exp(-0.5 * offset * offset / variance) * (nm[i] / 555.0)
    elif kind == UNDERWATER:
        shape = _daylight(basis, math.exp(theta[3]))
        d0, d1, d2 = max(theta[0], 0.0), max(theta[1], 0.0), max(theta[2], 0.0)
        for i in range(n):
            optical = water[i, 0] * d0 + water[i, 1] * d1 + water[i, 2] * d2
            out[i, 0] = shape[i] * math.exp(-optical) * nm[i] / 555.0
    elif kind == FILTER:
        shape = _planck(nm, math.exp(theta[0]))
        for i in range(n):
            x = (nm[i] - 550.0) / 100.0
            density = min(max(theta[1] * x + theta[2] * x * x, -30.0), 30.0)
            out[i, 0] = shape[i] * math.exp(-density) * nm[i] / 555.0


@njit(cache=True)
def _tangent(kind, theta, amplitudes, atoms, fixed, nm, slit, basis, water, lower, upper, out):
    """Write ``∂(B(θ) a)/∂θ`` of one part into ``out`` (n × P): closed forms where the numpy forms have them, else
    forward differences (:func:`processing.family_fit._difference_tangent`). ``atoms``: the part's B(θ) (C-ordered),
    as :func:`_atoms` wrote it for this θ (the refinement has it already: not evaluated again)."""
    n = nm.size
    p = theta.size
    if p == 0:
        return
    width = atoms.shape[1]
    spectrum = atoms @ amplitudes
    if kind == BLACKBODY:
        slope = _planck_log_slope(nm, math.exp(theta[0]))
        for i in range(n):
            out[i, 0] = spectrum[i] * slope[i]
    elif kind == BANDS:
        count = p // 2
        for j in range(count):
            width_j = max(theta[count + j], 1e-3)
            variance = (width_j / 2.3548) ** 2 + slit
            dvariance = 2 * width_j / 2.3548**2
            for i in range(n):
                offset = nm[i] - theta[j]
                weighted = atoms[i, j] * amplitudes[j]
                out[i, j] = weighted * offset / variance
                out[i, count + j] = weighted * offset * offset / (2 * variance * variance) * dvariance
    elif kind == UNDERWATER:
        for i in range(n):
            out[i, 0] = -water[i, 0] * spectrum[i]
            out[i, 1] = -water[i, 1] * spectrum[i]
            out[i, 2] = -water[i, 2] * spectrum[i]
        step = 1e-4 * (LOG_25000 - LOG_4000)
        if theta[3] + step > LOG_25000:
            step = -step
        moved = theta.copy()
        moved[3] += step
        shifted = np.empty((n, 1))
        _atoms(kind, moved, fixed, nm, slit, basis, water, shifted)
        for i in range(n):
            out[i, 3] = (shifted[i, 0] * amplitudes[0] - spectrum[i]) / step
    elif kind == FILTER:
        slope = _planck_log_slope(nm, math.exp(theta[0]))
        for i in range(n):
            x = (nm[i] - 550.0) / 100.0
            free = 1.0 if abs(theta[1] * x + theta[2] * x * x) < 30.0 else 0.0
            out[i, 0] = spectrum[i] * slope[i]
            out[i, 1] = -x * spectrum[i] * free
            out[i, 2] = -x * x * spectrum[i] * free
    else:  # forward differences of the atoms, stepping inwards at a bound
        shifted = np.empty((n, width))
        for j in range(p):
            step = 1e-4 * max(upper[j] - lower[j], 1e-6)
            if theta[j] + step > upper[j]:
                step = -step
            moved = theta.copy()
            moved[j] += step
            _atoms(kind, moved, fixed, nm, slit, basis, water, shifted)
            moved_spectrum = shifted @ amplitudes
            finite = True
            for i in range(n):
                if not math.isfinite(moved_spectrum[i]):
                    finite = False
            for i in range(n):
                out[i, j] = (moved_spectrum[i] - spectrum[i]) / step if finite else 0.0


@njit(cache=True)
def _cholesky_solve(matrix, right):
    """``matrix⁻¹ right`` (symmetric positive definite, Cholesky), and whether it was."""
    size = matrix.shape[0]
    factor = np.zeros((size, size))
    for j in range(size):
        total = matrix[j, j]
        for k in range(j):
            total -= factor[j, k] * factor[j, k]
        if not total > 0.0:
            return right.copy(), False
        factor[j, j] = math.sqrt(total)
        for i in range(j + 1, size):
            total = matrix[i, j]
            for k in range(j):
                total -= factor[i, k] * factor[j, k]
            factor[i, j] = total / factor[j, j]
    solution = right.copy()
    columns = solution.shape[1]
    for c in range(columns):
        for i in range(size):
            total = solution[i, c]
            for k in range(i):
                total -= factor[i, k] * solution[k, c]
            solution[i, c] = total / factor[i, i]
        for i in range(size - 1, -1, -1):
            total = solution[i, c]
            for k in range(i + 1, size):
                total -= factor[k, i] * solution[k, c]
            solution[i, c] = total / factor[i, i]
    return solution, True


@njit(cache=True)
def _least_squares(design, passive, target):
    """Least squares on the passive columns (zeros elsewhere): Householder QR, LAPACK's when nearly rank-deficient."""
    columns = np.flatnonzero(passive)
    solution = np.zeros(design.shape[1])
    size = columns.size
    if size == 0:
        return solution
    rows = design.shape[0]
    work = np.empty((rows, size))
    for k in range(size):
        for i in range(rows):
            work[i, k] = design[i, columns[k]]
    right = target.copy()
    largest = 0.0
    for k in range(size):
        norm = 0.0
        for i in range(k, rows):
            norm += work[i, k] * work[i, k]
        norm = math.sqrt(norm)
        largest = max(largest, norm)
        if norm <= 1e-10 * largest or norm == 0.0:
            coefficients = np.linalg.lstsq(np.ascontiguousarray(design[:, columns]), target, -1.0)[0]
            for j in range(size):
                solution[columns[j]] = coefficients[j]
            return solution
        alpha = -norm if work[k, k] > 0 else norm
        head = work[k, k] - alpha
        # reflector v = (head, work[k+1:, k]), applied as x − 2 v (vᵀx)/(vᵀv)
        vv = head * head + (norm * norm - work[k, k] * work[k, k])
        for j in range(k + 1, size):
            dot = head * work[k, j]
            for i in range(k + 1, rows):
                dot += work[i, k] * work[i, j]
            factor = 2.0 * dot / vv
            work[k, j] -= factor * head
            for i in range(k + 1, rows):
                work[i, j] -= factor * work[i, k]
        dot = head * right[k]
        for i in range(k + 1, rows):
            dot += work[i, k] * right[i]
        factor = 2.0 * dot / vv
        right[k] -= factor * head
        for i in range(k + 1, rows):
            right[i] -= factor * work[i, k]
        work[k, k] = alpha
    coefficients = np.empty(size)
    for k in range(size - 1, -1, -1):
        total = right[k]
        for j in range(k + 1, size):
            total -= work[k, j] * coefficients[j]
        coefficients[k] = total / work[k, k]
    for j in range(size):
        solution[columns[j]] = coefficients[j]
    return solution


@njit(cache=True)
def _passive_solve(gram, right, passive, design, target):
    """The least-squares solution on the passive columns from the Gram matrix (Cholesky of ``G[P, P]``), or by
    Householder QR of the design when that factor is not safely positive (nearly dependent columns)."""
    columns = np.flatnonzero(passive)
    size = columns.size
    solution = np.zeros(gram.shape[0])
    if size == 0:
        return solution
    factor = np.zeros((size, size))
    for j in range(size):
        total = gram[columns[j], columns[j]]
        for k in range(j):
            total -= factor[j, k] * factor[j, k]
        if not total > 1e-10 * gram[columns[j], columns[j]]:
            return _least_squares(design, passive, target)
        factor[j, j] = math.sqrt(total)
        for i in range(j + 1, size):
            total = gram[columns[i], columns[j]]
            for k in range(j):
                total -= factor[i, k] * factor[j, k]
            factor[i, j] = total / factor[j, j]
    forward = np.empty(size)
    for i in range(size):
        total = right[columns[i]]
        for k in range(i):
            total -= factor[i, k] * forward[k]
        forward[i] = total / factor[i, i]
    for i in range(size - 1, -1, -1):
        total = forward[i]
        for k in range(i + 1, size):
            total -= factor[k, i] * forward[k]
        forward[i] = total / factor[i, i]
    for i in range(size):
        solution[columns[i]] = forward[i]
    return solution


@njit(cache=True)
def nnls(design, target, most, start=None):
    """Lawson–Hanson ``argmin ‖D x − z‖, x ≥ 0``: ``(x, ‖D x − z‖², converged)``.

    The passive sets' least squares through the Gram matrix ``DᵀD`` (computed once; the residual at the end from
    D itself), by QR where its Cholesky factor is not safely positive. ``start`` (optional, columns): a guess of
    the positive set (the last solution's in a refinement): taken when its least squares are positive, and the
    algorithm goes on from there as from any of its own iterates (the solution is the same: the problem is convex).
    """
    rows, columns = design.shape
    gram = design.T @ design
    right = design.T @ target
    x = np.zeros(columns)
    passive = np.zeros(columns, np.bool_)
    gradient = right.copy()
    tolerance = 10.0 * max(rows, columns) * 2.220446049250313e-16 * max(np.abs(design).sum(axis=0).max(), 1.0)
    if start is not None and start.any():
        trial = _passive_solve(gram, right, start, design, target)
        positive = True
        for j in range(columns):
            if start[j] and not trial[j] > tolerance:
                positive = False
        if positive:
            for j in range(columns):
                passive[j] = start[j]
                x[j] = trial[j] if start[j] else 0.0
            gradient = right - gram @ x
    iterations = 0
    converged = True
    while True:
        best, chosen = tolerance, -1
        for j in range(columns):
            if not passive[j] and gradient[j] > best:
                best, chosen = gradient[j], j
        if chosen < 0:
            break
        passive[chosen] = True
        trial = _passive_solve(gram, right, passive, design, target)
        while True:
            smallest = math.inf
            for j in range(columns):
                if passive[j] and trial[j] <= 0.0:
                    ratio = x[j] / (x[j] - trial[j]) if x[j] - trial[j] != 0.0 else 0.0
                    smallest = min(smallest, ratio)
            if smallest == math.inf:
                break
            iterations += 1
            if iterations > most:
                converged = False
                break
            for j in range(columns):
                x[j] += smallest * (trial[j] - x[j])
                if passive[j] and x[j] <= tolerance:
                    passive[j] = False
                    x[j] = 0.0
            trial = _passive_solve(gram, right, passive, design, target)
        x = trial
        for j in range(columns):
            if not passive[j]:
                x[j] = 0.0
        if not converged:
            break
        gradient = right - gram @ x
    residual = design @ x - target
    return x, float(residual @ residual), converged


@njit(cache=True)
def nonnegative_fit(design, target, start=None):
    """:func:`processing.spectral_data_term.nonnegative_fit`: columns scaled to unit norm, one in closed form."""
    columns = design.shape[1]
    if columns == 1:
        energy = 0.0
        projection = 0.0
        for i in range(design.shape[0]):
            energy += design[i, 0] * design[i, 0]
            projection += design[i, 0] * target[i]
        out = np.zeros(1)
        if not (energy > 0 and math.isfinite(energy) and math.isfinite(projection)):
            return out, math.inf if not math.isfinite(energy) else float(target @ target)
        out[0] = max(projection, 0.0) / energy
        return out, max(float(target @ target) - out[0] * projection, 0.0)
    scale = np.empty(columns)
    total = 0.0
    for j in range(columns):
        energy = 0.0
        for i in range(design.shape[0]):
            energy += design[i, j] * design[i, j]
        norm = math.sqrt(energy)
        total += norm
        scale[j] = norm if norm > 0 else 1.0
    if not math.isfinite(total):
        return np.zeros(columns), math.inf
    scaled = design / scale
    solution, norm2, _ = nnls(scaled, target, 30 * columns, start)
    return solution / scale, norm2


@njit(cache=True)
def _all_atoms(kind_a, fixed_a, theta, n_a, kind_b, fixed_b, nm, slit, basis, water):
    width_a = _width(kind_a, n_a, fixed_a)
    width_b = _width(kind_b, theta.size - n_a, fixed_b) if kind_b >= 0 else 0
    atoms = np.empty((nm.size, width_a + width_b))
    part = np.empty((nm.size, width_a))
    _atoms(kind_a, theta[:n_a], fixed_a, nm, slit, basis, water, part)
    atoms[:, :width_a] = part
    if kind_b >= 0:
        part = np.empty((nm.size, width_b))
        _atoms(kind_b, theta[n_a:], fixed_b, nm, slit, basis, water, part)
        atoms[:, width_a:] = part
    return atoms


@njit(cache=True)
def refine(kind_a, fixed_a, n_a, kind_b, fixed_b, nm, slit, basis, water, root, target, theta, lower, upper,
           iterations, tolerance):  # fmt: skip
    """:func:`processing.family_fit.refine` of one part (``kind_b`` < 0) or two side by side (θ = θ_a ‖ θ_b):
    ``(θ, B(θ), a, ‖R B a − z‖²)`` at the refined θ."""
    theta = np.minimum(np.maximum(theta.astype(np.float64), lower), upper)
    atoms = _all_atoms(kind_a, fixed_a, theta, n_a, kind_b, fixed_b, nm, slit, basis, water)
    design = root @ atoms
    amplitudes, cost = nonnegative_fit(design, target)
    if not math.isfinite(cost):
        return theta, atoms, amplitudes, cost
    width_a = _width(kind_a, n_a, fixed_a)
    p = theta.size
    damping, growth = 1e-3, 2.0
    for _ in range(iterations):
        tangent = np.zeros((nm.size, p))
        if n_a > 0:
            part = np.zeros((nm.size, n_a))
            _tangent(kind_a, theta[:n_a], amplitudes[:width_a], np.ascontiguousarray(atoms[:, :width_a]), fixed_a, nm,
                     slit, basis, water, lower[:n_a], upper[:n_a], part)  # fmt: skip
            tangent[:, :n_a] = part
        if kind_b >= 0 and p > n_a:
            part = np.zeros((nm.size, p - n_a))
            _tangent(kind_b, theta[n_a:], amplitudes[width_a:], np.ascontiguousarray(atoms[:, width_a:]), fixed_b, nm,
                     slit, basis, water, lower[n_a:], upper[n_a:], part)  # fmt: skip
            tangent[:, n_a:] = part
        jacobian = root @ tangent
        active = np.flatnonzero(amplitudes > 0)
        if active.size:
            span = np.ascontiguousarray(design[:, active])
            coefficients, ok = _cholesky_solve(span.T @ span, span.T @ jacobian)
            if not ok:
                coefficients = np.linalg.lstsq(span, jacobian, -1.0)[0]
            jacobian = jacobian - span @ coefficients
        residual = design @ amplitudes - target
        normal = jacobian.T @ jacobian
        gradient = jacobian.T @ residual
        trace = 0.0
        for j in range(p):
            trace += normal[j, j]
        floor = 1e-12 * max(trace, 1e-300)
        improved = False
        while damping < 1e10:
            damped = normal.copy()
            for j in range(p):
                damped[j, j] += damping * (normal[j, j] + floor)
            solution, ok = _cholesky_solve(damped, -gradient.reshape(p, 1))
            step = solution[:, 0]
            if not ok or not np.all(np.isfinite(step)):
                damping, growth = damping * growth, growth * 2
                continue
            candidate = np.minimum(np.maximum(theta + step, lower), upper)
            taken = candidate - theta
            predicted = -2.0 * float(taken @ gradient) - float(taken @ (normal @ taken))
            if predicted <= tolerance * cost:
                break
            trial_atoms = _all_atoms(kind_a, fixed_a, candidate, n_a, kind_b, fixed_b, nm, slit, basis, water)
            trial_design = root @ trial_atoms
            trial_amplitudes, trial_cost = nonnegative_fit(trial_design, target, amplitudes > 0)
            if math.isfinite(trial_cost) and trial_cost < cost:
                gain = (cost - trial_cost) / predicted
                improved = cost - trial_cost > tolerance * max(cost, 1e-300)
                theta, atoms, design = candidate, trial_atoms, trial_design
                amplitudes, cost = trial_amplitudes, trial_cost
                damping = max(damping * max(1 / 3, 1 - (2 * gain - 1) ** 3), 1e-9)
                growth = 2.0
                break
            damping, growth = damping * growth, growth * 2
        if not improved:
            break
    return theta, atoms, amplitudes, cost


@njit(cache=True)
def held_out(atoms, offsets, roots, targets, folds, hessian, linear, energy, noise_hessian, noise_linear,
             noise_energy, lift):  # fmt: skip
    """:func:`processing.light_families._held_out` of every candidate at once: candidate ``c``'s atoms are
    ``atoms[:, offsets[c]:offsets[c + 1]]``, refitted (non-negative) on each fold's complement (``roots[i]``,
    ``targets[i]`` for fold ``folds[i]``) and judged on the fold. Returns (candidates, 2): the summed squared
    errors as observed and with the noise's share removed (each clipped at 0), not yet divided by the energy."""
    count = offsets.size - 1
    out = np.zeros((count, 2))
    reduced = lift @ atoms  # (r, total width): y = L B a
    designs = np.empty((folds.size, roots.shape[1], atoms.shape[1]))
    for i in range(folds.size):
        designs[i] = roots[i] @ atoms  # every candidate's design on fold i's complement at once
    for c in range(count):
        start, stop = offsets[c], offsets[c + 1]
        coordinates = np.ascontiguousarray(reduced[:, start:stop])
        previous = np.zeros(stop - start, np.bool_)
        for i in range(folds.size):
            fold = folds[i]
            amplitudes, _ = nonnegative_fit(np.ascontiguousarray(designs[i, :, start:stop]), targets[i], previous)
            previous = amplitudes > 0
            y = coordinates @ amplitudes
            observed = energy[fold] - 2.0 * float(linear[fold] @ y) + float(y @ (hessian[fold] @ y))
            noise = noise_energy[fold] - 2.0 * float(noise_linear[fold] @ y) + float(y @ (noise_hessian[fold] @ y))
            out[c, 0] += max(observed, 0.0)
            out[c, 1] += max(observed - noise, 0.0)
    return out


@njit(cache=True)
def greedy_discharge(designs, target, most):
    """:func:`processing.family_fit.fit_discharge`'s greedy choice: the atom indices in the order added (each the
    atom whose non-negative fit with those before leaves the least residual)."""
    atoms = designs.shape[1]
    chosen = np.full(min(most, atoms), -1, np.int64)
    for size in range(chosen.size):
        best_value, best_atom = math.inf, -1
        trial = np.empty((designs.shape[0], size + 1))
        for k in range(size):
            trial[:, k] = designs[:, chosen[k]]
        kept = np.ones(size + 1, np.bool_)  # warm start: the atoms chosen so far (the last one's trial decides)
        kept[size] = False
        for atom in range(atoms):
            taken = False
            for k in range(size):
                if chosen[k] == atom:
                    taken = True
            if taken:
                continue
            trial[:, size] = designs[:, atom]
            _, value = nonnegative_fit(trial, target, kept)
            if value < best_value:
                best_value, best_atom = value, atom
        chosen[size] = best_atom
    return chosen


@njit(cache=True)
def block_costs(designs, offsets, target):
    """The non-negative fit's ``‖D a − z‖²`` of each block of columns ``designs[:, offsets[c]:offsets[c + 1]]``
    (a multi-atom form's coarse starts, :func:`processing.family_fit._start_costs`)."""
    count = offsets.size - 1
    out = np.empty(count)
    for c in range(count):
        _, out[c] = nonnegative_fit(np.ascontiguousarray(designs[:, offsets[c] : offsets[c + 1]]), target)
    return out


EXACT_SUMS = 2.0**51
"""Integers up to this magnitude are exact in float64, with room for the rounding of the bound's own check
(:func:`fold_grams`)."""


@njit(cache=True, fastmath={"reassoc", "contract"})
def fold_grams(values, features, channels, width, last, saturated, bounds):
    """Each fold's Gram matrix of integer block rows as stored (:meth:`processing.block_rows.BlockRows.stored_rows`):
    ``(grams, exact)``.

    ``values`` (≥ features rows, block row · channel · block column each), its first ``features`` rows taken as the
    channel statistics stack them — feature ``f · channels + c``, then a row of ``last`` — over the blocks of block
    rows ``bounds[j] … bounds[j + 1]`` for fold j, blocks saturated (``saturated``, (block rows, block columns))
    zeroed in every row: :func:`processing.channel_statistics._gram` of each fold's band of
    :meth:`~processing.block_rows.BlockRows.channel_rows`, without that transposing copy.

    The sums are reassociated (4 × 4 tiles of vector sums): the same numbers only where every partial sum is exact.
    For integer values (the caller's part: block sums of integer frames and their half differences) every partial
    sum of ``Σ x_i y_i`` is an integer of magnitude at most ``√(Σ x_i² Σ y_i²)`` (Cauchy–Schwarz), at most the
    larger diagonal entry: ``exact`` is True when every diagonal entry is at most :data:`EXACT_SUMS` — then these
    are the exact sums, which the BLAS route also gives. Else the caller takes that route.
    """
    size = features * channels + 1
    padded = (size + 3) // 4 * 4  # zero rows up to whole tiles: exact zeros in the padding
    folds = bounds.size - 1
    grams = np.zeros((folds, size, size))
    longest = 0
    for j in range(folds):
        longest = max(longest, (bounds[j + 1] - bounds[j]) * width)
    band = np.zeros((padded, longest))
    tile = np.zeros((padded, padded))
    for j in range(folds):
        first, stop = bounds[j], bounds[j + 1]
        count = (stop - first) * width
        for h in range(first, stop):
            base = (h - first) * width
            for f in range(features):
                for c in range(channels):
                    source = (h * channels + c) * width
                    row = f * channels + c
                    for w in range(width):
                        band[row, base + w] = 0.0 if saturated[h, w] else values[f, source + w]
            for w in range(width):
                band[size - 1, base + w] = 0.0 if saturated[h, w] else last
        for p in range(0, padded, 4):
            for q in range(p, padded, 4):
                s00 = s01 = s02 = s03 = s10 = s11 = s12 = s13 = 0.0
                s20 = s21 = s22 = s23 = s30 = s31 = s32 = s33 = 0.0
                for i in range(count):
                    x0, x1, x2, x3 = band[p, i], band[p + 1, i], band[p + 2, i], band[p + 3, i]
                    y0, y1, y2, y3 = band[q, i], band[q + 1, i], band[q + 2, i], band[q + 3, i]
                    s00 += x0 * y0
                    s01 += x0 * y1
                    s02 += x0 * y2
                    s03 += x0 * y3
                    s10 += x1 * y0
                    s11 += x1 * y1
                    s12 += x1 * y2
                    s13 += x1 * y3
                    s20 += x2 * y0
                    s21 += x2 * y1
                    s22 += x2 * y2
                    s23 += x2 * y3
                    s30 += x3 * y0
                    s31 += x3 * y1
                    s32 += x3 * y2
                    s33 += x3 * y3
                sums = ((s00, s01, s02, s03), (s10, s11, s12, s13), (s20, s21, s22, s23), (s30, s31, s32, s33))
                for u in range(4):
                    for v in range(4):
                        tile[p + u, q + v] = sums[u][v]
                        tile[q + v, p + u] = sums[u][v]
        for p in range(size):
            if not tile[p, p] <= EXACT_SUMS:  # also NaN
                return grams, False
        grams[j] = tile[:size, :size]
    return grams, True
