"""Second moments with the noise taken out, kept positive definite: one rule for every solve that denoises.

The half-difference probe measures the noise's share ``N`` of a sample's second moments ``S`` (errors in
variables, :mod:`processing.statistics`); the solves use ``S − N``, which carries no noise bias. Where the
signal is weaker than the noise in some direction (a dim LED, two nearly collinear LED images, a dark scene)
``S − N`` can lose positive definiteness by the probe's own sampling error. :func:`noise_floored` raises each
such direction's eigenvalue to :data:`NOISE_FLOOR_SHARE` of the noise's along it: the solve stays defined,
the estimate is not thrown back to the biased observed moments, and a band that inverts the matrix widens
there. The LEDs' span floors its Gram matrix (:func:`processing.ambient.solved_statistics`), the light prior its
normal matrix (:func:`processing.light_prior.floored_normal_equations`).
"""

from __future__ import annotations

import numpy as np

from msflash.processing.scipy_cores import lapack

NOISE_FLOOR_SHARE = 0.1
"""A direction of the denoised moments whose eigenvalue falls below this share of the noise's along it (the images
hold less signal than noise there) is raised to it (:func:`noise_floored`)."""


def noise_floored(clean: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray, int] | None:
    """``clean = S − N`` with its noise-dominated directions raised, and how many; None when it is positive definite.

    Parameters
    ----------
    clean
        The denoised second moments ``S − N``, symmetric (n × n).
    noise
        The noise's share ``N`` that was removed, symmetric (n × n).

    Returns
    -------
    tuple of ndarray and int, or None
        None when ``clean``'s least eigenvalue is positive and above 10⁻¹² of its largest (use ``clean`` as it is);
        else ``V max(Λ, f) Vᵀ`` (symmetrised) with ``f = max(NOISE_FLOOR_SHARE · vᵀNv, 10⁻¹² λ_max)`` per
        eigenvector v, and the number of eigenvalues raised.
    """
    # The eigenvalues alone first (LAPACK's dsyevd without vectors: a third of eigh's cost at k ≈ 7, and most calls
    # end here); they agree with eigh's to rounding, so only a least eigenvalue within rounding of the test could
    # decide otherwise.
    eigenvalues, _, info = lapack.dsyevd(clean, compute_v=0, lower=1)
    if info == 0 and eigenvalues[0] > 0 and eigenvalues[0] > 1e-12 * eigenvalues[-1]:
        return None
    eigenvalues, vectors = np.linalg.eigh(clean)
    if eigenvalues[0] > 0 and eigenvalues[0] > 1e-12 * eigenvalues[-1]:
        return None
    noise_along = np.einsum("ji,jk,ki->i", vectors, noise, vectors)
    floor = np.maximum(NOISE_FLOOR_SHARE * noise_along, 1e-12 * max(float(eigenvalues[-1]), 1e-300))
    low = eigenvalues < floor
    raised = (vectors * np.where(low, floor, eigenvalues)) @ vectors.T
    return (raised + raised.T) / 2, int(np.count_nonzero(low))
