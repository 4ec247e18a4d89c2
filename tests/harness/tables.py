"""Spectral tables for the harness, read with the independent generator's own CSV reader.

Nothing here comes from msflash's readers or resampler: cameras, LED sets, reflectances and the
401-light library are read from /work/shared/data (or the identical copies under processing/data)
by :mod:`tests.processing.unseen_sequences`' ``_csv`` and put on a grid by its ``_on``
(``np.interp``). Only the light library's *split labels* come from msflash
(:func:`processing.light_library.library_lights`), as issue 17 asks.

Units: cameras are quantal (photon) responsivities, LEDs and lights are energy, as in the files.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from functools import cache

import numpy as np

from tests.processing.unseen_sequences import DATA, _csv, _data, _on

FINE_NM = np.arange(380.0, 781.0, 1.0)
"""The grid frames are rendered on (1 nm); sequences carry their spectra on a coarser grid."""


@dataclass(frozen=True)
class Table:
    """Columns of spectra on their own wavelengths (one column per item)."""

    wavelengths_nm: np.ndarray
    names: tuple[str, ...]
    values: np.ndarray

    def on(self, wavelengths: np.ndarray, outside: str = "zero") -> np.ndarray:
        """All columns on ``wavelengths`` (linear interpolation; zero or edge value outside)."""
        return _on(wavelengths, self.wavelengths_nm, self.values, outside=outside)

    def column(self, name: str) -> Table:
        """One column as a table."""
        index = self.names.index(name)
        return Table(self.wavelengths_nm, (name,), self.values[:, [index]])


# -- lights -----------------------------------------------------------------------------------------
LIGHTS_FILE = "lights/houser2013_401_lights_380_780_5nm.csv"


def msflash_label(label: str) -> str:
    """A shared-file label as msflash's copy of the library spells it (',' → ';', single spaces)."""
    return " ".join(label.replace(",", ";").split())


@cache
def lights() -> Table:
    """The 401 library lights (energy, 380–780/5), labelled as msflash labels them.

    The shared file quotes labels that hold commas; msflash's copy replaced those commas by ';' and
    collapsed runs of spaces (:func:`msflash_label`).
    """
    path = _data(LIGHTS_FILE)
    rows = [
        row
        for row in csv.reader(path.read_text(encoding="utf-8-sig").splitlines())
        if row and not row[0].startswith("#")
    ]
    header, body = rows[0], np.array([[float(v) for v in row] for row in rows[1:]])
    names = tuple(msflash_label(label) for label in header[1:])
    return Table(body[:, 0], names, body[:, 1:])


# -- LEDs -------------------------------------------------------------------------------------------
PAPER_SUBSETS: dict[int, tuple[int, ...]] = {
    3: (0, 3, 6),
    4: (0, 2, 3, 6),
    5: (0, 2, 3, 4, 6),
    6: (0, 1, 2, 3, 4, 6),
    7: tuple(range(7)),
}
"""The paper's LED subsets by count (0-based; the paper's 1-based [1,4,7], [1,3,4,7], …)."""

ISETCAM_LED_FILES = {4: "Luxeon4LEDs.csv", 5: "Luxeon5LEDs.csv", 6: "SixLEDs.csv", 8: "LuxeonLEDSpectra_8LED.csv"}


def led_set_names() -> tuple[str, ...]:
    """Every LED set the harness draws from: ``paper3`` … ``paper7``, ``isetcam4/5/6/8``."""
    return tuple(f"paper{k}" for k in PAPER_SUBSETS) + tuple(f"isetcam{k}" for k in ISETCAM_LED_FILES)


@cache
def led_set(name: str) -> Table:
    """An LED set (energy), each column one LED."""
    if name.startswith("paper"):
        nm, names, values = _csv(
            _data("paper/csv/ximeaLights_energy_380_1068_4nm.csv", "paper/ximeaLights_energy_380_1068_4nm.csv")
        )
        which = list(PAPER_SUBSETS[int(name[5:])])
        return Table(nm, tuple(names[i] for i in which), np.nan_to_num(values[:, which]))
    if name.startswith("isetcam"):
        nm, names, values = _csv(_data(f"leds/isetcam/{ISETCAM_LED_FILES[int(name[7:])]}"))
        return Table(nm, tuple(names), np.clip(np.nan_to_num(values), 0.0, None))
    raise ValueError(f"unknown LED set {name}")


# -- cameras ----------------------------------------------------------------------------------------
ISETCAM_CAMERAS = (
    "AptinaMT9M031",
    "AptinaMT9M131",
    "NikonD1",
    "NikonD100",
    "NikonD200IR",
    "NikonD2xsNikon50mm",
    "NikonD70",
)
COLOUR_CAMERAS = {"Nikon 5100 (NPL)": "Nikon D5100", "Sigma SDMerill (NPL)": "Sigma SDMerill"}
"""colour-science's cameras and the identity each is split by (the NPL Nikon 5100 is the D5100)."""


@cache
def _paper34() -> tuple[np.ndarray, list[str], np.ndarray]:
    return _csv(_data("cameras/paper34_cameras_400_700_10nm.csv"))


