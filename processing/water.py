"""Underwater light: absorption and backscattering of natural waters, and the ambient at depth.

Public objects
--------------
- :class:`WaterBody`: the optically significant constituents of a water body (chlorophyll,
  CDOM, non-algal particles) and what follows from them: absorption ``a(λ)`` by component,
  backscattering ``b_b(λ)``, diffuse attenuation ``K_d(λ)``, path transmittances.
- :data:`WATER_TYPES`: named presets (``pure``, ``clear_ocean``, ``ocean``, ``coastal``, ``lake``).
- :func:`underwater_ambient`: daylight at depth ``z`` seen over ``distance_m`` of water, the
  ambient of the simulated underwater rig.
- :func:`flash_path_transmittance`: what a flash at the camera loses on its way to the subject
  and back.
- :func:`water_transmittance`: a path of pure water, ``exp(−a_w(λ) · d)`` (the paper's pool).

The model
---------
Absorption is the sum of four components, in 1/m (the model of the authors' underwater
simulations, hblasins/uwSim ``createAbsorptionCurve.m``, with measured tables in place of the
digitised ones)::

    a(λ) = a_w(λ)                         pure water, Pope & Fry (1997)
         + A_φ(λ) · Chl^E_φ(λ)            phytoplankton, Bricaud et al. (1998)
         + a_CDOM(440) · exp(−0.014 (λ − 440))      coloured dissolved organic matter
         + a_NAP(440) · exp(−0.011 (λ − 440))       non-algal particles (detritus, minerals)

with ``a_NAP(440) = 0.0124 · Chl^0.724`` (Bricaud et al. 1998) unless given. Backscattering is
pure water's half of ``b_w`` (Smith & Baker 1981) plus particles,
``b_bp(λ) = ratio · 0.416 · Chl^0.766 · 550/λ`` (particle scattering of Loisel & Morel 1998,
backscattering ratio ``particle_backscatter_ratio``, 1% by default).

Light from the sky at depth ``z`` (downwelling irradiance) decays as ``exp(−K_d z)`` with the
quasi-single-scattering approximation ``K_d ≈ (a + b_b) / μ_d`` (Gordon 1989; ``μ_d`` the mean
cosine of the downwelling light, 0.85 for a high sun). Light from the subject to the camera
over ``distance_m`` loses ``exp(−(a + b_b) d)``: forward-scattered light still forms the
(blurred) image, so only absorption and backscattering remove it.

Not modelled: the veiling light scattered into the line of sight (path radiance), which adds
a blue-green haze that grows with distance; inelastic scattering (Raman, fluorescence); the sun
angle beyond ``μ_d``; surface reflection and waves. These all matter for real dives; none
changes the point of the simulations (red is missing, and the flash can add it back).

References
----------
Pope R. M., Fry E. S. (1997), Appl. Opt. 36, 8710–8723. Bricaud A. et al. (1998), J. Geophys.
Res. 103(C13), 31033–31044. Smith R. C., Baker K. S. (1981), Appl. Opt. 20, 177–184. Loisel
H., Morel A. (1998), Limnol. Oceanogr. 43, 847–858. Gordon H. R. (1989), Limnol. Oceanogr. 34,
1389–1409. Mobley C. D. (1994), *Light and Water*, Academic Press.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid

CDOM_SLOPE_PER_NM = 0.014
"""Spectral slope of CDOM absorption, ``exp(−S (λ − 440))`` (uwSim; Bricaud et al. 1981)."""
NAP_SLOPE_PER_NM = 0.011
"""Spectral slope of non-algal particle absorption (Bricaud et al. 1998; uwSim)."""
ABSORPTION_COMPONENTS = ("water", "phytoplankton", "cdom", "nap")
"""Names of the absorption components, in the order :meth:`WaterBody.absorption` returns them."""

_LICENCE = (
    "Pope & Fry 1997 (published table); Bricaud 1998 via ocpy (BSD-3, processing/data/water/"
    "LICENSE-ocpy-BSD-3.txt); Smith & Baker 1981 via NASA OBPG (US government work)"
)


def _check(name: str, value: float, minimum: float = 0.0, strict: bool = False) -> float:
    value = float(value)
    ok = math.isfinite(value) and (value > minimum if strict else value >= minimum)
    if not ok:
        raise SpectralDataError(
            f"water: {name} is {value}; expected a finite value {'>' if strict else '≥'} {minimum:g}"
        )
    return value


def _table(relative: str, columns: tuple[str, ...]) -> Spectra:
    return datasets.load_spectra_csv(
        datasets.DATA_DIR / relative, "reflectance", "none", source=f"msflash data {relative}"
    ).select(list(columns))


def bricaud_1998(grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """Bricaud et al. (1998) coefficients ``Aphi, Ephi, Ap, Ep`` (``a = A · Chl^E``) on ``grid`` (within 400–700 nm)."""
    table = _table("water/bricaud_1998_aph_400_700_2nm.csv", ("Aphi", "Ephi", "Ap", "Ep"))
    return table.resample(grid).replace(metadata={"quantity": "Bricaud 1998 coefficients", "licence": _LICENCE})


def pure_water_scattering(grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
    """Pure-water scattering coefficient ``b_w(λ)`` in 1/m (Smith & Baker 1981), shape (n_wavelengths,)."""
    return _table("water/smith_baker_1981_bw_380_700_1nm.csv", ("b_w_per_m",)).resample(grid).values[:, 0]


def water_transmittance(path_m: float, grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """Transmittance ``exp(-a_w(λ) · path_m)`` of ``path_m`` metres of pure water, on ``grid``.

    Examples
    --------
    >>> t = water_transmittance(5.0)
    >>> bool(t.column("water_5m")[0] > t.column("water_5m")[-1])
    True
    """
    if not (math.isfinite(path_m) and path_m >= 0):
        raise SpectralDataError(f"water_transmittance: path_m is {path_m}; expected a finite length ≥ 0 m")
    absorption = datasets.water_absorption().resample(grid)
    return absorption.replace(
        values=np.exp(-absorption.values * path_m),
        names=(f"water_{path_m:g}m",),
        source=f"pure-water transmittance over {path_m:g} m (Pope & Fry 1997)",
        metadata={"quantity": "transmittance", "path_m": path_m},
    )


@dataclass(frozen=True)
class WaterBody:
    """A water body described by its constituents (all concentrations ≥ 0).

    Examples
    --------
    >>> pure = WaterBody(chlorophyll_mg_m3=0.0, cdom_440_per_m=0.0)
    >>> a = pure.total_absorption(WavelengthGrid(400, 700, 100))
    >>> bool(a[-1] > 10 * a[0])  # water absorbs red far more than blue
    True
    """

    chlorophyll_mg_m3: float = 0.5
    """Chlorophyll-a concentration (0.01 oligotrophic ocean … 10 coastal … 100 eutrophic lakes)."""
    cdom_440_per_m: float = 0.05
    """CDOM absorption at 440 nm (0–0.1 oceans, 0.1–0.5 lakes, up to ~10 rivers)."""
    nap_440_per_m: float | None = None
    """Non-algal particle absorption at 440 nm; None derives it from chlorophyll (Bricaud 1998)."""
    particle_backscatter_ratio: float = 0.01
    """Fraction of particle scattering that goes backwards (0.005–0.02 typical)."""
    mean_cosine: float = 0.85
    """Mean cosine ``μ_d`` of the downwelling light (1 = sun at zenith, no diffuse light)."""

    def __post_init__(self) -> None:
        _check("chlorophyll_mg_m3", self.chlorophyll_mg_m3)
        _check("cdom_440_per_m", self.cdom_440_per_m)
        if self.nap_440_per_m is not None:
            _check("nap_440_per_m", self.nap_440_per_m)
        _check("particle_backscatter_ratio", self.particle_backscatter_ratio)
        mu = _check("mean_cosine", self.mean_cosine, strict=True)
        if mu > 1:
            raise SpectralDataError(f"water: mean_cosine is {mu}; expected 0 < μ_d ≤ 1")

    @property
    def nap_440(self) -> float:
        """``a_NAP(440)`` in 1/m: the given value or ``0.0124 · Chl^0.724`` (Bricaud et al. 1998)."""
        if self.nap_440_per_m is not None:
            return float(self.nap_440_per_m)
        return 0.0124 * self.chlorophyll_mg_m3**0.724

    def absorption(self, grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
        """Absorption by component, 1/m, columns :data:`ABSORPTION_COMPONENTS`, shape (n_wavelengths, 4).

        Returned as unitless per-wavelength coefficients (``kind="reflectance"``, as
        :func:`processing.datasets.water_absorption`), ``metadata["quantity"]`` says what they are.
        """
        wavelengths = grid.wavelengths_nm
        water = datasets.water_absorption().resample(grid).values[:, 0]
        bricaud = bricaud_1998(grid)
        chl = self.chlorophyll_mg_m3
        phytoplankton = bricaud.column("Aphi") * chl ** bricaud.column("Ephi") if chl > 0 else np.zeros_like(water)
        cdom = self.cdom_440_per_m * np.exp(-CDOM_SLOPE_PER_NM * (wavelengths - 440.0))
        nap = self.nap_440 * np.exp(-NAP_SLOPE_PER_NM * (wavelengths - 440.0))
        return Spectra(
            grid,
            np.stack([water, phytoplankton, cdom, nap], axis=1),
            ABSORPTION_COMPONENTS,
            kind="reflectance",
            unit="none",
            source=f"absorption of {self.describe()}",
            metadata={"quantity": "absorption coefficient", "unit": "1/m", "licence": _LICENCE},
        )

    def total_absorption(self, grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
        """``a(λ)``, the sum of the components, 1/m, shape (n_wavelengths,)."""
        return self.absorption(grid).values.sum(axis=1)

    def backscattering(self, grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
        """``b_b(λ) = b_w/2 + ratio · 0.416 Chl^0.766 · 550/λ``, 1/m, shape (n_wavelengths,)."""
        particles = 0.416 * self.chlorophyll_mg_m3**0.766 * (550.0 / grid.wavelengths_nm)
        return 0.5 * pure_water_scattering(grid) + self.particle_backscatter_ratio * particles

    def path_attenuation(self, grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
        """``a + b_b``: what a path of water removes from image-forming light, 1/m."""
        return self.total_absorption(grid) + self.backscattering(grid)

    def diffuse_attenuation(self, grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
        """``K_d ≈ (a + b_b) / μ_d`` of the downwelling light (Gordon 1989), 1/m."""
        return self.path_attenuation(grid) / self.mean_cosine

    def transmittance(self, path_m: float, grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
        """``exp(−(a + b_b) · path_m)``: a horizontal path of water (subject → camera), one spectrum."""
        path_m = _check("path_m", path_m)
        return Spectra(
            grid,
            np.exp(-self.path_attenuation(grid) * path_m),
            (f"path_{path_m:g}m",),
            kind="reflectance",
            unit="none",
            source=f"{path_m:g} m of {self.describe()}",
            metadata={"quantity": "transmittance", "path_m": path_m},
        )

    def describe(self) -> str:
        """A one-line description for ``Spectra.source`` and reports."""
        return (
            f"water (Chl {self.chlorophyll_mg_m3:g} mg/m³, a_CDOM(440) {self.cdom_440_per_m:g}/m, "
            f"a_NAP(440) {self.nap_440:.3g}/m)"
        )


WATER_TYPES: dict[str, WaterBody] = {
    "pure": WaterBody(0.0, 0.0, 0.0, 0.0),
    "clear_ocean": WaterBody(0.05, 0.005),
    "ocean": WaterBody(0.5, 0.03),
    "coastal": WaterBody(3.0, 0.2),
    "lake": WaterBody(10.0, 0.5),
}
"""Named water bodies: ``pure`` (a swimming pool: water only), ``clear_ocean`` (oligotrophic),
``ocean`` (mesotrophic), ``coastal`` and ``lake`` (eutrophic, CDOM-rich)."""


def water_body(water: WaterBody | str) -> WaterBody:
    """A :class:`WaterBody` or the preset of that name (:data:`WATER_TYPES`)."""
    if isinstance(water, WaterBody):
        return water
    key = str(water).lower()
    if key not in WATER_TYPES:
        raise SpectralDataError(f"water type '{water}': unknown; expected one of {', '.join(WATER_TYPES)}")
    return WATER_TYPES[key]


def underwater_ambient(
    depth_m: float = 5.0,
    distance_m: float = 1.0,
    grid: WavelengthGrid = DEFAULT_GRID,
    water: WaterBody | str = "ocean",
) -> Spectra:
    """D65 daylight at ``depth_m`` as a camera ``distance_m`` from the subject sees it, energy, peak 1.

    ``E(λ) = E_0(λ) · exp(−K_d(λ) · depth_m) · exp(−(a + b_b)(λ) · distance_m)``. The second
    factor is the subject → camera path: it applies to every light the subject reflects, so a
    simulation that puts it in the ambient must give the flash the same path (twice, there and
    back: :func:`flash_path_transmittance`).

    Parameters
    ----------
    grid
        Within 400–700 nm, the Bricaud table's range.
    water
        A :data:`WATER_TYPES` name, or a :class:`WaterBody` of any constituents.

    Examples
    --------
    >>> ambient = underwater_ambient(5.0, 1.0)
    >>> wavelengths = ambient.wavelengths_nm
    >>> bool(ambient.values[wavelengths == 650, 0][0] < 0.2)  # red is mostly gone at 5 m
    True
    """
    body = water_body(water)
    depth_m = _check("depth_m", depth_m)
    distance_m = _check("distance_m", distance_m)
    surface = datasets.illuminant("D65", grid)
    factor = np.exp(-body.diffuse_attenuation(grid) * depth_m - body.path_attenuation(grid) * distance_m)
    return surface.replace(
        values=surface.values * factor[:, None],
        names=("underwater",),
        source=f"D65 at {depth_m:g} m depth, seen over {distance_m:g} m, in {body.describe()}",
        metadata={"depth_m": depth_m, "distance_m": distance_m, "water": body.describe()},
    ).normalised("max")


def flash_path_transmittance(
    distance_m: float, water: WaterBody | str = "ocean", grid: WavelengthGrid = DEFAULT_GRID
) -> Spectra:
    """``exp(−(a + b_b) · 2 · distance_m)``: a flash at the camera, to the subject and back."""
    return water_body(water).transmittance(2.0 * _check("distance_m", distance_m), grid)
