"""Cameras made from physics for the harness (issue 30, item 3): in no data set, so outside every training set.

A camera channel's quantal responsivity is ``QE(λ) · T_c(λ) · T_ir(λ)``:

- ``QE``: a silicon photodiode that collects what is absorbed between a dead surface layer and the end of
  its collection depth, ``(1 − R) (exp(−α x₀) − exp(−α x₁))``, with silicon's absorption coefficient α(λ)
  (Green 2008, log-interpolated) and the depths drawn per camera;
- ``T_c``: the colour filter's dye — blue a short-pass, green a band-pass, red a long-pass, each with its
  own edges and a floor of leakage;
- ``T_ir``: the infrared-cut filter's edge.

Each camera is drawn from its name's CRC-32, so ``physics:t03`` is the same camera everywhere.
"""

from __future__ import annotations

import zlib
from functools import cache

import numpy as np

SILICON_ALPHA_PER_UM = (
    (380, 30.0),
    (400, 9.52),
    (450, 2.55),
    (500, 1.11),
    (550, 0.694),
    (600, 0.414),
    (650, 0.281),
    (700, 0.190),
    (750, 0.130),
    (800, 0.0850),
)
"""Silicon's absorption coefficient at 300 K, 1/µm (Green 2008, Sol. Energy Mater. Sol. Cells 92, 1305)."""


def _logistic(x: np.ndarray, edge: float, width: float) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-(x - edge) / width))


def physics_camera(name: str, wavelengths: np.ndarray) -> np.ndarray:
    """R, G, B quantal responsivities of the camera ``name`` (``physics:…``) on ``wavelengths``, peak 1."""
    return _camera(name)(np.asarray(wavelengths, float))


@cache
def _camera(name: str):  # noqa: ANN202 — a closure over the drawn parameters
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    dead, depth = rng.uniform(0.05, 0.3), rng.uniform(2.0, 6.0)
    reflect = rng.uniform(0.05, 0.25)
    blue_edge, blue_width = rng.uniform(495, 525), rng.uniform(10, 20)
    green_centre, green_width, green_power = rng.uniform(520, 550), rng.uniform(35, 50), rng.uniform(2, 4)
    red_edge, red_width = rng.uniform(575, 605), rng.uniform(7, 14)
    ir_edge, ir_width = rng.uniform(640, 690), rng.uniform(6, 14)
    leak = rng.uniform(0.01, 0.06, 3)
    blue_ir = rng.uniform(0.0, 0.5)  # dyes turn transparent again in the far red

    def responsivities(nm: np.ndarray) -> np.ndarray:
        table = np.array(SILICON_ALPHA_PER_UM)
        alpha = np.exp(np.interp(nm, table[:, 0], np.log(table[:, 1])))
        qe = (1 - reflect) * (np.exp(-alpha * dead) - np.exp(-alpha * depth))
        ir_cut = 1.0 - _logistic(nm, ir_edge, ir_width)
        blue = (1.0 - _logistic(nm, blue_edge, blue_width)) * _logistic(nm, 395, 8) + blue_ir * _logistic(nm, 690, 15)
        green = np.exp(-(np.abs((nm - green_centre) / green_width) ** green_power))
        red = _logistic(nm, red_edge, red_width)
        filters = np.column_stack([red, green, blue]) * (1 - leak) + leak
        values = qe[:, None] * filters * ir_cut[:, None]
        return values / values.max()

    return responsivities


def physics_camera_names(split: str, count: int = 10) -> tuple[str, ...]:
    """``count`` cameras of one split: ``physics:t00…`` (tuning) or ``physics:h00…`` (held out)."""
    prefix = "t" if split == "tuning" else "h"
    return tuple(f"physics:{prefix}{i:02d}" for i in range(count))