def camera_names() -> tuple[str, ...]:
    """Every camera: the paper's 34, ``isetcam:NAME`` (7, own grids), ``colour:NAME`` (2)."""
    _, columns, _ = _paper34()
    paper = tuple(dict.fromkeys(c.split("|")[0] for c in columns))
    return paper + tuple(f"isetcam:{n}" for n in ISETCAM_CAMERAS) + tuple(f"colour:{n}" for n in COLOUR_CAMERAS)


def camera_identity(name: str) -> str:
    """The physical camera a name refers to (the same camera in two files is one identity)."""
    if name.startswith("isetcam:"):
        return name[8:]
    if name.startswith("colour:"):
        return COLOUR_CAMERAS[name[7:]]
    return name


@cache
def camera(name: str) -> Table:
    """A camera's R, G, B quantal responsivities on its own grid, peak 1 (NaN → 0); ``physics:…`` cameras are
    generated (:mod:`tests.harness.physics_cameras`) on the 1-nm grid."""
    if name.startswith("physics:"):
        from tests.harness.physics_cameras import physics_camera

        nm, values = FINE_NM, physics_camera(name, FINE_NM)
    elif name.startswith("isetcam:"):
        nm, _, values = _csv(_data(f"cameras/isetcam/{name[8:]}.csv"))
    elif name.startswith("colour:"):
        import colour  # colour-science's own camera data (BSD-3), offline

        sensitivities = colour.MSDS_CAMERA_SENSITIVITIES[name[7:]]
        nm, values = sensitivities.wavelengths, sensitivities.values
    else:
        nm, columns, all_values = _paper34()
        values = all_values[:, [columns.index(f"{name}|{c}") for c in "RGB"]]
    values = np.clip(np.nan_to_num(np.asarray(values, float)), 0.0, None)
    return Table(np.asarray(nm, float), ("R", "G", "B"), values / values.max())


# -- reflectances -----------------------------------------------------------------------------------
REFLECTANCE_FILES = {
    "munsell": "reflectances/vrhel_isetcam/MunsellSamples_Vhrel.csv",
    "objects": "reflectances/vrhel_isetcam/Objects_Vhrel.csv",
    "macbeth": "reflectances/charts_isetcam/macbethChart_24.csv",
    "gretag": "reflectances/charts_isetcam/gretagDigitalColorSG_140.csv",
    "esser": "reflectances/charts_isetcam/esserChart_113.csv",
    "ces99": "colour-science: CIE 2017 colour-fidelity samples (TM-30's 99 CES)",
}
"""Surface sets the harness draws from (Natural-100 itself is not one of them)."""
NATURAL100_FILE = "reflectances/natural100/natural100_400_700_10nm.csv"
NATURAL100_TOLERANCE = 0.01
"""A surface within this of a Natural-100 surface (largest absolute difference, 400–700 nm) is a copy of
it. Vrhel Objects holds 82 Natural-100 surfaces verbatim and Esser two near copies: all are left out,
since a light prior's reflectance basis may come from Natural-100."""


@cache
def reflectance_set(name: str) -> Table:
    """A surface set (reflectance factors on the file's grid), clipped to [0, 1]."""
    if name == "ces99":  # never used by the library harness; no file: colour-science ships them
        import colour
        from colour.quality.cfi2017 import load_TCS_CIE2017

        samples = load_TCS_CIE2017(colour.SpectralShape(380, 780, 5))
        return Table(
            np.asarray(samples.wavelengths, float),
            tuple(f"ces99:{n}" for n in samples.labels),
            np.clip(np.asarray(samples.values, float), 0.0, 1.0),
        )
    nm, names, values = _csv(
        DATA / REFLECTANCE_FILES[name] if (DATA / REFLECTANCE_FILES[name]).is_file() else _data(REFLECTANCE_FILES[name])
    )
    return Table(nm, tuple(f"{name}:{n}" for n in names), np.clip(np.nan_to_num(values), 0.0, 1.0))


@cache
def natural100() -> Table:
    """Natural-100 (Vrhel 1994 via the paper), 400–700/10."""
    nm, names, values = _csv(_data(NATURAL100_FILE, "paper/csv/natural100_reflectance_400_700_10nm.csv"))
    return Table(nm, tuple(names), values)


@cache
def surfaces(sets: tuple[str, ...]) -> Table:
    """The surfaces of ``sets`` on the 1-nm grid (edge values held outside their data), less every
    copy of a Natural-100 surface (:data:`NATURAL100_TOLERANCE`)."""
    reference = natural100()
    names, columns = [], []
    for name in sets:
        table = reflectance_set(name)
        visible = table.on(reference.wavelengths_nm, outside="edge")
        distance = np.abs(visible[:, :, None] - reference.values[:, None, :]).max(axis=0).min(axis=1)
        keep = np.flatnonzero(distance > NATURAL100_TOLERANCE)
        names += [table.names[i] for i in keep]
        columns.append(table.on(FINE_NM, outside="edge")[:, keep])
    return Table(FINE_NM, tuple(names), np.column_stack(columns))
