"""The harness's tuning / held-out split of lights, cameras and surfaces (issue 17).

Lights follow msflash's library split (:func:`processing.light_library.library_lights`), which the
light prior also trains on the tuning side of. Cameras are split here, once, by the CRC-32 of their
identity (:func:`tests.harness.tables.camera_identity`, so one camera in two files is on one side).
Surfaces: tuning scenes draw from Vrhel Munsell + Objects + Macbeth, held-out scenes from Gretag
SG 140 + Esser, less every copy of a Natural-100 surface (:func:`tests.harness.tables.surfaces`),
which a light prior's reflectance basis may come from. A
held-out case uses a held-out light, a held-out camera and held-out surfaces only.
"""

from __future__ import annotations

import zlib
from functools import cache
from typing import Literal

from msflash.processing.light_library import library_lights
from tests.harness import tables

Split = Literal["tuning", "held_out"]
SPLITS: tuple[Split, ...] = ("tuning", "held_out")

CAMERA_HELD_OUT_PER_MILLE = 300
"""A camera is held out when the CRC-32 of its identity, modulo 1000, is below this."""

SURFACE_SETS: dict[Split, tuple[str, ...]] = {
    "tuning": ("munsell", "objects", "macbeth"),
    "held_out": ("gretag", "esser"),
}
"""Reflectance sets (keys of :data:`tests.harness.tables.REFLECTANCE_FILES`) per split."""


def camera_split(name: str) -> Split:
    """The side of the split a camera is on (by the CRC-32 of its identity)."""
    identity = tables.camera_identity(name)
    return "held_out" if zlib.crc32(identity.encode("utf-8")) % 1000 < CAMERA_HELD_OUT_PER_MILLE else "tuning"


@cache
def cameras_of(split: Split) -> tuple[str, ...]:
    """The cameras on one side."""
    return tuple(name for name in tables.camera_names() if camera_split(name) == split)


@cache
def lights_of(split: Split) -> tuple[tuple[str, str], ...]:
    """(label, light type) of the library lights on one side (msflash's library split)."""
    return tuple((light.label, light.light_type) for light in library_lights() if light.split == split)


def surface_sets_of(split: Split) -> tuple[str, ...]:
    """The reflectance sets scenes of one side draw from."""
    return SURFACE_SETS[split]
