"""The physics suite's case lists (issue 30, item 3): lights from physics, split by their parameters.

Each split's cases are balanced over the light family (:data:`tests.harness.physics_lights.FAMILIES`), the
CFA layout (RGB and the four Bayer layouts, a fifth each), the LED set, the grid and the bit depth; the
light's parameters are drawn from the split's own intervals (:data:`tests.harness.physics_lights.RANGES`).

- **tuning**: the harness's tuning cameras and ten physics cameras ``physics:t00…t09``; surfaces from
  Vrhel Munsell + Objects + Macbeth.
- **held out**: the harness's held-out cameras and ten other physics cameras ``physics:h00…h09`` (half the
  cases each); surfaces from the CIE 2017 colour-fidelity set (TM-30's 99, which neither the library harness
  nor any msflash model ever used) with Gretag SG 140 and Esser.

A case's ``light`` is ``physics:`` followed by the light's JSON (:func:`light_of`), its ``light_type`` the
family. **Never tune on the held-out rows.**
"""

from __future__ import annotations

import json
import math
import zlib
from functools import cache

import numpy as np

from tests.harness import splits, tables
from tests.harness.cases import BITS_AND_BLACK, GRIDS, RATIO_RANGE
from tests.harness.physics_cameras import physics_camera_names
from tests.harness.physics_lights import FAMILIES, PhysicsLight, draw_light
from tests.harness.render import HarnessCase

CASES_PER_SPLIT = 100
LAYOUTS: tuple[str | None, ...] = (None, "RGGB", "BGGR", "GRBG", "GBRG")
SURFACES = {"tuning": ("munsell", "objects", "macbeth"), "held_out": ("ces99", "gretag", "esser")}
QUICK_EVERY = 10


def _balanced(values: tuple, count: int, rng: np.random.Generator) -> list:
    repeated = [values[i % len(values)] for i in range(count)]
    return [repeated[i] for i in rng.permutation(count)]


def light_of(case: HarnessCase) -> PhysicsLight:
    """The physics light of a case (its ``light`` field decoded)."""
    data = json.loads(case.light[len("physics:") :])
    return PhysicsLight(
        data["family"],
        data["kind"],
        tuple((k, float(v)) for k, v in data["params"]),
        data.get("second_kind", ""),
        tuple((k, float(v)) for k, v in data.get("second_params", ())),
        float(data.get("fraction", 1.0)),
    )


def encode(light: PhysicsLight) -> str:
    """The ``light`` field of a case lit by ``light``."""
    data = {"family": light.family, "kind": light.kind, "params": [list(p) for p in light.params]}
    if light.second_kind:
        data.update(second_kind=light.second_kind, second_params=[list(p) for p in light.second_params])
        data["fraction"] = light.fraction
    return "physics:" + json.dumps(data, separators=(",", ":"))


@cache
def physics_cases_of(split: splits.Split, count: int = CASES_PER_SPLIT) -> tuple[HarnessCase, ...]:
    """The physics cases of one split (the same on every machine)."""
    seed = zlib.crc32(f"physics-{split}".encode())
    rng = np.random.default_rng(seed)
    families = _balanced(FAMILIES, count, rng)
    layouts = _balanced(LAYOUTS, count, rng)
    depths = _balanced(BITS_AND_BLACK, count, rng)
    grids = _balanced(GRIDS, count, rng)
    led_sets = _balanced(tables.led_set_names(), count, rng)
    harness_cameras = splits.cameras_of(split)
    physics_cameras = physics_camera_names(split)
    out = []
    for i in range(count):
        light = draw_light(families[i], split, rng)
        camera = str(rng.choice(physics_cameras if i % 2 else harness_cameras))
        bits, black = depths[i]
        out.append(
            HarnessCase(
                name=f"physics-{split}-{i:03d}",
                split=split,
                seed=seed + i,
                camera=camera,
                light=encode(light),
                light_type=light.family,
                leds=led_sets[i],
                cfa=layouts[i],
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
                surface_sets=SURFACES[split],
                n_surfaces=int(rng.integers(20, 61)),
            )
        )
    return tuple(out)


def select_physics_cases(split: str, quick: bool = False) -> list[HarnessCase]:
    """The physics cases of ``split`` (``tuning``, ``held_out`` or ``both``); ``quick`` keeps a small subset."""
    chosen = list(splits.SPLITS) if split == "both" else [split]
    out = []
    for name in chosen:
        cases = physics_cases_of(name)  # type: ignore[arg-type]
        out.extend(cases[::QUICK_EVERY] if quick else cases)
    return out
