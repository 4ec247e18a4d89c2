"""The harness's deterministic case lists, one per split.

Every family dimension (RGB or a Bayer CFA, bit depth, wavelength grid, LED set, light type) is
balanced: its values are repeated to the list's length and shuffled with the split's seed, so
the marginals are even and the combinations scrambled. Continuous conditions (ambient/flash
ratio, noise, vignetting, exposures, specular highlights) are drawn per case. A case of one split
uses only that split's lights, cameras and surfaces (:mod:`tests.harness.splits`).
"""

from __future__ import annotations

import math
import zlib
from functools import cache

import numpy as np

from tests.harness import splits, tables
from tests.harness.render import HarnessCase

CASES_PER_SPLIT = 150
MOSAICS: tuple[str | None, ...] = (None, "RGGB", None, "BGGR", None, "GRBG", None, "GBRG")
"""RGB half the time, each Bayer CFA an eighth."""
BITS_AND_BLACK = ((10, 64), (12, 256), (14, 512), (16, 0), (16, 2048))
GRIDS: tuple[tuple[float, float, float], ...] = ((400, 700, 10), (380, 780, 5), (400, 700, 5), (400, 720, 4))
LIGHT_TYPES = ("led", "fluorescent", "incandescent", "discharge", "led", "fluorescent", "incandescent", "other")
"""Light types cycled through (``other``: daylight and model lights, few in the library)."""
RATIO_RANGE = (0.25, 4.0)
"""Ambient over mean single-LED signal on white: log-uniform in this range (comparable, ±)."""
QUICK_EVERY = 15
"""``--quick`` keeps every this-many-th case of each split."""


def _balanced(values: tuple, count: int, rng: np.random.Generator) -> list:
    repeated = [values[i % len(values)] for i in range(count)]
    return [repeated[i] for i in rng.permutation(count)]


@cache
def cases_of(split: splits.Split, count: int = CASES_PER_SPLIT) -> tuple[HarnessCase, ...]:
    """The cases of one split (the same on every machine)."""
    seed = zlib.crc32(f"harness-{split}".encode())
    rng = np.random.default_rng(seed)
    lights_by_type: dict[str, list[str]] = {}
    for label, kind in splits.lights_of(split):
        lights_by_type.setdefault(kind if kind in LIGHT_TYPES else "other", []).append(label)
    cameras = splits.cameras_of(split)
    mosaics = _balanced(MOSAICS, count, rng)
    depths = _balanced(BITS_AND_BLACK, count, rng)
    grids = _balanced(GRIDS, count, rng)
    led_sets = _balanced(tables.led_set_names(), count, rng)
    kinds = _balanced(LIGHT_TYPES, count, rng)
    out = []
    for i in range(count):
        kind = kinds[i] if kinds[i] in lights_by_type else "led"
        label = str(rng.choice(lights_by_type[kind]))
        light_type = next(t for name, t in splits.lights_of(split) if name == label)
        bits, black = depths[i]
        out.append(
            HarnessCase(
                name=f"{split}-{i:03d}",
                split=split,
                seed=seed + i,
                camera=str(rng.choice(cameras)),
                light=label,
                light_type=light_type,
                leds=led_sets[i],
                cfa=mosaics[i],
                bits=bits,
                black=black,
                grid=grids[i],
                unit=str(rng.choice(["energy", "photons"])),
                ratio=float(math.exp(rng.uniform(*np.log(RATIO_RANGE)))),
                exposures="unequal" if rng.random() < 0.5 else "equal",
                vignetting=float(rng.uniform(0.5, 0.85)) if rng.random() < 0.5 else 1.0,
                specular=bool(rng.random() < 0.25),
                peak=float(rng.uniform(0.5, 0.9)),
                full_well_e=float(rng.uniform(5000, 20000)),
                read_noise_e=float(rng.uniform(2.0, 10.0)),
                surface_sets=splits.surface_sets_of(split),
                n_surfaces=int(rng.integers(20, 61)),
            )
        )
    return tuple(out)


def select_cases(split: str, quick: bool = False) -> list[HarnessCase]:
    """The cases of ``split`` (``tuning``, ``held_out`` or ``both``); ``quick`` keeps a small subset."""
    chosen = list(splits.SPLITS) if split == "both" else [split]
    out = []
    for name in chosen:
        cases = cases_of(name)  # type: ignore[arg-type]
        out.extend(cases[::QUICK_EVERY] if quick else cases)
    return out
