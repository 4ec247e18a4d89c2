"""The generative families' spectral forms (issue 30, item 2): how each kind of light is made.

``thermal``: a blackbody or CIE daylight. ``discharge``: known lines and lamp-phosphor bands, a dictionary
(:func:`discharge_atoms`). ``solid_state``: emission bands as LEDs are made (:data:`SOLID_STATE`).
``transmitted``: daylight through water ``D(CCT) exp(−τ_w a_w − τ_g e^{−0.014(λ−440)} − τ_p a_φ)``, or a thermal
source through a filter of smooth optical density ``B(T) exp(−(b₁ x + b₂ x²))``. ``mixture``: two of them
(:func:`processing.family_fit.fit_mixture`). The table with every atom: docs/light-families.md.

Every form gives the ambient as ``e = B(θ) a``: non-negative atoms B (photons, on the sequence's grid) with
non-negative amplitudes a and few nonlinear parameters θ (:class:`Form`); :data:`FORMS` lists the parametric ones.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

from msflash.processing import datasets
from msflash.processing.spectra import WavelengthGrid

C2_NM_K = 1.4388e7
"""Second radiation constant, nm·K."""
KINDS = FIXED, BLACKBODY, DAYLIGHT, BANDS, UNDERWATER, FILTER = 0, 1, 2, 3, 4, 5
"""The kinds of form the compiled refinement knows (:mod:`processing.family_kernels`): fixed atoms (the discharge
dictionary's chosen atoms, no θ), a blackbody, CIE daylight, emission bands (centres then FWHMs), daylight under
water, a filtered blackbody."""
NONE = -1
"""No second part (a form alone), or a form the compiled refinement does not know."""

# Known emission lines (nm, air; NIST Atomic Spectra Database) and phosphor line groups (relative heights).
LINES: dict[str, tuple[tuple[float, float], ...]] = {
    "Hg 405": ((404.66, 1.0), (407.78, 0.1)),
    "Hg 436": ((435.83, 1.0),),
    "Hg 546": ((546.07, 1.0),),
    "Hg 577/579": ((576.96, 1.0), (579.07, 1.0)),
    "Na 589": ((588.99, 1.0), (589.59, 0.5)),
    "Tl 535": ((535.05, 1.0),),
    "In 451/410": ((451.13, 1.0), (410.18, 0.6)),
    "Li 671": ((670.78, 1.0),),
    "Tb³⁺ 543": ((543.0, 1.0), (488.0, 0.25), (584.0, 0.12), (620.0, 0.07)),
    "Eu³⁺ 611": ((611.0, 1.0), (587.0, 0.08), (593.0, 0.1), (599.0, 0.06), (627.0, 0.15), (650.0, 0.04), (707.0, 0.06)),
}
"""Line atoms of the discharge family."""
BROAD_BANDS: dict[str, tuple[float, float]] = {
    "BAM 450": (450.0, 50.0),
    "Sb³⁺ 480": (480.0, 110.0),
    "Mn²⁺ 580": (580.0, 80.0),
    "Na broadened 30": (589.3, 30.0),
    "Na broadened 60": (589.3, 60.0),
}
"""Broad atoms of the discharge family: (centre, FWHM) nm — lamp phosphors and high-pressure sodium."""


# -- spectral shapes on a grid ------------------------------------------------------------------------
@lru_cache(maxsize=16)
def _nm(grid: WavelengthGrid) -> np.ndarray:
    """The grid's wavelengths, computed once (the forms evaluate their shapes thousands of times a scene)."""
    wavelengths = grid.wavelengths_nm
    wavelengths.flags.writeable = False
    return wavelengths


def _photons(wavelengths: np.ndarray, energy: np.ndarray) -> np.ndarray:
    """Energy → photons (∝ λ; the scale is immaterial: amplitudes are free)."""
    return energy * (wavelengths / 555.0)[:, None] if energy.ndim == 2 else energy * wavelengths / 555.0


def planck(wavelengths: np.ndarray, kelvin: float) -> np.ndarray:
    """Planck's law (energy per nm), 1 at 560 nm."""
    kelvin = max(float(kelvin), 100.0)
    return (
        (560.0 / wavelengths) ** 5
        * math.expm1(min(C2_NM_K / (kelvin * 560.0), 700.0))
        / np.expm1(np.minimum(C2_NM_K / (kelvin * wavelengths), 700.0))
    )


@lru_cache(maxsize=8)
def _daylight_basis(grid: WavelengthGrid) -> np.ndarray:
    import colour

    basis = colour.colorimetry.SDS_BASIS_FUNCTIONS_CIE_ILLUMINANT_D_SERIES
    nm = _nm(grid)
    return np.column_stack([np.interp(nm, basis[n].wavelengths, basis[n].values) for n in ("S0", "S1", "S2")])


def daylight_weights(cct: float) -> tuple[float, float]:
    """CIE 15's M1, M2 of daylight at ``cct`` (clamped to 4000–25000 K): the chromaticity of the daylight locus,
    then the weights of the S1, S2 basis. Plain arithmetic, so the compiled fits compile this same function."""
    t = min(max(float(cct), 4000.0), 25000.0) * 1.4388 / 1.4380
    if t <= 7000:
        x = -4.6070e9 / t**3 + 2.9678e6 / t**2 + 0.09911e3 / t + 0.244063
    else:
        x = -2.0064e9 / t**3 + 1.9018e6 / t**2 + 0.24748e3 / t + 0.237040
    y = -3.0 * x * x + 2.87 * x - 0.275
    m = 0.0241 + 0.2562 * x - 0.7341 * y
    return (-1.3515 - 1.7703 * x + 5.9114 * y) / m, (0.0300 - 31.4424 * x + 30.0717 * y) / m


def daylight(grid: WavelengthGrid, cct: float) -> np.ndarray:
    """CIE daylight at ``cct`` (energy; :func:`daylight_weights`), clipped at 0."""
    m1, m2 = daylight_weights(cct)
    return np.clip(_daylight_basis(grid) @ np.array([1.0, m1, m2]), 0.0, None)


def band(grid: WavelengthGrid, centre: float, fwhm: float) -> np.ndarray:
    """A Gaussian emission band seen through the grid's triangular slit (its variance adds step²/6), peak 1."""
    sigma2 = (max(fwhm, 1e-3) / 2.3548) ** 2 + grid.step_nm**2 / 6.0
    return np.exp(-0.5 * (_nm(grid) - centre) ** 2 / sigma2)


def line(grid: WavelengthGrid, centre: float) -> np.ndarray:
    """A line narrower than the grid step, as a spectroradiometer of that bandwidth reports it (unit area)."""
    return np.clip(1.0 - np.abs(_nm(grid) - centre) / grid.step_nm, 0.0, None)


@lru_cache(maxsize=8)
def _water_shapes(grid: WavelengthGrid) -> np.ndarray:
    """(n, 3): pure-water absorption a_w (Pope & Fry; beyond 700 nm rising as water's does towards its 740-nm
    band), CDOM ``e^{−0.014 (λ−440)}``, phytoplankton ``A_φ`` (Bricaud 1998, edge values outside 400–700 nm)."""
    from msflash.processing.water import bricaud_1998

    nm = _nm(grid)
    table = datasets.water_absorption()
    a_w = np.interp(nm, table.wavelengths_nm, table.values[:, 0])
    beyond = nm > table.wavelengths_nm[-1]
    a_w[beyond] = np.minimum(table.values[-1, 0] * np.exp((nm[beyond] - table.wavelengths_nm[-1]) / 35.0), 2.5)
    phyto = bricaud_1998(WavelengthGrid(400.0, 700.0, 2.0))
    a_phi = np.interp(nm, phyto.wavelengths_nm, phyto.column("Aphi"))
    return np.column_stack([a_w, np.exp(-0.014 * (nm - 440.0)), a_phi / a_phi.max()])


@lru_cache(maxsize=8)
def kernel_grid(grid: WavelengthGrid) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """What the compiled forms need of a grid (:mod:`processing.family_kernels`): the wavelengths, the slit's
    variance (step²/6), the daylight basis and the water shapes (C-ordered float64)."""
    return (
        np.ascontiguousarray(_nm(grid), float),
        grid.step_nm**2 / 6.0,
        np.ascontiguousarray(_daylight_basis(grid), float),
        np.ascontiguousarray(_water_shapes(grid), float),
    )


# -- forms ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Form:
    """One generative form: ``e = B(θ) a`` with non-negative atoms and amplitudes.

    ``atoms(grid, θ)`` gives B (photons, n × m); θ has :attr:`parameters` names, :attr:`bounds` and a coarse
    grid of :attr:`starts` searched before refinement (an empty θ: the atoms are fixed).
    """

    name: str
    family: str
    parameters: tuple[str, ...]
    bounds: tuple[tuple[float, float], ...]
    starts: tuple[tuple[float, ...], ...]
    atoms: Callable[[WavelengthGrid, np.ndarray], np.ndarray] = field(compare=False)
    atom_names: tuple[str, ...] = ()
    tangent: Callable[[WavelengthGrid, np.ndarray, np.ndarray], np.ndarray] | None = field(default=None, compare=False)
    """``∂(B(θ) a)/∂θ`` (n × P) in closed form, or None: forward differences of the atoms (:func:`refine`)."""
    kind: int = field(default=NONE, compare=False)
    """The compiled refinement's kind of this form (:data:`KINDS`), or ``NONE``."""

    def describe(self, theta: np.ndarray) -> dict[str, float]:
        """The nonlinear parameters in physical units (temperatures in K rather than their logarithm)."""
        out = {}
        for name, value in zip(self.parameters, theta):
            if name.startswith("log_"):
                out[name[4:]] = float(math.exp(value))
            else:
                out[name] = float(value)
        return out


def _thermal_forms() -> list[Form]:
    temperatures = tuple((math.log(t),) for t in np.geomspace(1200, 20000, 24))
    daylights = tuple((math.log(t),) for t in np.geomspace(4000, 25000, 14))
    return [
        Form(
            "blackbody",
            "thermal",
            ("log_kelvin",),
            ((math.log(800.0), math.log(30000.0)),),
            temperatures,
            lambda grid, th: _photons(_nm(grid), planck(_nm(grid), math.exp(th[0])))[:, None],
            tangent=lambda grid, th, a: (
                _photons(_nm(grid), planck(_nm(grid), math.exp(th[0])) * planck_log_slope(_nm(grid), math.exp(th[0])))
                * a[0]
            )[:, None],
            kind=BLACKBODY,
        ),
        Form(
            "daylight",
            "thermal",
            ("log_cct",),
            ((math.log(4000.0), math.log(25000.0)),),
            daylights,
            lambda grid, th: _photons(_nm(grid), daylight(grid, math.exp(th[0])))[:, None],
            kind=DAYLIGHT,
        ),
    ]


@lru_cache(maxsize=8)
def discharge_atoms(grid: WavelengthGrid) -> tuple[np.ndarray, tuple[str, ...]]:
    """The discharge family's dictionary (photons, n × atoms) and the atoms' names: lines, phosphor and sodium
    bands, and a warm continuum (Planck at 3000 K: a lamp's hot electrodes and recombination)."""
    nm = _nm(grid)
    columns, names = [], []
    for name, group in LINES.items():
        columns.append(sum(height * line(grid, centre) for centre, height in group))
        names.append(name)
    for name, (centre, fwhm) in BROAD_BANDS.items():
        columns.append(band(grid, centre, fwhm))
        names.append(name)
    columns.append(planck(nm, 3000.0))
    names.append("continuum 3000 K")
    atoms = _photons(nm, np.column_stack(columns))
    atoms = atoms / np.maximum(atoms.max(axis=0), 1e-300)
    keep = atoms.max(axis=0) > 0
    return atoms[:, keep], tuple(n for n, k in zip(names, keep) if k)


SOLID_STATE: dict[str, tuple[tuple[tuple[float, float], tuple[float, float]], ...]] = {
    "phosphor white": (((400.0, 480.0), (12.0, 40.0)), ((500.0, 620.0), (50.0, 140.0))),
    "phosphor white + red": (
        ((400.0, 480.0), (12.0, 40.0)),
        ((500.0, 600.0), (50.0, 140.0)),
        ((590.0, 680.0), (40.0, 120.0)),
    ),
    "RGB": (((430.0, 490.0), (12.0, 45.0)), ((490.0, 565.0), (12.0, 45.0)), ((590.0, 680.0), (12.0, 45.0))),
    "RGBA": (
        ((430.0, 490.0), (12.0, 45.0)),
        ((490.0, 565.0), (12.0, 45.0)),
        ((565.0, 610.0), (12.0, 45.0)),
        ((610.0, 680.0), (12.0, 45.0)),
    ),
    "violet-pumped": (
        ((380.0, 430.0), (12.0, 40.0)),
        ((430.0, 490.0), (30.0, 120.0)),
        ((490.0, 590.0), (40.0, 140.0)),
        ((590.0, 680.0), (40.0, 120.0)),
    ),
}
"""The solid-state forms: each band's (centre, FWHM) bounds in nm, as LEDs are made. A phosphor-converted white
is a narrow blue pump (InGaN, 12–40 nm) and broad phosphor bands (50–140 nm); an RGB(A) luminaire narrow direct
emitters; a violet-pumped white a violet pump and three phosphors. Free-floating bands with free widths fitted
what the folds share (reflectance misfit) with narrow spikes and bands at the grid's blind edges instead."""


def _band_form(name: str, limits: tuple[tuple[tuple[float, float], tuple[float, float]], ...]) -> Form:
    count = len(limits)
    centre_bounds = tuple(c for c, _ in limits)
    width_bounds = tuple(w for _, w in limits)
    middle = tuple(0.5 * (c[0] + c[1]) for c in centre_bounds)
    narrow = tuple(w[0] + 0.25 * (w[1] - w[0]) for w in width_bounds)
    broad = tuple(w[0] + 0.75 * (w[1] - w[0]) for w in width_bounds)
    low = tuple(c[0] + 0.25 * (c[1] - c[0]) for c in centre_bounds)
    high = tuple(c[0] + 0.75 * (c[1] - c[0]) for c in centre_bounds)
    starts = tuple(c + w for c in (middle, low, high) for w in (narrow, broad))

    def atoms(grid: WavelengthGrid, th: np.ndarray) -> np.ndarray:
        return _bands(grid, th[:count], th[count:])[0]

    def tangent(grid: WavelengthGrid, th: np.ndarray, amplitudes: np.ndarray) -> np.ndarray:
        # ∂/∂c_i = a_i b_i (λ − c_i)/s_i ; ∂/∂w_i = a_i b_i (λ − c_i)²/(2 s_i²) · ∂s_i/∂w_i, s_i = (w_i/2.3548)² + step²/6
        shapes, offsets, variances = _bands(grid, th[:count], th[count:])
        weighted = shapes * amplitudes
        by_centre = weighted * offsets / variances
        by_width = weighted * offsets**2 / (2 * variances**2) * (2 * np.maximum(th[count:], 1e-3) / 2.3548**2)
        return np.hstack([by_centre, by_width])

    return Form(
        name,
        "solid_state",
        tuple(f"centre_{i}_nm" for i in range(count)) + tuple(f"fwhm_{i}_nm" for i in range(count)),
        centre_bounds + width_bounds,
        starts,
        atoms,
        tangent=tangent,
        kind=BANDS,
    )


def _bands(grid: WavelengthGrid, centres: np.ndarray, fwhms: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`band` of several bands at once (photons, n × m), with ``λ − c`` and the variances behind them."""
    nm = _nm(grid)
    variances = (np.maximum(fwhms, 1e-3) / 2.3548) ** 2 + grid.step_nm**2 / 6.0
    offsets = nm[:, None] - centres
    return np.exp(-0.5 * offsets**2 / variances) * (nm / 555.0)[:, None], offsets, variances


def planck_log_slope(wavelengths: np.ndarray, kelvin: float) -> np.ndarray:
    """``∂ ln B(λ, T) / ∂ ln T`` of :func:`planck` (normalised at 560 nm): ``g(x) − g(x₅₆₀)``, ``g(x) = x / (1 − e^{−x})``,
    ``x = c₂ / (λ T)``."""
    kelvin = max(float(kelvin), 100.0)
    x = np.minimum(C2_NM_K / (kelvin * wavelengths), 700.0)
    x0 = min(C2_NM_K / (kelvin * 560.0), 700.0)
    return x / -np.expm1(-x) - x0 / -math.expm1(-x0)


def _water_atoms(grid: WavelengthGrid, th: np.ndarray) -> np.ndarray:
    shapes = _water_shapes(grid)
    depth = np.clip(th[:3], 0.0, None)
    return _photons(_nm(grid), daylight(grid, math.exp(th[3])) * np.exp(-(shapes @ depth)))[:, None]


def _water_tangent(grid: WavelengthGrid, th: np.ndarray, amplitudes: np.ndarray) -> np.ndarray:
    """∂/∂ optical depths in closed form (``−shape · e``); ∂/∂ ln CCT by a difference of the daylight locus."""
    spectrum = _water_atoms(grid, th)[:, 0] * amplitudes[0]
    step = 1e-4 * (math.log(25000.0) - math.log(4000.0))
    step = step if th[3] + step <= math.log(25000.0) else -step
    moved = th.copy()
    moved[3] += step
    by_cct = (_water_atoms(grid, moved)[:, 0] * amplitudes[0] - spectrum) / step
    return np.column_stack([-_water_shapes(grid) * spectrum[:, None], by_cct])


def _filter_atoms(grid: WavelengthGrid, th: np.ndarray) -> np.ndarray:
    x = (_nm(grid) - 550.0) / 100.0
    density = np.clip(th[1] * x + th[2] * x * x, -30.0, 30.0)
    return _photons(_nm(grid), planck(_nm(grid), math.exp(th[0])) * np.exp(-density))[:, None]


def _filter_tangent(grid: WavelengthGrid, th: np.ndarray, amplitudes: np.ndarray) -> np.ndarray:
    """``∂e/∂(ln T, b₁, b₂)`` of the filtered thermal form, in closed form (zero where the density is clipped)."""
    nm = _nm(grid)
    x = (nm - 550.0) / 100.0
    spectrum = _filter_atoms(grid, th)[:, 0] * amplitudes[0]
    free = np.abs(th[1] * x + th[2] * x * x) < 30.0
    return np.column_stack(
        [spectrum * planck_log_slope(nm, math.exp(th[0])), -x * spectrum * free, -x * x * spectrum * free]
    )


def _transmitted_forms() -> list[Form]:
    water_starts = tuple(
        (w, g, p, math.log(c))
        for w in (0.0, 3.0, 8.0, 20.0)
        for g in (0.0, 1.0, 4.0)
        for p in (0.0, 4.0, 15.0)
        for c in (5500.0, 8000.0)
    )
    filter_starts = tuple(
        (math.log(t), b1, b2) for t in (2200.0, 3200.0, 5000.0) for b1 in (-2.0, 0.0, 2.0) for b2 in (-1.5, 0.0, 1.5)
    )
    return [
        Form(
            "underwater",
            "transmitted",
            ("water_depth_m", "cdom_optical_depth", "phytoplankton_optical_depth", "log_cct"),
            ((0.0, 60.0), (0.0, 20.0), (0.0, 60.0), (math.log(4000.0), math.log(25000.0))),
            water_starts,
            _water_atoms,
            tangent=_water_tangent,
            kind=UNDERWATER,
        ),
        Form(
            "filter",
            "transmitted",
            ("log_kelvin", "density_slope", "density_curvature"),
            ((math.log(1200.0), math.log(20000.0)), (-8.0, 8.0), (-8.0, 8.0)),
            filter_starts,
            _filter_atoms,
            tangent=_filter_tangent,
            kind=FILTER,
        ),
    ]


FORMS: tuple[Form, ...] = (
    *_thermal_forms(),
    *(_band_form(n, limits) for n, limits in SOLID_STATE.items()),
    *_transmitted_forms(),
)
"""The parametric forms (the discharge family is a dictionary: :func:`discharge_atoms`)."""


def seen_forms(forms: tuple[Form, ...], seen_nm: tuple[float, float]) -> tuple[Form, ...]:
    """``forms`` with every emission band's centre held inside ``seen_nm``, the range the camera sees.

    Outside it the pixels do not say where a band is: a band centred where the camera is blind costs the data term
    nothing and can hold any energy there (on the tuning rows, bands at 384, 408 and 720 nm carried the family
    model's worst misses). Thermal and transmitted forms extrapolate by their physics and are left as they are.
    """
    low, high = seen_nm
    out = []
    for form in forms:
        if form.family != "solid_state":
            out.append(form)
            continue
        bounds = tuple(
            (max(b[0], low), min(b[1], high)) if name.startswith("centre_") else b
            for name, b in zip(form.parameters, form.bounds)
        )
        starts = tuple(tuple(min(max(v, b[0]), b[1]) for v, b in zip(start, bounds)) for start in form.starts)
        out.append(replace(form, bounds=bounds, starts=starts))
    return tuple(out)
