"""The paper's simulation illuminants: the smoothest non-negative spectrum with a given CIE xy.

For a chromaticity ``(x, y)`` the illuminant is the photon spectrum ``s`` on the grid that
minimises the roughness ``‖∇ s‖²`` (squared first differences) subject to ``s ≥ 0`` and to its CIE
1931 XYZ having that chromaticity::

    X − x (X + Y + Z) = 0,   Y − y (X + Y + Z) = 0,   X + Y + Z = 1   (normalisation)

with ``XYZ = Σ_λ cmf(λ) · e(λ)`` and ``e`` the energy spectrum of ``s`` (the CMFs weigh energy;
they are converted once to photon units with :meth:`Spectra.to_unit`). The equalities are
eliminated (``s = s₀ + N z`` with ``N`` a null-space basis) and the remaining inequality-
constrained quadratic is solved exactly by :func:`processing.least_squares.minimise_quadratic`.
A chromaticity is *feasible* when that programme has a solution, i.e. when ``(x, y)`` lies inside
the convex hull of the spectral locus sampled on the grid (400–700 nm).

The returned spectrum is scaled to peak 1.

Differences from the authors' ``xy2Spectrum.m``: they apply the energy CMFs directly to the
unknown vector, then convert the result with ``Quanta2Energy`` and use that as a photon
spectrum. Their illuminants therefore have a chromaticity somewhat off the requested grid point
(they evaluate against the computed xy, as we do) and a slightly different shape. The feasible
set is the same (a positive per-wavelength scaling does not change the cone of the CMFs). Pass
``convention="authors"`` to reproduce their construction.

References
----------
Blasinski H., Farrell J. "Computational multispectral flash", ICCP 2017, Section 5;
hblasins/compMultispFlash ``Utilities/xy2Spectrum.m``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np

from msflash.processing import datasets
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.least_squares import minimise_quadratic
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid

Convention = Literal["exact", "authors"]

PAPER_XY_STEPS = 10
"""The paper samples x and y each on ``linspace(0, 1, 10)``."""

PAPER_FEASIBLE_COUNT = 23
"""Feasible points of that grid according to the paper."""


@lru_cache(maxsize=8)
def _cmfs(grid: WavelengthGrid) -> Spectra:
    """CIE 1931 2° colour-matching functions on ``grid`` (energy responsivities), cached."""
    return datasets.cie1931_cmfs(grid)


def cmfs_photons(grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
    """The CIE 1931 CMFs weighing *photon* spectra on ``grid``, shape (n_wavelengths, 3).

    ``cmfs_photons(grid).T @ s`` is proportional to the XYZ of the photon spectrum ``s``.
    """
    return _cmfs(grid).to_unit("photons").values


def xy_of(spectra: np.ndarray, grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
    """CIE 1931 xy of photon spectra, shape (..., 2) for input (n_wavelengths,) or (n_wavelengths, n).

    A spectrum with ``X + Y + Z = 0`` gets NaN.

    Examples
    --------
    >>> from msflash.processing.spectra import energy_to_photons
    >>> equal_energy = energy_to_photons(np.ones(31), DEFAULT_GRID.wavelengths_nm)
    >>> np.round(xy_of(equal_energy), 2).tolist()  # illuminant E on a 10 nm grid
    [0.33, 0.33]
    """
    values = np.asarray(spectra, dtype=float)
    xyz = cmfs_photons(grid).T @ values  # (3,) or (3, n)
    total = xyz.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        xy = xyz[:2] / np.where(total != 0, total, np.nan)
    return xy.T


@dataclass(frozen=True)
class SmoothIlluminant:
    """A smoothest spectrum for a requested chromaticity."""

    requested_xy: tuple[float, float]
    """The chromaticity asked for."""
    xy: tuple[float, float]
    """The chromaticity of the returned spectrum (equal to ``requested_xy`` for ``"exact"``)."""
    spectrum: Spectra
    """Photon spectrum, peak 1, on the grid."""


def _smoothest_vector(weights: np.ndarray, x: float, y: float) -> np.ndarray | None:
    """argmin ‖∇ s‖² s.t. s ≥ 0 and ``weights.T @ s`` has chromaticity (x, y), sum 1; None if infeasible."""
    n = weights.shape[0]
    big_x, big_y, big_z = weights.T
    total = big_x + big_y + big_z
    equalities = np.vstack([big_x - x * total, big_y - y * total, total])
    rhs = np.array([0.0, 0.0, 1.0])
    # Particular solution and null-space basis of the 3 equalities (SVD: exact and well scaled).
    particular = np.linalg.lstsq(equalities, rhs, rcond=None)[0]
    _, singular, vt = np.linalg.svd(equalities)
    rank = int(np.sum(singular > 1e-12 * singular[0]))
    if rank < 3:
        return None  # x + y = 1 with z̄ ≡ 0 etc.: degenerate, no positive XYZ with that chromaticity
    null = vt[rank:].T  # (n, n - 3)
    difference = np.diff(np.eye(n), axis=0)
    hessian = null.T @ difference.T @ difference @ null
    linear = -null.T @ difference.T @ difference @ particular
    scale = float(np.trace(hessian) / hessian.shape[0])
    try:
        solution = minimise_quadratic(
            hessian / scale, linear / scale, null, -particular, where=f"smoothest spectrum for xy=({x:.4f}, {y:.4f})"
        )
    except SolverError:
        return None
    spectrum = particular + null @ solution.x
    spectrum = np.clip(spectrum, 0.0, None)
    return spectrum if spectrum.max() > 0 else None


def smoothest_spectrum(
    x: float, y: float, grid: WavelengthGrid = DEFAULT_GRID, convention: Convention = "exact"
) -> SmoothIlluminant | None:
    """The smoothest non-negative photon spectrum with CIE 1931 chromaticity ``(x, y)``, or None.

    Parameters
    ----------
    x, y
        The chromaticity.
    grid
        The wavelength grid.
    convention
        ``"exact"`` (default): the photon spectrum's true xy is ``(x, y)``. ``"authors"``: the
        construction of ``xy2Spectrum.m`` (energy CMFs on the unknown, result ÷ λ used as
        photons), whose xy differs from the request.

    Returns
    -------
    SmoothIlluminant or None
        None when no non-negative spectrum on the grid has that chromaticity.

    Examples
    --------
    >>> result = smoothest_spectrum(1 / 3, 1 / 3)
    >>> bool(np.allclose(result.xy, (1 / 3, 1 / 3)))
    True
    >>> smoothest_spectrum(0.0, 0.0) is None
    True
    """
    if not (np.isfinite(x) and np.isfinite(y)):
        raise SpectralDataError(f"smoothest spectrum: xy=({x}, {y}); expected finite numbers")
    if convention == "exact":
        weights = cmfs_photons(grid)
    elif convention == "authors":
        weights = _cmfs(grid).values
    else:
        raise SpectralDataError(f"smoothest spectrum: convention '{convention}'; expected exact or authors")
    vector = _smoothest_vector(weights, float(x), float(y))
    if vector is None:
        return None
    if convention == "authors":
        vector = vector / grid.wavelengths_nm  # Quanta2Energy, then used as a photon spectrum
    vector = vector / vector.max()
    xy = xy_of(vector, grid)
    spectrum = Spectra(
        grid,
        vector,
        (f"smooth_xy_{x:.3f}_{y:.3f}",),
        kind="spd",
        unit="photons",
        source=f"smoothest spectrum with xy=({x:.4f}, {y:.4f}) [{convention}]",
    )
    return SmoothIlluminant(requested_xy=(float(x), float(y)), xy=(float(xy[0]), float(xy[1])), spectrum=spectrum)


@lru_cache(maxsize=8)
def feasible_grid(
    steps: int = PAPER_XY_STEPS, grid: WavelengthGrid = DEFAULT_GRID, convention: Convention = "exact"
) -> tuple[SmoothIlluminant, ...]:
    """The smoothest spectra of every feasible point of ``linspace(0,1,steps)²`` (x outer, y inner).

    The paper reports 23 feasible points for ``steps=10``; on the 400–700/10 nm grid we find 23
    too. Cached (the 100 small programmes take about two seconds).
    """
    values = np.linspace(0.0, 1.0, steps)
    result = []
    for x in values:
        for y in values:
            illuminant = smoothest_spectrum(float(x), float(y), grid, convention)
            if illuminant is not None:
                result.append(illuminant)
    return tuple(result)
