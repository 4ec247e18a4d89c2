"""The data term of any ambient spectrum, through the light prior's sufficient statistics (issue 30, item 2).

The light prior's prediction ``â_b = K(e) f_b`` (module notes of :mod:`processing.light_prior`) is linear in e, so
with ``K_λ`` the predictor of the unit spectrum at wavelength λ the data term of any spectrum is the quadratic form

    J(e) = Σ_b ‖a_b − K(e) f_b‖² = E − 2 gᵀ e + eᵀ H e,   H[λ,μ] = tr(K_λᵀ K_μ S_ff),  g[λ] = tr(K_λ S_fa),

per fold of block rows, with the noise's share beside it (:class:`SceneForm`). The predictors factor exactly
through r ≪ n coordinates (:class:`Reduction`), so every fit works on an r × r form, in least-squares form
(:class:`Whitened`) for the non-negative fits of :mod:`processing.family_fit`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msflash.processing.channel_statistics import ChannelStatistics, Moments
from msflash.processing.errors import SpectralDataError
from msflash.processing.light_prior import (
    RIDGE,
    ReflectanceBasis,
    learn_reflectance_basis,
    light_predictors,
    plane_responsivities,
)
from msflash.processing.scipy_cores import NNLS_CORE, lapack, nnls
from msflash.processing.spectra import Spectra, require_unit


@dataclass(frozen=True)
class Reduction:
    """``K(e) = Σ_q (L e)_q A_q``: the predictors of the unit spectra factored through r ≪ n coordinates.

    The prediction depends on e only through the LED weights of its in-span part (k numbers) and, for each
    plane, the projections of its remainder weighted by the plane's responsivity onto the reflectance basis
    (C·p numbers): r ≤ k + C·p. The data term is then an r × r form (module notes), and no product of the
    n × n size (which OpenBLAS runs threaded, at a cost far above the work on a busy machine) is needed.
    """

    lift: np.ndarray
    """L (r, n): spectrum → coordinates."""
    shapes: np.ndarray
    """A (r, C, C·k): each coordinate's predictor."""


def reduce_predictors(predictors: np.ndarray) -> Reduction:
    """The exact low-rank factorisation ``K_flat = Lᵀ A_flat`` of :func:`unit_predictors`'s (n, C, C·k) array."""
    n, channels, width = predictors.shape
    flat = predictors.reshape(n, channels * width)
    left, singular, right = np.linalg.svd(flat, full_matrices=False)
    rank = int(np.count_nonzero(singular > singular[0] * 1e-10)) if singular.size and singular[0] > 0 else 0
    lift = (left[:, :rank] * singular[:rank]).T
    return Reduction(np.ascontiguousarray(lift), right[:rank].reshape(rank, channels, width))


