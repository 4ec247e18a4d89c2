"""A reference of known reflectance in the scene — a grey card or a colour chart (issue 30, item 4).

Its patches hold every candidate spectrum to equations free of the reflectance estimate
(:class:`ReferencePatch`); ``--reference-patch`` / ``--reference-chart`` turn the family estimate into a
calibrated one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msflash.processing.channel_statistics import ChannelStatistics
from msflash.processing.errors import SpectralDataError
from msflash.processing.light_prior import plane_responsivities
from msflash.processing.scipy_cores import nnls
from msflash.processing.spectra import Spectra, require_unit
from msflash.processing.spectral_data_term import Whitened

PATCH_WEIGHT = 10.0
"""With a reference (:class:`ReferencePatch`), a candidate's evidence is ``√(held-out² + w · reference²)``, both
relative errors. Chosen on the physics suite's tuning rows with a 24-patch chart (docs/measurements.md)."""
PATCH_FIT_WEIGHT = 10.0
"""The calibrated estimate refits the chosen form's amplitudes with the reference's rows weighted to this multiple
of the whole image's data term (chosen on the same rows: docs/measurements.md)."""


@dataclass(frozen=True)
class ReferencePatch:
    """Regions of the scene of known reflectance — a grey or white card, or a colour chart's patches: a check free
    of the reflectance estimate (issue 30, item 4).

    A patch of reflectance r: its mean LED-only responses ``f̄_(c,i) = s Σ_λ C_c(λ) r(λ) I_i(λ)`` give its unknown
    gain s; its mean ambient response must then be ``ā_c = s Σ_λ C_c(λ) r(λ) e(λ)``: C equations every candidate
    spectrum e is held to, with no reflectance estimated. A flat card pins three camera numbers; a chart's patches,
    many more (:meth:`combined`).
    """

    design: np.ndarray
    """(P·C, n): ``s_p (C_c r_p)ᵀ`` — the patches' predicted ambient responses are ``design @ e``."""
    target: np.ndarray
    """(P·C,): the patches' measured mean ambient responses."""
    led_misfit: float
    """Largest relative misfit of a patch's ``f̄`` by ``s Σ C r I`` (large: the reflectance is not the one given, or
    the patch is not where it was said to be)."""

    @classmethod
    def of(
        cls,
        statistics: ChannelStatistics,
        led_spectra: Spectra,
        responsivities: Spectra,
        reflectance: np.ndarray | None = None,
    ) -> ReferencePatch:
        """From the channel statistics of one patch's pixels alone (:func:`processing.channel_statistics`) and its
        reflectance on the LEDs' grid (None: spectrally flat, a grey card)."""
        count = max(statistics.n_blocks, 1)
        led_mean = statistics.led_sums.sum(0).reshape(statistics.n_channels, statistics.n_leds) / count
        ambient_mean = statistics.ambient_sums.sum(0) / count
        planes = plane_responsivities(require_unit(responsivities, "photons"), statistics.channels)  # (n, C)
        if reflectance is not None:
            planes = planes * np.clip(np.asarray(reflectance, float), 0.0, None)[:, None]
        expected = planes.T @ require_unit(led_spectra, "photons").values  # (C, k)
        scale = float((led_mean * expected).sum() / max((expected * expected).sum(), 1e-300))
        misfit = float(np.linalg.norm(led_mean - scale * expected)) / max(float(np.linalg.norm(led_mean)), 1e-300)
        if not scale > 0:
            raise SpectralDataError(
                "reference patch: its LED images hold no light; expected a surface of known reflectance lit by the flash"
            )
        return cls(scale * planes.T, ambient_mean, misfit)

    @classmethod
    def combined(cls, patches: list[ReferencePatch]) -> ReferencePatch:
        """Several patches as one reference (their equations stacked)."""
        return cls(
            np.vstack([p.design for p in patches]),
            np.concatenate([p.target for p in patches]),
            max(p.led_misfit for p in patches),
        )

    def relative_error(self, spectrum: np.ndarray) -> float:
        """``‖ā − design e‖ / ‖ā‖`` for the best overall scale of e (spectra carry their own scales)."""
        predicted = self.design @ spectrum
        energy = float(predicted @ predicted)
        if not energy > 0:
            return 1.0
        fitted = predicted * float(predicted @ self.target) / energy
        return float(np.linalg.norm(self.target - fitted)) / max(float(np.linalg.norm(self.target)), 1e-300)

    def calibrate(self, problem: Whitened, atoms: np.ndarray) -> np.ndarray:
        """Non-negative amplitudes of ``atoms`` fitting the image's data term and, :data:`PATCH_FIT_WEIGHT` times as
        strongly, the patch."""
        norm = max(float(np.linalg.norm(self.target)), 1e-300)
        weight = math.sqrt(PATCH_FIT_WEIGHT * max(problem.energy, 1e-300))
        design = np.vstack([problem.root @ atoms, weight * (self.design @ atoms) / norm])
        target = np.concatenate([problem.target, weight * self.target / norm])
        scale = np.linalg.norm(design, axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        solution, _ = nnls(design / scale, target)
        return solution / scale
