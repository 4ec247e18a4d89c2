"""One palette and one spectral unit for every plot msflash draws, and the one way a figure becomes a PNG.

Every plot (the run report, ``evaluate``, ``colour-study``, ``study``, ``local-study``) takes
its colours from :data:`PALETTE` and draws spectra in :data:`PLOT_UNIT`, named on the axis by
:func:`spectral_axis`, so the matching flash is the same orange and the complementary flash the
same blue in every figure, and a spectrum is never in photons in one plot and energy in the next.
The colours are Okabe & Ito's colour-blind-safe set (*Color Universal Design*, 2008); the other
series of a plot cycle through the same set (:data:`SERIES`).

Figures are written by :func:`figure_png` / :func:`save_figure` through
:mod:`acquisition.app.srgb_png` (PNG with the sRGB chunk).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.app.srgb_png import srgb_png_bytes
from msflash.processing.flash import FlashSolution
from msflash.processing.spectra import Spectra, SpectralUnit

SERIES = ("#0072B2", "#E69F00", "#009E73", "#CC79A7", "#56B4E9", "#D55E00", "#F0E442", "#000000")
"""Okabe & Ito's colours (blue, orange, bluish green, reddish purple, sky blue, vermillion, yellow, black)."""


@dataclass(frozen=True)
class Palette:
    """The colour of each thing msflash plots, the same in every figure."""

    ambient: str = "#009E73"
    """The ambient: its estimate, the ambient-only image's bar (bluish green)."""
    truth: str = "#000000"
    """The true ambient of a simulation (black, dashed)."""
    led_fit: str = "#7F7F7F"
    """The best non-negative LED fit of the truth (grey, dotted)."""
    matching: str = "#E69F00"
    """The matching flash (eq. 7) and what it gives (orange)."""
    complementary: str = "#0072B2"
    """The complementary flash (eq. 8–9) and what it gives (blue)."""
    ambient_plus_complementary: str = "#CC79A7"
    """Ambient + complementary flash, the light the scene is finally under (reddish purple)."""
    target: str = "#999999"
    """The complementary target illuminant (light grey, dotted)."""
    warning: str = "#D55E00"
    """Warnings, failures, the app's default point (vermillion)."""
    reference: str = "#56B4E9"
    """A published or reference figure beside msflash's own (the paper's numbers; sky blue)."""

    def of(self, name: str) -> str:
        """The colour of a named thing: ``ambient``, ``matching``, ``complementary``, ``matching-capture``, …

        A re-captured image (``…-capture``) has the colour of its mode; an unknown name is an error.

        Examples
        --------
        >>> PALETTE.of("complementary-capture") == PALETTE.complementary
        True
        """
        key = name.removesuffix("-capture").replace("-", "_")
        if key not in self.__dataclass_fields__:
            raise KeyError(f"palette: no colour for '{name}'; expected one of {', '.join(self.__dataclass_fields__)}")
        return str(getattr(self, key))


PALETTE = Palette()
"""The palette every plot uses."""

PLOT_UNIT: SpectralUnit = "energy"
"""The unit spectra are drawn in: radiometric (energy per wavelength), the usual one for illuminants."""
SPECTRAL_AXIS_LABEL = "relative spectral power (energy units)"
"""The y label of every spectrum plot."""
WAVELENGTH_AXIS_LABEL = "wavelength (nm)"
"""The x label of every spectrum plot."""

_STYLE: dict[str, Any] = {
    "figure.dpi": 100,
    "savefig.dpi": 150,
    "font.size": 10,
    "axes.titlesize": 11,
    "axes.labelsize": 10,
    "legend.fontsize": 8,
    "legend.framealpha": 0.85,
    "axes.grid": True,
    "grid.alpha": 0.3,
}