@dataclass(frozen=True)
class SceneForm:
    """The data term ``J(e) = E − 2 gᵀ(Le) + (Le)ᵀ H (Le)`` of a scene, per fold, in reduced coordinates.

    Arrays carry a leading fold axis; ``noise_*`` are the noise's share (half-difference probe), zero when
    not measured. Scaled so that the total observed ambient energy is 1.
    """

    hessian: np.ndarray
    linear: np.ndarray
    energy: np.ndarray
    noise_hessian: np.ndarray
    noise_linear: np.ndarray
    noise_energy: np.ndarray
    counts: np.ndarray
    lift: np.ndarray
    """L (r, n)."""

    def part(self, folds: list[int], denoised: bool = True) -> tuple[np.ndarray, np.ndarray, float]:
        """``(H, g, E)`` summed over ``folds`` (noise removed when ``denoised``)."""
        hessian, linear, energy = self._sums(np.asarray(folds, dtype=np.intp), denoised)
        return hessian, linear, float(energy)

    def _sums(self, folds: np.ndarray, denoised: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(H, g, E)`` summed over the last axis of the fold indices ``folds`` — one set (1-D) or one per row
        (2-D) —, noise removed when ``denoised``, H symmetrised."""
        axis = folds.ndim - 1
        h = self.hessian[folds].sum(axis)
        g = self.linear[folds].sum(axis)
        e = self.energy[folds].sum(axis)
        if denoised:
            h = h - self.noise_hessian[folds].sum(axis)
            g = g - self.noise_linear[folds].sum(axis)
            e = e - self.noise_energy[folds].sum(axis)
        return 0.5 * (h + np.swapaxes(h, -1, -2)), g, e

    def whitened(self, folds: list[int], denoised: bool = True) -> Whitened:
        """The folds' data term as a :class:`Whitened` problem."""
        return Whitened.of(*self.part(folds, denoised), self.lift)

    def complements(self) -> dict[int, Whitened]:
        """Each non-empty fold's complement, denoised, as a :class:`Whitened` problem: ``whitened`` of every other
        fold, to the bit (the same sums in the same order: a reduction over the kept folds' axis adds them in turn),
        with the sums of all complements taken at once."""
        count = self.n_folds
        keep = np.array([[f for f in range(count) if f != fold] for fold in range(count)], dtype=np.intp)
        hessians, linears, energies = self._sums(keep, denoised=True)
        return {
            fold: Whitened.of(hessians[fold], linears[fold], float(energies[fold]), self.lift)
            for fold in range(count)
            if self.counts[fold] > 0
        }

    def error(self, folds: list[int], spectrum: np.ndarray, denoised: bool = True) -> float:
        """J(e) of ``folds`` (:meth:`whitened`'s ``error`` without its eigendecomposition)."""
        hessian, linear, energy = self.part(folds, denoised)
        y = self.lift @ spectrum
        return float(energy - 2 * linear @ y + y @ hessian @ y)

    def fold_error(self, fold: int, spectrum: np.ndarray) -> tuple[float, float]:
        """``(J, J of the noise alone)`` of one fold as observed."""
        y = self.lift @ spectrum
        observed = self.energy[fold] - 2 * self.linear[fold] @ y + y @ self.hessian[fold] @ y
        noise = self.noise_energy[fold] - 2 * self.noise_linear[fold] @ y + y @ self.noise_hessian[fold] @ y
        return float(observed), float(noise)

    @property
    def n_folds(self) -> int:
        """Folds of block rows."""
        return int(self.counts.size)


def unit_predictors(
    led_spectra: Spectra,
    responsivities: Spectra,
    channels: tuple[str, ...],
    reflectance: ReflectanceBasis | None = None,
    ridge: float = RIDGE,
) -> np.ndarray:
    """``K_λ`` (n, C, C·k): the light prior's predictors of the unit spectra on the LEDs' grid."""
    led = require_unit(led_spectra, "photons")
    camera = require_unit(responsivities, "photons")
    if not camera.grid.same_as(led.grid):
        raise SpectralDataError(f"light families: responsivities on {camera.grid} but LEDs on {led.grid}")
    reflectance = learn_reflectance_basis(led.grid) if reflectance is None else reflectance
    planes = plane_responsivities(camera, channels)
    return light_predictors(led.values, planes, np.eye(led.grid.size), reflectance, ridge, True)


def scene_form(statistics: ChannelStatistics, reduction: Reduction) -> SceneForm:
    """The scene's :class:`SceneForm` from its channel statistics and the model's :class:`Reduction`."""
    shapes = reduction.shapes
    rank, channels, width = shapes.shape
    stacked = shapes.reshape(rank * channels, width)
    flat_t = shapes.reshape(rank, -1).T

    def terms(moments: Moments) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # H_f[q,s] = Σ_c A_q,c S_ff,f A_s,cᵀ ; g_f[q] = Σ_c,l A[q,c,l] S_fa,f[l,c] ; E_f = tr S_aa,f
        # (as products, not einsum's loops: slower on these shapes, docs/measurements.md)
        folds = moments.ff.shape[0]
        products = np.matmul(stacked, moments.ff).reshape(folds, rank, channels * width)
        hessian = products @ flat_t
        linear = moments.fa.transpose(0, 2, 1).reshape(folds, channels * width) @ flat_t
        energy = np.trace(moments.aa, axis1=1, axis2=2)
        return hessian, linear, energy

    h, g, e = terms(statistics.moments)
    if statistics.noise is not None:
        nh, ng, ne = terms(statistics.noise)
    else:
        nh, ng, ne = np.zeros_like(h), np.zeros_like(g), np.zeros_like(e)
    scale = float(e.sum())
    scale = scale if scale > 0 else 1.0
    return SceneForm(
        h / scale, g / scale, e / scale, nh / scale, ng / scale, ne / scale, statistics.counts, reduction.lift
    )


@dataclass(frozen=True)
class Whitened:
    """``J(e) = ‖R e − z‖² + c`` with ``R = Λ^½ Vᵀ L``: a fold set's data term in least-squares form."""

    root: np.ndarray
    """R (r, n)."""
    target: np.ndarray
    constant: float
    hessian: np.ndarray
    """H (r, r), reduced coordinates."""
    linear: np.ndarray
    energy: float
    lift: np.ndarray

    @classmethod
    def of(cls, hessian: np.ndarray, linear: np.ndarray, energy: float, lift: np.ndarray) -> Whitened:
        """From ``(H, g, E)`` and L; eigenvalues of H below 10⁻⁹ of the largest are raised to it."""
        # scipy's LAPACK directly: numpy's eigh wakes OpenBLAS's threads (docs/measurements.md).
        values, vectors, info = lapack.dsyevd(np.ascontiguousarray(hessian), compute_v=1, lower=1)
        if info != 0:
            values, vectors = np.linalg.eigh(hessian)
        floor = max(float(values[-1]), 1e-300) * 1e-9
        roots = np.sqrt(np.maximum(values, floor))
        root = (roots[:, None] * vectors.T) @ lift
        target = (vectors.T @ linear) / roots
        return cls(root, target, float(energy - target @ target), hessian, linear, energy, lift)

    def error(self, spectrum: np.ndarray) -> float:
        """J(e)."""
        y = self.lift @ spectrum
        return float(self.energy - 2 * self.linear @ y + y @ self.hessian @ y)

    def information(self, jacobian: np.ndarray) -> np.ndarray:
        """``Dᵀ H_e D`` for spectra derivatives D (n, P)."""
        reduced = self.lift @ jacobian
        return reduced.T @ self.hessian @ reduced

    def amplitudes(self, atoms: np.ndarray) -> tuple[np.ndarray, float]:
        """Non-negative amplitudes minimising J(B a), and J."""
        amplitudes, norm2 = nonnegative_fit(self.root @ atoms, self.target)
        return amplitudes, norm2 + self.constant

    def residual(self, atoms: np.ndarray) -> np.ndarray:
        """``R B a − z`` at the non-negative amplitudes (variable projection: J = ‖residual‖² + c)."""
        design = self.root @ atoms
        amplitudes, _ = nonnegative_fit(design, self.target)
        return design @ amplitudes - self.target


def nonnegative_fit(design: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, float]:
    """``argmin ‖D a − z‖², a ≥ 0`` and the squared residual, columns scaled to unit norm first.

    One column in closed form; more by the NNLS core directly (:mod:`processing.scipy_cores`): the fits call this
    tens of thousands of times on problems of ~30 × ≤ 12, where the public wrapper's checks cost more than the
    solve (docs/measurements.md). Non-finite designs have no fit: zero amplitudes, infinite residual.
    """
    columns = design.shape[1]
    if columns == 1:
        column = design[:, 0]
        energy = float(column @ column)
        projection = float(column @ target)
        if not (energy > 0 and math.isfinite(energy) and math.isfinite(projection)):
            return np.zeros(1), math.inf if not math.isfinite(energy) else float(target @ target)
        amplitude = max(projection, 0.0) / energy
        return np.array([amplitude]), max(float(target @ target) - amplitude * projection, 0.0)
    norms = np.sqrt(np.einsum("ij,ij->j", design, design))
    if not math.isfinite(float(norms.sum())):
        return np.zeros(columns), math.inf
    scale = np.where(norms > 0, norms, 1.0)
    scaled = design / scale
    if NNLS_CORE is not None:
        solution, norm, info = NNLS_CORE(scaled, target, 3 * columns)
        if info != 3:
            return solution / scale, float(norm) ** 2
    solution, norm = nnls(scaled, target, 30 * columns)
    return solution / scale, norm * norm
