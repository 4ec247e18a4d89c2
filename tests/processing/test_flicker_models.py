"""The flicker correction is exact for every model's statistics (processing/flicker.py, module notes).

Correcting the statistics of flickering frames by the LED images' ambient shares ``e`` must give the statistics of
the same frames with each LED frame's extra ambient subtracted pixel by pixel, ``F_j − δ_j (s_a / s_j)(A − b)`` with
``δ = L e``: for the LED model's (eq. 4–6), the light prior's and families' channel-resolved ones (per fold, with
their noise probe) and the local model's tiles (with their noise-free part and block rows), weighted or not.
"""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.channel_statistics import accumulate_channel_statistics
from msflash.processing.flicker import (
    FlickerCheck,
    corrected_channel_statistics,
    corrected_tiles,
    with_ambient_gains,
)
from msflash.processing.region_cells import Cells
from msflash.processing.statistics import FrameStackSpec
from msflash.processing.tile_statistics import tile_statistics

BLACK, WHITE = 64.0, 1e9


def _stack(seed: int, cfa: str | None, levels: np.ndarray) -> tuple[np.ndarray, list[np.ndarray], FrameStackSpec]:
    """Float frames (so a subtraction stays exact) of a textured ambient and LEDs, no pixel near white."""
    rng = np.random.default_rng(seed)
    shape = (48, 64) if cfa else (48, 64, 3)
    ambient = BLACK + rng.uniform(50, 400, shape)
    frames = [ambient * rng.uniform(0.7, 1.3) + rng.uniform(20, 300, shape) for _ in range(levels.shape[0])]
    spec = FrameStackSpec(
        black_level=BLACK,
        white_level=WHITE,
        ambient_scale=1 / 2000.0,
        led_scales=tuple(1 / rng.uniform(1000, 3000) for _ in range(levels.shape[0])),
        led_levels=levels,
    )
    return ambient, frames, spec


def _deflickered(ambient: np.ndarray, frames: list[np.ndarray], spec: FrameStackSpec, e: np.ndarray) -> list:
    delta = spec.led_levels @ e
    return [
        frame - d * (spec.ambient_scale / scale) * (ambient - BLACK)
        for frame, d, scale in zip(frames, delta, spec.led_scales, strict=True)
    ]


def _check(e: np.ndarray) -> FlickerCheck:
    return FlickerCheck(True, True, True, e, np.full(e.size, 0.01), applied_offsets=e)


LAYOUTS = [
    pytest.param(None, np.diag([1.0, 0.8, 0.6, 1.0]), id="RGB, one LED a frame"),
    pytest.param("RGGB", np.diag([1.0, 0.8, 0.6, 1.0]), id="RGGB"),
    pytest.param(
        "GBRG", np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0.5, 0.5, 0, 0]]), id="mixed frames"
    ),
]


@pytest.mark.parametrize(("cfa", "levels"), LAYOUTS)
def test_the_channel_statistics_of_the_light_models_are_corrected_exactly(cfa, levels) -> None:
    ambient, frames, spec = _stack(1, cfa, np.asarray(levels, float))
    e = np.array([0.21, -0.13, 0.05, -0.3])
    corrected = corrected_channel_statistics(accumulate_channel_statistics(ambient, frames, spec, cfa=cfa), _check(e))
    truth = accumulate_channel_statistics(ambient, _deflickered(ambient, frames, spec, e), spec, cfa=cfa)
    for name in ("ff", "fa", "aa"):
        np.testing.assert_allclose(getattr(corrected.moments, name), getattr(truth.moments, name), rtol=1e-9)
        assert corrected.noise is not None and truth.noise is not None
        np.testing.assert_allclose(getattr(corrected.noise, name), getattr(truth.noise, name), rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(corrected.led_sums, truth.led_sums, rtol=1e-9)
    np.testing.assert_array_equal(corrected.counts, truth.counts)
    # … and the LED model's statistics summed from them are the global correction's.
    summed = corrected.led_statistics()
    direct = with_ambient_gains(accumulate_channel_statistics(ambient, frames, spec, cfa=cfa).led_statistics(), e)
    np.testing.assert_allclose(summed.gram, direct.gram, rtol=1e-9)
    np.testing.assert_allclose(summed.cross, direct.cross, rtol=1e-9)


@pytest.mark.parametrize(("cfa", "levels"), LAYOUTS)
@pytest.mark.parametrize("weighting", [False, True], ids=["uniform", "weighted"])
def test_the_local_models_tiles_are_corrected_exactly(cfa, levels, weighting) -> None:
    ambient, frames, spec = _stack(2, cfa, np.asarray(levels, float))
    e = np.array([-0.18, 0.27, 0.0, 0.11])
    period = 2 if cfa else 1

    def tiles(stack: list[np.ndarray]):
        return tile_statistics(ambient, stack, spec, 3, bin_factor=4, cfa_period=period, weighting=weighting)

    corrected = corrected_tiles(tiles(frames), _check(e))
    truth = tiles(_deflickered(ambient, frames, spec, e))
    for part, expected in ((corrected, truth), (corrected.denoised, truth.denoised)):
        assert part is not None and expected is not None
        for name in ("gram", "cross", "ambient_energy", "led_sums", "ambient_sum", "n_samples"):
            np.testing.assert_allclose(getattr(part, name), getattr(expected, name), rtol=1e-8, atol=1e-6)
    assert corrected.blocks is not None and truth.blocks is not None
    mine, theirs = Cells.of(corrected.blocks), Cells.of(truth.blocks)
    np.testing.assert_allclose(mine.gram, theirs.gram, rtol=1e-8, atol=1e-6)
    np.testing.assert_allclose(mine.cross, theirs.cross, rtol=1e-8, atol=1e-6)
    assert mine.differences is not None and theirs.differences is not None
    np.testing.assert_allclose(mine.differences, theirs.differences, rtol=1e-8, atol=1e-6)
    # The tiles sum to the whole frame's statistics, corrected by the same shares.
    whole = accumulate_statistics(ambient, frames, spec, bin_factor=4, cfa_period=period, weighting=weighting)
    whole = with_ambient_gains(whole, e)
    np.testing.assert_allclose(corrected.total().gram, whole.gram, rtol=1e-8)


def test_nothing_changes_when_nothing_is_corrected() -> None:
    ambient, frames, spec = _stack(3, "RGGB", np.eye(4))
    channel = accumulate_channel_statistics(ambient, frames, spec, cfa="RGGB")
    tiles = tile_statistics(ambient, frames, spec, 2, bin_factor=4, cfa_period=2)
    steady = FlickerCheck(True, False, False, np.zeros(4), np.ones(4))
    for check in (None, steady):
        assert corrected_channel_statistics(channel, check) is channel
        assert corrected_tiles(tiles, check) is tiles
