"""Lights made from physics, not taken from any library (issue 30, item 3).

Every light here is generated from how light is made, with free parameters drawn per case; none is a
measured spectrum of any library, and none of msflash's code is used (the CIE daylight basis comes from
colour-science, the water tables from /work/shared/data through the harness's own reader).

Kinds, by family (:data:`KINDS`):

- **thermal**: ``blackbody`` (Planck, T), ``tungsten`` (Planck × tungsten's emissivity, which falls with
  wavelength, × a glass envelope's UV edge), ``daylight`` (CIE D series from S0, S1, S2 at a CCT).
- **discharge**: ``triphosphor`` (mercury lines + Eu²⁺ BAM blue band + Tb³⁺ and Eu³⁺ rare-earth line groups,
  each line a Lorentz–Gauss profile of its own width), ``halophosphate`` (mercury lines + the Sb³⁺ and Mn²⁺
  bands of calcium halophosphate), ``sodium`` (high-pressure sodium: a self-reversed, pressure-broadened D
  line with its satellites, some mercury from the amalgam), ``metal_halide`` (mercury, sodium, thallium,
  indium, scandium and lithium lines over a rare-earth quasi-continuum).
- **solid_state**: ``pc_white`` (a blue InGaN pump, skewed, + a Ce:YAG-like band that is two Gaussians in
  photon energy + optionally a red nitride band), ``violet_pumped`` (a violet pump + blue, green and red
  phosphors), ``rgba`` (3–4 direct-emission LEDs, each Ohno's 2005 shape with a skew, drive levels free).
- **transmitted**: ``underwater`` (CIE daylight at a depth in water of a composition: pure-water absorption
  and scattering, Bricaud 1998 phytoplankton, CDOM and detritus, ``exp(−K_d z)`` with ``K_d = (a + b_b)/μ``;
  then a horizontal path), ``filtered`` (a thermal source through a dyed gel: absorption bands in optical
  density).
- **mixture**: two lights of two other families, mixed at a fraction.

The tuning and held-out splits draw from *different parameter ranges* of each kind (:data:`RANGES`):
other colour temperatures, pump wavelengths, phosphor blends, depths, water types, gels. A held-out
light is never a tuning light with new noise.

Spectra are made on the 1-nm rendering grid by integrating each line over its 1-nm bin (so a 1-nm line
keeps its energy); :func:`on_grid` gives what a spectroradiometer with a triangular slit as wide as the
sequence's grid step reports — the truth a case is scored against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np
from scipy.special import erf

from tests.harness import tables
from tests.processing.unseen_sequences import _data

FAMILIES = ("thermal", "discharge", "solid_state", "transmitted", "mixture")
KINDS: dict[str, tuple[str, ...]] = {
    "thermal": ("blackbody", "tungsten", "daylight"),
    "discharge": ("triphosphor", "halophosphate", "sodium", "metal_halide"),
    "solid_state": ("pc_white", "violet_pumped", "rgba"),
    "transmitted": ("underwater", "filtered"),
}
"""The kinds of each family (mixtures combine two kinds of two families)."""

FINE = tables.FINE_NM
C2_NM_K = 1.4388e7
"""Second radiation constant, nm·K."""

# Known line wavelengths (nm, air), NIST Atomic Spectra Database.
MERCURY_LINES = ((404.66, 0.35), (435.83, 1.0), (546.07, 1.1), (576.96, 0.25), (579.07, 0.25), (407.78, 0.05))
SODIUM_LINES = ((568.82, 0.10), (498.28, 0.05), (515.36, 0.04), (615.42, 0.06), (616.07, 0.08))
TERBIUM_LINES = ((543.0, 1.0), (488.0, 0.25), (584.0, 0.12), (620.0, 0.07), (490.5, 0.1), (548.0, 0.3))
EUROPIUM3_LINES = (
    (611.0, 1.0),
    (587.0, 0.08),
    (593.0, 0.1),
    (599.0, 0.06),
    (627.0, 0.15),
    (650.0, 0.04),
    (707.0, 0.06),
)
METAL_HALIDE_LINES = {
    "sodium": ((588.99, 1.0), (589.59, 0.6), (568.82, 0.1), (616.07, 0.08)),
    "thallium": ((535.05, 1.0),),
    "indium": ((451.13, 1.0), (410.18, 0.6)),
    "scandium": ((567.2, 0.6), (570.0, 0.4), (474.3, 0.3), (476.9, 0.3), (503.4, 0.2), (630.6, 0.2)),
    "lithium": ((670.78, 1.0), (610.36, 0.1)),
}


# -- profiles on the 1-nm grid -------------------------------------------------------------------------
def _gauss_bins(centre: float, fwhm: float) -> np.ndarray:
    """A unit-area Gaussian integrated over each 1-nm bin of :data:`FINE`."""
    sigma = max(fwhm, 0.05) / 2.3548
    edges = np.concatenate([FINE - 0.5, [FINE[-1] + 0.5]])
    cdf = 0.5 * (1 + erf((edges - centre) / (sigma * math.sqrt(2))))
    return np.diff(cdf)


def _lorentz_bins(centre: float, fwhm: float) -> np.ndarray:
    """A unit-area Lorentzian (pressure broadening) integrated over each 1-nm bin."""
    gamma = max(fwhm, 0.05) / 2
    edges = np.concatenate([FINE - 0.5, [FINE[-1] + 0.5]])
    return np.diff(np.arctan((edges - centre) / gamma) / math.pi)


def _line(centre: float, width: float, lorentz_share: float = 0.3) -> np.ndarray:
    """A spectral line: pseudo-Voigt of unit area (Gaussian Doppler/instrument core, Lorentzian wings)."""
    return (1 - lorentz_share) * _gauss_bins(centre, width) + lorentz_share * _lorentz_bins(centre, width)


def _skewed_band(centre: float, fwhm: float, skew: float) -> np.ndarray:
    """A band of peak 1 whose long-wavelength half is ``(1 + skew)`` times as wide as the short half."""
    left = fwhm / (2 + skew)
    right = left * (1 + skew)
    sigma = np.where(FINE < centre, left, right) / 1.1774
    return np.exp(-0.5 * ((FINE - centre) / sigma) ** 2)


def _energy_gaussian(centre_nm: float, fwhm_ev: float) -> np.ndarray:
    """A band Gaussian in photon energy (as 5d→4f emission of Ce³⁺ and Eu²⁺ is), per nm, peak ≈ 1."""
    energy = 1239.84 / FINE
    centre = 1239.84 / centre_nm
    sigma = fwhm_ev / 2.3548
    band = np.exp(-0.5 * ((energy - centre) / sigma) ** 2) * energy**2  # dE/dλ ∝ E²
    return band / band.max()


def planck(kelvin: float, wavelengths: np.ndarray = FINE) -> np.ndarray:
    """Planck's law (energy per nm), normalised at 560 nm."""
    return (
        (560.0 / wavelengths) ** 5
        * math.expm1(C2_NM_K / (kelvin * 560.0))
        / np.expm1(np.minimum(C2_NM_K / (kelvin * wavelengths), 700.0))
    )


