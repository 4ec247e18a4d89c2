"""The measured light library (Houser et al. 2013, 401 sources) and its tuning / held-out split.

The library is what msflash learns about real lights from (the light prior) and what it is judged
on (the ambient harness). Judging on a light that was learnt from says nothing, and the library
holds the same source several times (the F32T8/TL830 tube measured by NIST, by Guo & Houser and for
AE 9200): so lights are first grouped with their copies (cosine ≥ :data:`SAME_SOURCE_COSINE`), then
whole groups go to one side. The prior is stricter still: it learns only from tuning lights with
no near copy (cosine ≥ :data:`NEAR_COPY_COSINE`) among the held-out ones
(:func:`prior_training_lights`), and any other spectrum it adds (CIE daylight, blackbodies) passes
the same test (:func:`without_near_copies`).

The split is fixed by the labels alone (a CRC of the group's first label), not by any result:
it is the same on every machine and never moves to suit an estimator.
"""

from __future__ import annotations

import re
import zlib
from dataclasses import dataclass
from functools import cache
from typing import Literal

import numpy as np

from msflash.processing.datasets import DATA_DIR, load_spectra_csv
from msflash.processing.spectra import Spectra

LIBRARY_FILE = "lights/houser2013_401_lights_380_780_5nm.csv"
"""The library as shipped (see processing/data/SOURCES.md)."""

SAME_SOURCE_COSINE = 0.999
"""Lights whose spectra (400–700 nm, energy) have a cosine similarity at least this (transitively) are
one source and always fall on the same side of the split."""

NEAR_COPY_COSINE = 0.995
"""A spectrum this similar (cosine, 400–700 nm, energy) to a held-out light is a near copy of it and
stays out of the light prior."""

HELD_OUT_PER_MILLE = 300
"""Share of the near-copy groups held out, in thousandths (by the CRC-32 of each group's first label)."""

Split = Literal["tuning", "held_out"]
LightType = Literal["incandescent", "fluorescent", "led", "discharge", "daylight", "model"]

_TYPE_PATTERNS: tuple[tuple[LightType, str], ...] = (
    ("daylight", r"d65|daylight(?! fl)|eew|plasma|sun"),
    ("discharge", r"metal halide|mercury|hps|son\b|cdm|mhc|mh100|h38|c100s54|sdw|\bhid\b"),
    (
        "fluorescent",
        r"\bfl\b|fl\d|fluoresc|f\d+t\d+|t12|t8|\bcie f\d|f40|f34|tl\d|\bf3\.\d|tri-?phosphor|cool white|"
        r"warm white fl|triband|tri-band",
    ),
    (
        "led",
        r"led|phosphor|rgb|cree|lumileds|xicato|vio|soraa|ngl|m\d-\d|m\d\.\d|hp\d|fortimo|w[a-z]*\dk|wgarc|"
        r"true white|yag|luxeon|ssl|booth|b-y|peak|broad|3-led|4-led",
    ),
    (
        "incandescent",
        r"incandescent|halogen|halogena|60wa19|softer white|rough house|reveal|krypton|\bhalo\b|"
        r"illum\. a|\ba\b$|neodimium|\d+ ?k$|\d,\d+ k$",
    ),
)


@dataclass(frozen=True)
class LibraryLight:
    """One light of the library: its label, near-copy group, type and side of the split."""

    label: str
    group: int
    """Index of its near-copy group (lights of one group are near copies, transitively)."""
    light_type: LightType
    split: Split


@cache
def light_library() -> Spectra:
    """The 401 light spectra, energy units, 380–780/5 nm, one column per light (its label)."""
    return load_spectra_csv(
        DATA_DIR / LIBRARY_FILE, "spd", "energy", source=f"msflash data {LIBRARY_FILE} (Houser et al. 2013)"
    )


def light_type(label: str) -> LightType:
    """The kind of source a library label names (for per-family reports), by keywords of its label."""
    text = label.split(":", 1)[-1].strip().lower()
    for kind, pattern in _TYPE_PATTERNS:
        if re.search(pattern, text):
            return kind
    return "model"


def near_copy_groups(values: np.ndarray, threshold: float = SAME_SOURCE_COSINE) -> np.ndarray:
    """Group columns of ``values`` (n_wavelengths × n_lights) that are near copies, transitively.

    Returns the group index of each column; groups are numbered in order of their first column.
    """
    columns = np.asarray(values, dtype=float)
    norms = np.linalg.norm(columns, axis=0)
    unit = columns / np.where(norms > 0, norms, 1.0)
    similar = unit.T @ unit >= threshold
    parent = list(range(columns.shape[1]))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in zip(*np.nonzero(np.triu(similar, 1))):
        a, b = root(int(i)), root(int(j))
        if a != b:
            parent[max(a, b)] = min(a, b)
    roots = [root(i) for i in range(columns.shape[1])]
    numbering = {r: n for n, r in enumerate(dict.fromkeys(roots))}
    return np.array([numbering[r] for r in roots])


@cache
def library_lights() -> tuple[LibraryLight, ...]:
    """Every light of the library with its group, type and split (fixed by the labels; see the module notes)."""
    library = light_library()
    groups = near_copy_groups(library.values[_visible(library)])
    first_label: dict[int, str] = {}
    for label, group in zip(library.names, groups):
        first_label.setdefault(int(group), label)
    lights = []
    for label, group in zip(library.names, groups):
        held = zlib.crc32(first_label[int(group)].encode("utf-8")) % 1000 < HELD_OUT_PER_MILLE
        lights.append(LibraryLight(label, int(group), light_type(label), "held_out" if held else "tuning"))
    return tuple(lights)


def lights_of(split: Split) -> Spectra:
    """The library's lights on one side of the split, as one :class:`Spectra` (energy, 380–780/5)."""
    library = light_library()
    keep = [i for i, light in enumerate(library_lights()) if light.split == split]
    return library.replace(
        values=library.values[:, keep],
        names=tuple(library.names[i] for i in keep),
        source=f"{library.source}, {split} split",
    )


def _visible(spectra: Spectra) -> np.ndarray:
    wavelengths = spectra.wavelengths_nm
    return (wavelengths >= 400) & (wavelengths <= 700)


def without_near_copies(
    candidates: Spectra, held_out: Spectra | None = None, threshold: float = NEAR_COPY_COSINE
) -> Spectra:
    """``candidates`` less every spectrum that is a near copy of a held-out light (cosine ≥ ``threshold``
    over 400–700 nm, compared on the held-out lights' grid in energy units).

    ``held_out`` defaults to the library's held-out split.
    """
    held_out = lights_of("held_out") if held_out is None else held_out
    reference = held_out.values[_visible(held_out)]
    wavelengths = held_out.wavelengths_nm[_visible(held_out)]
    energy = candidates if candidates.unit == "energy" else candidates.to_unit("energy")
    values = np.column_stack(
        [np.interp(wavelengths, energy.wavelengths_nm, column, left=0.0, right=0.0) for column in energy.values.T]
    )

    def unit(columns: np.ndarray) -> np.ndarray:
        norms = np.linalg.norm(columns, axis=0)
        return columns / np.where(norms > 0, norms, 1.0)

    near = (unit(values).T @ unit(reference) >= threshold).any(axis=1)
    keep = np.flatnonzero(~near)
    return candidates.replace(values=candidates.values[:, keep], names=tuple(candidates.names[i] for i in keep))


@cache
def prior_training_lights() -> Spectra:
    """The library lights a light prior may learn from: the tuning split less near copies of held-out lights."""
    return without_near_copies(lights_of("tuning"))