def pyplot() -> Any:
    """matplotlib.pyplot with the Agg backend and msflash's style (colour cycle, sizes, grid)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from cycler import cycler

    style: dict[str, Any] = {**_STYLE, "axes.prop_cycle": cycler(color=list(SERIES))}
    plt.style.use(style)
    return plt


def in_plot_unit(spectra: Spectra) -> np.ndarray:
    """The values of ``spectra`` in :data:`PLOT_UNIT`, shape (n_wavelengths, n)."""
    return spectra.to_unit(PLOT_UNIT).values


def spectral_axis(axis: Any, scaled_to: str | None = None) -> None:
    """Label a spectrum plot's axes: wavelength in nm, relative power in :data:`PLOT_UNIT` (and what is 1)."""
    axis.set_xlabel(WAVELENGTH_AXIS_LABEL)
    axis.set_ylabel(SPECTRAL_AXIS_LABEL + (f"\n1 = {scaled_to}" if scaled_to else ""))


def peak_of(values: np.ndarray) -> float:
    """The largest magnitude of ``values``, the 1 of a plot scaled to it (1 for an all-zero curve)."""
    return float(np.max(np.abs(values))) or 1.0


FLASH_MODES = ("matching", "complementary")
"""The flash mixes in the order every figure draws them (eq. 7, then eq. 8–9)."""


def draw_flash_mixes(
    axis: Any,
    wavelengths_nm: np.ndarray,
    led_values: np.ndarray,
    ambient: np.ndarray,
    solutions: dict[str, FlashSolution],
    target: np.ndarray | None,
    peak: float,
) -> None:
    """The flash-mix curves of every figure that shows them (the run's ``spectra.png``, ``evaluate``'s report).

    The ambient estimate; each flash mix ``I w_f`` (eq. 7 and eq. 8–9: the LED spectra at the solved
    weights, in :data:`FLASH_MODES` order, whatever the order of ``solutions``); the light the scene is
    finally under, ambient + complementary flash ``I (w_a + w_f)``; and the target least-squares scaled
    onto that sum (eq. 8 is scale-free), when given and not orthogonal to it. Every curve divided by
    ``peak``.

    Spectra are in :data:`PLOT_UNIT`: ``led_values`` (n_wavelengths, k) at full drive, ``ambient`` and ``target``
    (n_wavelengths,); ``solutions`` by mode (either may be missing); ``peak`` is 1 on the y axis.
    """
    axis.plot(wavelengths_nm, ambient / peak, color=PALETTE.ambient, lw=2, label="ambient (estimate)")
    for mode in FLASH_MODES:
        if mode in solutions:
            flash = led_values @ solutions[mode].flash_weights
            axis.plot(wavelengths_nm, flash / peak, color=PALETTE.of(mode), lw=1.8, label=f"{mode} flash")
    complementary = solutions.get("complementary")
    if complementary is None:
        return
    total = led_values @ (complementary.ambient_weights + complementary.flash_weights)
    axis.plot(
        wavelengths_nm,
        total / peak,
        color=PALETTE.ambient_plus_complementary,
        lw=2,
        ls="-.",
        label="ambient + complementary flash",
    )
    energy = float(target @ target) if target is not None else 0.0
    if target is None or not energy > 0:
        return
    axis.plot(
        wavelengths_nm,
        target * (float(total @ target) / energy) / peak,
        color=PALETTE.target,
        ls=":",
        lw=1.8,
        label="target (scaled to ambient + complementary)",
    )


def figure_rgb8(figure: Any) -> np.ndarray:
    """The figure drawn by Agg, (H, W, 3) uint8 (the white background made opaque)."""
    figure.canvas.draw()
    rgba = np.asarray(figure.canvas.buffer_rgba())
    return np.ascontiguousarray(rgba[:, :, :3])


def figure_png(figure: Any, dpi: float | None = None) -> bytes:
    """PNG bytes of ``figure`` at ``dpi`` (default ``savefig.dpi``) with the sRGB chunk; the figure is closed.

    The layout is the caller's (``tight_layout()`` or ``layout="constrained"``).
    """
    plt = pyplot()
    try:
        figure.set_dpi(dpi if dpi is not None else plt.rcParams["savefig.dpi"])
        return srgb_png_bytes(figure_rgb8(figure), {"Software": "msflash"})
    finally:
        plt.close(figure)


def save_figure(figure: Any, path: Path, dpi: float | None = None) -> Path:
    """Write ``figure`` as a PNG (:func:`figure_png`) to ``path``; return the path."""
    path = Path(path)
    path.write_bytes(figure_png(figure, dpi))
    return path