def _tungsten_emissivity() -> np.ndarray:
    """Tungsten's spectral emissivity near 2800 K (≈ 0.47 at 400 nm falling to ≈ 0.42 at 780 nm; de Vos 1954)."""
    return 0.474 - 0.000135 * (FINE - 400.0)


def _glass_edge(cut_nm: float) -> np.ndarray:
    """A glass envelope's transmittance: a UV absorption edge at ``cut_nm``."""
    return 1.0 / (1.0 + np.exp(-(FINE - cut_nm) / 6.0))


@cache
def _daylight_basis() -> np.ndarray:
    """CIE S0, S1, S2 on :data:`FINE` (colour-science's tables, linearly interpolated)."""
    import colour

    basis = colour.colorimetry.SDS_BASIS_FUNCTIONS_CIE_ILLUMINANT_D_SERIES
    return np.column_stack([np.interp(FINE, basis[n].wavelengths, basis[n].values) for n in ("S0", "S1", "S2")])


def daylight(cct: float) -> np.ndarray:
    """CIE daylight of correlated colour temperature ``cct`` (CIE 15:2004 chromaticity → M1, M2)."""
    t = cct * 1.4388 / 1.4380
    if t <= 7000:
        x = -4.6070e9 / t**3 + 2.9678e6 / t**2 + 0.09911e3 / t + 0.244063
    else:
        x = -2.0064e9 / t**3 + 1.9018e6 / t**2 + 0.24748e3 / t + 0.237040
    y = -3.0 * x * x + 2.87 * x - 0.275
    m = 0.0241 + 0.2562 * x - 0.7341 * y
    m1 = (-1.3515 - 1.7703 * x + 5.9114 * y) / m
    m2 = (0.0300 - 31.4424 * x + 30.0717 * y) / m
    return _daylight_basis() @ np.array([1.0, m1, m2])


