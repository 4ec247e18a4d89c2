"""Lights by name: the ambients of the simulated rig and the CIE/colour-science illuminants.

Public objects
--------------
- :data:`AMBIENTS` and :func:`ambient_spectrum`: the ambients of the simulated rig (the paper's
  booth and pool ambients, and an ocean one from :mod:`processing.water`).
- :func:`light_spectrum`: a sim ambient or a colour-science illuminant, by name.

The standard illuminants themselves are :func:`processing.datasets.illuminant`. This module sits
above :mod:`processing.datasets` and :mod:`processing.water` and composes both, so the water model
builds on the shipped data and no import runs the other way.
"""

from __future__ import annotations

import numpy as np

from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.names import unknown_name
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid
from msflash.processing.water import underwater_ambient, water_transmittance

AMBIENTS = ("tungsten", "fluorescent", "daylight", "underwater", "green", "orange", "underwater_ocean")
"""Names accepted by :func:`ambient_spectrum`."""


def _ambient_key(name: str) -> str:
    """Case-insensitive lookup of an ambient name, or an error listing the valid ones."""
    for candidate in AMBIENTS:
        if candidate.lower() == name.lower():
            return candidate
    raise SpectralDataError(unknown_name("ambient", name, AMBIENTS))


def _smooth_filter(wavelengths_nm: np.ndarray, kind: str) -> np.ndarray:
    """Transmittance of a plausible gel filter: a band-pass for green, a long-pass for orange.

    Real gels never block completely, hence the small floor.
    """
    if kind == "green":
        return 0.04 + 0.96 * np.exp(-0.5 * ((wavelengths_nm - 530.0) / 35.0) ** 2)
    return 0.03 + 0.97 / (1.0 + np.exp(-(wavelengths_nm - 585.0) / 12.0))


def ambient_spectrum(name: str, grid: WavelengthGrid = DEFAULT_GRID, water_path_m: float = 5.0) -> Spectra:
    """An ambient light of the simulated rig, energy units, peak 1, on ``grid``.

    Parameters
    ----------
    name
        ``tungsten`` (CIE A), ``fluorescent`` (FL2), ``daylight`` (D65), ``underwater`` (D65
        through ``water_path_m`` of pure water, ``exp(-a_w(λ)·d)``), ``green`` (A through a
        band-pass gel near 530 nm) or ``orange`` (A through a long-pass gel from ~585 nm) — the
        paper's booth and pool ambients (Section 6) — or ``underwater_ocean`` (daylight at 5 m
        depth in mesotrophic ocean water, seen over 1 m: :func:`processing.water.underwater_ambient`
        with chlorophyll, CDOM and particles).
    water_path_m
        Light path through water for ``underwater`` (the paper dived to 5 m).

    Examples
    --------
    >>> ambient_spectrum("orange").unit
    'energy'
    """
    key = _ambient_key(name)
    if key in ("tungsten", "fluorescent", "daylight"):
        base = datasets.illuminant({"tungsten": "A", "fluorescent": "FL2", "daylight": "D65"}[key], grid)
        return base.replace(names=(key,), source=f"ambient '{key}' ({base.source})")
    if key == "underwater_ocean":
        return underwater_ambient(5.0, 1.0, grid=grid, water="ocean").replace(names=(key,))
    if key == "underwater":
        base = datasets.illuminant("D65", grid)
        values = base.values * water_transmittance(water_path_m, grid).values
        source = f"ambient 'underwater' (D65 through {water_path_m:g} m of pure water)"
    else:
        base = datasets.illuminant("A", grid)
        values = base.values * _smooth_filter(grid.wavelengths_nm, key)[:, None]
        source = f"ambient '{key}' (CIE A through a {key} gel)"
    return base.replace(values=values, names=(key,), source=source).normalised("max")


def light_spectrum(name: str, grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """A light by name, energy units, peak 1, on ``grid``: a sim ambient or a CIE/colour-science illuminant.

    Parameters
    ----------
    name
        One of :data:`AMBIENTS` (:func:`ambient_spectrum`), a key of ``colour.SDS_ILLUMINANTS``
        (``A``, ``D50``, ``D65``, ``FL2``, ``LED-B1``…; ``F2`` is read as ``FL2``), or
        ``blackbody:<kelvin>`` (:func:`processing.datasets.illuminant`). Case is ignored.

    Raises
    ------
    SpectralDataError
        For an unknown name; the message lists every accepted one.

    Examples
    --------
    >>> light_spectrum("f11").names, light_spectrum("Tungsten").names
    (('FL11',), ('tungsten',))
    """
    if any(name.lower() == ambient for ambient in AMBIENTS):
        return ambient_spectrum(name, grid)
    if name.lower().startswith("blackbody:"):
        return datasets.illuminant(name, grid)
    import colour  # imported here: loading colour-science takes a second and only these helpers need it

    keys = tuple(colour.SDS_ILLUMINANTS.keys())
    wanted = name.lower()
    if len(wanted) > 1 and wanted[0] == "f" and wanted[1:].replace(".", "").isdigit():
        wanted = "fl" + wanted[1:]  # CIE's F2 is colour-science's FL2
    key = next((k for k in keys if k.lower() == wanted), None)
    if key is None:
        raise SpectralDataError(unknown_name("light", name, AMBIENTS + keys, "blackbody:<kelvin>"))
    return datasets.illuminant(key, grid)