# -- water (the harness's own reading of the shared tables) ----------------------------------------------
@cache
def _water_table() -> tuple[np.ndarray, np.ndarray]:
    """(a_w, b_w) of pure water on :data:`FINE`, 1/m (NASA OBPG: Pope & Fry 1997, Kou 1993, Smith & Baker 1981)."""
    rows = []
    for line in _data("water/nasa_water_coef_popefry_kou_smithbaker.txt").read_text().splitlines():
        parts = line.split()
        if len(parts) == 3 and not line.startswith(("#", "wavelength")):
            rows.append([float(v) for v in parts])
    table = np.array(rows)
    return np.interp(FINE, table[:, 0], table[:, 1]), np.interp(FINE, table[:, 0], table[:, 2])


@cache
def _bricaud() -> np.ndarray:
    """(A_φ, E_φ) of Bricaud et al. 1998 on :data:`FINE` (edge values held outside 400–700 nm)."""
    lines = [
        line
        for line in _data("water/aph_bricaud_1998.txt").read_text().splitlines()
        if line and not line.startswith(("#", "/", "lambda"))
    ]
    table = np.array([[float(v) for v in line.split(",")] for line in lines])
    return np.column_stack([np.interp(FINE, table[:, 0], table[:, 3]), np.interp(FINE, table[:, 0], table[:, 4])])


def water_attenuation(chlorophyll: float, cdom_440: float, backscatter_ratio: float = 0.015) -> np.ndarray:
    """``a + b_b`` of a water body, 1/m, on :data:`FINE`."""
    a_w, b_w = _water_table()
    aphi = _bricaud()
    phyto = aphi[:, 0] * chlorophyll ** aphi[:, 1] if chlorophyll > 0 else 0.0
    detritus = 0.0124 * chlorophyll**0.724 * np.exp(-0.011 * (FINE - 440.0))
    cdom = cdom_440 * np.exp(-0.0145 * (FINE - 440.0))
    particles = backscatter_ratio * 0.416 * chlorophyll**0.766 * (550.0 / FINE)
    return a_w + phyto + detritus + cdom + 0.5 * b_w + particles


# -- the kinds ------------------------------------------------------------------------------------------
Params = dict[str, float]

RANGES: dict[str, dict[str, dict[str, tuple[tuple[float, float], ...]]]] = {
    # kind -> parameter -> split -> allowed intervals (a draw picks an interval, then uniform within it)
    "blackbody": {
        "kelvin": {"tuning": ((2300, 3300), (5000, 6000)), "held_out": ((1700, 2300), (3300, 5000), (6000, 9000))}
    },
    "tungsten": {
        "kelvin": {"tuning": ((2600, 3000),), "held_out": ((2000, 2600), (3000, 3400))},
        "cut_nm": {"tuning": ((330, 360),), "held_out": ((360, 400),)},
    },
    "daylight": {"cct": {"tuning": ((5000, 6500),), "held_out": ((4000, 5000), (6500, 20000))}},
    "triphosphor": {
        "red": {"tuning": ((0.8, 1.6),), "held_out": ((0.3, 0.8), (1.6, 2.2))},
        "blue": {"tuning": ((0.3, 0.8),), "held_out": ((0.8, 1.6),)},
        "line_nm": {"tuning": ((2.0, 4.0),), "held_out": ((1.0, 2.0), (4.0, 6.0))},
        "mercury": {"tuning": ((0.15, 0.3),), "held_out": ((0.05, 0.15), (0.3, 0.45))},
    },
    "halophosphate": {
        "manganese": {"tuning": ((0.6, 1.2),), "held_out": ((0.3, 0.6), (1.2, 1.8))},
        "mercury": {"tuning": ((0.1, 0.2),), "held_out": ((0.2, 0.35),)},
    },
    "sodium": {
        "broadening_nm": {"tuning": ((25, 40),), "held_out": ((12, 25), (40, 60))},
        "reversal": {"tuning": ((0.5, 0.8),), "held_out": ((0.2, 0.5), (0.8, 0.95))},
    },
    "metal_halide": {
        "sodium": {"tuning": ((0.5, 1.0),), "held_out": ((0.1, 0.5),)},
        "thallium": {"tuning": ((0.3, 0.6),), "held_out": ((0.6, 1.0),)},
        "indium": {"tuning": ((0.1, 0.3),), "held_out": ((0.3, 0.6),)},
        "continuum": {"tuning": ((0.3, 0.6),), "held_out": ((0.6, 1.2),)},
    },
    "pc_white": {
        "pump_nm": {"tuning": ((445, 455),), "held_out": ((430, 445), (455, 470))},
        "pump_fwhm": {"tuning": ((18, 24),), "held_out": ((14, 18), (24, 30))},
        "phosphor_nm": {"tuning": ((545, 560),), "held_out": ((530, 545), (560, 575))},
        "phosphor": {"tuning": ((1.5, 3.0),), "held_out": ((0.8, 1.5), (3.0, 4.5))},
        "red": {"tuning": ((0.0, 0.4),), "held_out": ((0.4, 1.2),)},
        "red_nm": {"tuning": ((620, 640),), "held_out": ((640, 660),)},
    },
    "violet_pumped": {
        "pump_nm": {"tuning": ((405, 412),), "held_out": ((395, 405), (412, 420))},
        "green_nm": {"tuning": ((520, 535),), "held_out": ((505, 520), (535, 545))},
        "red_nm": {"tuning": ((625, 640),), "held_out": ((610, 625), (640, 655))},
    },
    "rgba": {
        "blue_nm": {"tuning": ((455, 465),), "held_out": ((440, 455), (465, 475))},
        "green_nm": {"tuning": ((520, 530),), "held_out": ((510, 520), (530, 540))},
        "red_nm": {"tuning": ((625, 635),), "held_out": ((615, 625), (635, 650))},
        "amber": {"tuning": ((0.0, 0.0),), "held_out": ((0.3, 1.0),)},
    },
    "underwater": {
        "depth_m": {"tuning": ((1.0, 5.0),), "held_out": ((5.0, 15.0),)},
        "chlorophyll": {"tuning": ((0.05, 0.5),), "held_out": ((0.5, 5.0),)},
        "cdom_440": {"tuning": ((0.0, 0.05),), "held_out": ((0.05, 0.3),)},
        "cct": {"tuning": ((5500, 6500),), "held_out": ((4500, 5500), (6500, 9000))},
    },
    "filtered": {
        "kelvin": {"tuning": ((2800, 3200),), "held_out": ((2400, 2800), (3200, 5600))},
        "gel": {"tuning": ((0, 1),), "held_out": ((2, 4),)},
        "density": {"tuning": ((0.3, 0.8),), "held_out": ((0.8, 1.5),)},
    },
}
"""Parameter intervals of each kind per split (tuning and held-out never overlap)."""

GELS = (
    ((560.0, 90.0), (450.0, 0.0)),  # 0: colour-temperature blue (absorbs yellow-red)
    ((450.0, 70.0), (500.0, 0.0)),  # 1: colour-temperature orange (absorbs blue)
    ((540.0, 50.0), (420.0, 40.0)),  # 2: magenta (absorbs green, some violet)
    ((620.0, 70.0), (430.0, 40.0)),  # 3: green (absorbs red and blue)
    ((600.0, 40.0), (0.0, 0.0)),  # 4: cyan-ish notch (absorbs orange)
)
"""Dye absorption bands of the gels (centre, FWHM in nm; a second band of FWHM 0 is absent)."""


def draw_params(kind: str, split: str, rng: np.random.Generator) -> Params:
    """Parameters of one light of ``kind`` drawn from the split's intervals (and a few free shape parameters)."""
    params: Params = {}
    for name, by_split in RANGES[kind].items():
        intervals = by_split[split]
        low, high = intervals[int(rng.integers(len(intervals)))]
        params[name] = float(rng.uniform(low, high)) if name != "gel" else float(rng.integers(int(low), int(high) + 1))
    params["shape_seed"] = float(rng.integers(1 << 30))
    return params


def spectrum(kind: str, params: Params) -> np.ndarray:
    """The light's energy spectrum on :data:`FINE` (1 nm, 380–780), max 1."""
    shape = np.random.default_rng(int(params.get("shape_seed", 0)))
    p = params
    if kind == "blackbody":
        spd = planck(p["kelvin"])
    elif kind == "tungsten":
        spd = planck(p["kelvin"]) * _tungsten_emissivity() * _glass_edge(p["cut_nm"])
    elif kind == "daylight":
        spd = daylight(p["cct"])
    elif kind == "triphosphor":
        width = p["line_nm"]
        blue = _energy_gaussian(shape.uniform(445, 455), shape.uniform(0.28, 0.36))
        green = sum(w * _line(c + shape.normal(0, 0.5), width * shape.uniform(0.8, 1.5)) for c, w in TERBIUM_LINES)
        red = sum(w * _line(c + shape.normal(0, 0.5), width * shape.uniform(0.6, 1.2)) for c, w in EUROPIUM3_LINES)
        mercury = sum(w * _line(c, 0.3 + 0.2 * shape.random()) for c, w in MERCURY_LINES)
        spd = p["blue"] * 0.02 * blue + green + p["red"] * red + p["mercury"] * mercury
        spd = spd + 0.002 * shape.uniform(0.5, 1.5) * _energy_gaussian(680, 0.4)  # weak deep-red continuum
    elif kind == "halophosphate":
        antimony = _energy_gaussian(shape.uniform(475, 490), shape.uniform(0.45, 0.55))
        manganese = _energy_gaussian(shape.uniform(575, 590), shape.uniform(0.28, 0.34))
        mercury = sum(w * _line(c, 0.3 + 0.2 * shape.random()) for c, w in MERCURY_LINES)
        spd = 0.03 * (antimony + 2.0 * p["manganese"] * manganese) + p["mercury"] * mercury
    elif kind == "sodium":
        broad = p["broadening_nm"]
        wings = _lorentz_bins(589.3, broad) + 0.3 * _lorentz_bins(589.3, broad * 2.5)
        dip = 1.0 - p["reversal"] * np.exp(-0.5 * ((FINE - 589.3) / (broad * 0.12)) ** 2)
        satellites = sum(w * _line(c, 2.0 + 2 * shape.random()) for c, w in SODIUM_LINES)
        mercury = sum(w * _line(c, 0.5) for c, w in MERCURY_LINES[:3])
        spd = wings * dip + 0.02 * satellites + 0.004 * shape.random() * mercury + 0.0005 * planck(2100.0)
    elif kind == "metal_halide":
        lines = sum(w * _line(c, 0.5 + shape.random()) for c, w in MERCURY_LINES) * 0.5
        for element, amount in (("sodium", p["sodium"]), ("thallium", p["thallium"]), ("indium", p["indium"])):
            lines = lines + amount * sum(w * _line(c, 1.0 + 2 * shape.random()) for c, w in METAL_HALIDE_LINES[element])
        lines = lines + 0.3 * shape.random() * sum(w * _line(c, 1.5) for c, w in METAL_HALIDE_LINES["scandium"])
        lines = lines + 0.1 * shape.random() * sum(w * _line(c, 1.0) for c, w in METAL_HALIDE_LINES["lithium"])
        # Rare-earth (Dy, Ho, Tm) quasi-continuum: hundreds of lines that the slit blends into a lumpy band.
        centres = shape.uniform(400, 700, 300)
        continuum = sum(_gauss_bins(c, 3.0) for c in centres) / 300 * 0.6
        spd = lines * 0.02 + p["continuum"] * continuum * 0.05 + 0.0003 * planck(4000.0)
    elif kind == "pc_white":
        pump = _skewed_band(p["pump_nm"], p["pump_fwhm"], shape.uniform(0.1, 0.5))
        yellow = _energy_gaussian(p["phosphor_nm"], shape.uniform(0.42, 0.5)) + 0.6 * _energy_gaussian(
            p["phosphor_nm"] + 35, shape.uniform(0.35, 0.45)
        )
        red = _energy_gaussian(p["red_nm"], shape.uniform(0.25, 0.32))
        spd = pump + p["phosphor"] * 0.5 * yellow + p["red"] * red
    elif kind == "violet_pumped":
        pump = _skewed_band(p["pump_nm"], shape.uniform(12, 18), 0.3)
        blue = _energy_gaussian(shape.uniform(445, 460), shape.uniform(0.35, 0.45))
        green = _energy_gaussian(p["green_nm"], shape.uniform(0.3, 0.4))
        red = _energy_gaussian(p["red_nm"], shape.uniform(0.25, 0.32))
        spd = shape.uniform(0.3, 0.8) * pump + shape.uniform(0.3, 0.6) * blue + shape.uniform(0.5, 0.9) * green
        spd = spd + shape.uniform(0.7, 1.2) * red
    elif kind == "rgba":
        channels = [
            (p["blue_nm"], shape.uniform(18, 24), shape.uniform(0.3, 1.0)),
            (p["green_nm"], shape.uniform(28, 36), shape.uniform(0.3, 1.0)),
            (p["red_nm"], shape.uniform(14, 20), shape.uniform(0.3, 1.0)),
        ]
        if p["amber"] > 0:
            channels.append((shape.uniform(585, 595), shape.uniform(14, 18), p["amber"]))
        spd = sum(level * _ohno(centre, fwhm, shape.uniform(0.0, 0.3)) for centre, fwhm, level in channels)
    elif kind == "underwater":
        attenuation = water_attenuation(p["chlorophyll"], p["cdom_440"])
        spd = daylight(p["cct"]) * np.exp(-attenuation / 0.85 * p["depth_m"] - attenuation * shape.uniform(0.5, 2.0))
    elif kind == "filtered":
        bands = GELS[int(p["gel"])]
        density = sum(
            np.exp(-0.5 * ((FINE - c) / (w / 2.3548)) ** 2) * (1.0 if i == 0 else 0.6)
            for i, (c, w) in enumerate(bands)
            if w
        )
        spd = planck(p["kelvin"]) * _glass_edge(360.0) * 10.0 ** (-p["density"] * density)
    else:
        raise ValueError(f"unknown physics light kind {kind!r}")
    spd = np.clip(np.asarray(spd, float), 0.0, None)
    return spd / spd.max()


def _ohno(centre: float, fwhm: float, skew: float) -> np.ndarray:
    """Ohno (2005)'s LED shape ``(g + 2 g⁵)/3``, ``g`` a Gaussian, its red side widened by ``skew``."""
    width = np.where(FINE < centre, fwhm, fwhm * (1 + skew)) / 1.6651  # g = exp(−((λ−c)/w)²), FWHM of (g+2g⁵)/3
    g = np.exp(-(((FINE - centre) / width) ** 2))
    return (g + 2 * g**5) / 3


# -- lights of a split ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class PhysicsLight:
    """One generated light: its family, kind(s), parameters and mixing fraction."""

    family: str
    kind: str
    params: tuple[tuple[str, float], ...]
    second_kind: str = ""
    second_params: tuple[tuple[str, float], ...] = ()
    fraction: float = 1.0
    """Share of the first light in a mixture (by their spectra's sums)."""

    @property
    def label(self) -> str:
        """A readable label (``kind(param=…)``, mixtures as ``a + b``)."""

        def one(kind: str, params: tuple[tuple[str, float], ...]) -> str:
            shown = ", ".join(f"{k}={v:.4g}" for k, v in params if k != "shape_seed")
            return f"{kind}({shown})"

        if not self.second_kind:
            return one(self.kind, self.params)
        return f"{self.fraction:.2f} {one(self.kind, self.params)} + {one(self.second_kind, self.second_params)}"

    def energy(self) -> np.ndarray:
        """The spectrum on :data:`FINE` (energy, max 1)."""
        first = spectrum(self.kind, dict(self.params))
        if not self.second_kind:
            return first
        second = spectrum(self.second_kind, dict(self.second_params))
        mixed = self.fraction * first / first.sum() + (1 - self.fraction) * second / second.sum()
        return mixed / mixed.max()


def draw_light(family: str, split: str, rng: np.random.Generator) -> PhysicsLight:
    """A light of ``family`` with the split's parameters."""
    if family == "mixture":
        first, second = rng.choice(list(KINDS), 2, replace=False)
        kind_a = str(rng.choice(KINDS[str(first)]))
        kind_b = str(rng.choice(KINDS[str(second)]))
        fraction = float(rng.uniform(0.25, 0.75))
        return PhysicsLight(
            family,
            kind_a,
            tuple(draw_params(kind_a, split, rng).items()),
            kind_b,
            tuple(draw_params(kind_b, split, rng).items()),
            fraction,
        )
    kind = str(rng.choice(KINDS[family]))
    return PhysicsLight(family, kind, tuple(draw_params(kind, split, rng).items()))


def on_grid(fine_values: np.ndarray, wavelengths: np.ndarray) -> np.ndarray:
    """What a spectroradiometer reports on ``wavelengths``: the 1-nm spectrum through a triangular slit whose
    bandwidth (FWHM) is the grid's step (a line between two samples is shared by both, not lost)."""
    step = float(np.median(np.diff(wavelengths))) if wavelengths.size > 1 else 1.0
    weights = np.clip(1.0 - np.abs(FINE[None, :] - wavelengths[:, None]) / step, 0.0, None)
    return (weights @ fine_values) / np.maximum(weights.sum(axis=1), 1e-12)
