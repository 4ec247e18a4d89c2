"""The channel statistics taken from the LED estimate's block rows (issue 31: one pass over the frames) are those
taken from the frames, to the bit, on both routes; where the rows cannot give them, they say so."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.lab.bench.processing import benchmark_world, led_stream_rows
from msflash.processing import block_rows as block_rows_module
from msflash.processing import channel_statistics as channel_statistics_module
from msflash.processing import frame_kernels
from msflash.processing.block_rows import BlockRows
from msflash.processing.block_sums import plane_shape
from msflash.processing.channel_statistics import (
    ChannelStatistics,
    accumulate_channel_statistics,
    channel_statistics_of_block_rows,
)


def _assert_identical(expected: ChannelStatistics, got: ChannelStatistics) -> None:
    for name in ("ff", "fa", "aa"):
        assert np.array_equal(getattr(expected.moments, name), getattr(got.moments, name)), name
        assert expected.noise is not None and got.noise is not None
        assert np.array_equal(getattr(expected.noise, name), getattr(got.noise, name)), name
    assert np.array_equal(expected.counts, got.counts)
    assert np.array_equal(expected.led_sums, got.led_sums)
    assert np.array_equal(expected.ambient_sums, got.ambient_sums)
    assert (expected.n_blocks_total, expected.n_leds, expected.channels) == (
        got.n_blocks_total,
        got.n_leds,
        got.channels,
    )


@pytest.mark.parametrize("route", ["numpy", "numba"])
@pytest.mark.parametrize("cfa", [None, "RGGB"])
def test_the_rows_give_the_frames_channel_statistics_to_the_bit(
    monkeypatch: pytest.MonkeyPatch, cfa: str | None, route: str
) -> None:
    """Saturated blocks (a highlight clipped in one LED frame only) and an excluded block left in, as the frames'
    statistics leave them: every moment, probe, count and sum the same."""
    monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, route)
    world = benchmark_world(192, 256, cfa=cfa)
    frames, spec = [np.array(frame) for frame in world["frames"]], world["spec"]
    frames[2][40:52, 60:75] = int(spec.white_level)  # clipped in one LED frame only
    frames[0][100:103, 10:12] = int(spec.white_level)
    rows = led_stream_rows(frames, spec, cfa, 4)
    rows.exclude(np.eye(*rows.block_shape[::2], dtype=bool))  # the LED estimate's own choice, not the statistics'
    expected = accumulate_channel_statistics(frames[0], frames[1:], spec, cfa=cfa, bin_factor=4)
    got = channel_statistics_of_block_rows(rows, spec, cfa=cfa)
    assert got is not None
    assert (frame_kernels.block_pass(frames[0], 4, 2 if cfa else 1, 1e9, 1, np.empty(rows.block_shape), None)[0]) == (
        route == "numba"
    )  # the route asked for is the one taken
    assert expected.counts.sum() < expected.n_blocks_total  # the clipped blocks are out
    _assert_identical(expected, got)


def test_rows_that_cannot_give_them_say_so(monkeypatch: pytest.MonkeyPatch) -> None:
    """A strided probe (large frames probe every few block rows), a missing frame, too few block rows: None."""
    world = benchmark_world(96, 128, cfa="RGGB")
    frames, spec = world["frames"], world["spec"]
    rows = led_stream_rows(frames, spec, "RGGB", 4)
    assert channel_statistics_of_block_rows(rows, spec, cfa="RGGB", n_folds=rows.block_shape[0] + 1) is None
    partial = BlockRows(len(frames) - 1, plane_shape(frames[0].shape, 2), 4, spec.white_level)
    partial.add_frame(0, frames[1], 2)
    assert channel_statistics_of_block_rows(partial, spec, cfa="RGGB") is None
    monkeypatch.setattr(block_rows_module, "PROBE_BLOCKS", 1)
    strided = led_stream_rows(frames, spec, "RGGB", 4)
    assert strided.probe_stride > 1
    assert channel_statistics_of_block_rows(strided, spec, cfa="RGGB") is None


@pytest.mark.parametrize("route", ["numpy", "numba"])
def test_a_kept_probe_gives_large_frames_channel_statistics_and_leaves_the_estimate_as_it_was(
    monkeypatch: pytest.MonkeyPatch, route: str
) -> None:
    """Large frames probe every few block rows (here forced on a small one): with ``full_probe`` the rows keep every
    block row's half difference, give the frames' channel statistics to the bit, and the LED estimate's own
    statistics (moments, probe, channel moments) are the strided probe's, to the bit, on both moment routes."""
    monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, route)
    monkeypatch.setattr(block_rows_module, "PROBE_BLOCKS", 64)
    world = benchmark_world(192, 256, cfa="RGGB")
    frames, spec = [np.array(frame) for frame in world["frames"]], world["spec"]
    frames[3][10:30, 200:230] = int(spec.white_level)
    compiled = route == "numba"
    strided = led_stream_rows(frames, spec, "RGGB", 4, compiled=compiled)
    kept = led_stream_rows(frames, spec, "RGGB", 4, full_probe=True, compiled=compiled)
    assert strided.probe_stride == kept.probe_stride > 1
    got = channel_statistics_of_block_rows(kept, spec, cfa="RGGB")
    assert got is not None
    _assert_identical(accumulate_channel_statistics(frames[0], frames[1:], spec, cfa="RGGB", bin_factor=4), got)
    one, other = strided.statistics(spec), kept.statistics(spec)
    assert np.array_equal(one.gram, other.gram) and np.array_equal(one.cross, other.cross)
    assert one.noise is not None and other.noise is not None
    assert np.array_equal(one.noise.gram, other.noise.gram) and np.array_equal(one.noise.cross, other.noise.cross)
    assert one.ambient_energy == other.ambient_energy and one.n_samples == other.n_samples
    assert one.channels is not None and other.channels is not None
    for name in ("fa", "ff", "aa", "noise_fa", "noise_ff", "noise_aa"):
        assert np.array_equal(getattr(one.channels, name), getattr(other.channels, name)), name


@pytest.mark.parametrize("cfa", [None, "RGGB"])
def test_the_compiled_fold_products_are_the_blas_products_to_the_bit(
    monkeypatch: pytest.MonkeyPatch, cfa: str | None
) -> None:
    """With the compiled fits in use, each fold's Gram matrix of the rows and of the probe comes from the rows as
    stored (family_kernels_numba.fold_grams, no transposing copy): the same numbers as the BLAS products of
    channel_rows — saturated blocks zeroed in every row, folds of unequal height — and the statistics the frames'."""
    pytest.importorskip("msflash.processing.family_kernels_numba", reason="numba (the fast extra) absent")
    monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, "numba")
    world = benchmark_world(184, 256, cfa=cfa)  # 46 block rows: folds of 10 and 9
    frames, spec = [np.array(frame) for frame in world["frames"]], world["spec"]
    frames[4][60:75, 30:47] = int(spec.white_level)
    frames[0][0:3, 250:256] = int(spec.white_level)
    rows = led_stream_rows(frames, spec, cfa, 4)
    height, channels, width = rows.block_shape
    blocks = channel_statistics_module._BlockLayout(height, width, channels)
    taken = channel_statistics_module._compiled_fold_products(rows, 5, blocks)
    assert taken is not None  # the route under test is the one taken
    stacked = rows.channel_rows()
    assert stacked is not None
    bounds = ((np.arange(6) * height + 4) // 5) * width
    for got, rows_of in zip(taken, stacked):
        assert rows_of is not None and got is not None
        expected = np.stack([channel_statistics_module._gram(rows_of[:, bounds[j] : bounds[j + 1]]) for j in range(5)])
        assert np.array_equal(expected, got)
    statistics = channel_statistics_of_block_rows(rows, spec, cfa=cfa)
    assert statistics is not None
    assert statistics.counts.sum() < statistics.n_blocks_total  # the clipped blocks are out
    _assert_identical(accumulate_channel_statistics(frames[0], frames[1:], spec, cfa=cfa, bin_factor=4), statistics)


def test_the_compiled_fold_products_answer_only_where_every_sum_is_exact(monkeypatch: pytest.MonkeyPatch) -> None:
    """Integers whose sums of squares pass 2⁵¹ (reassociated, they could round otherwise): the kernel says so; float
    frames' rows are not offered to it; both routes then take the copy and BLAS, and the statistics are the frames'."""
    kernels = pytest.importorskip("msflash.processing.family_kernels_numba", reason="numba (the fast extra) absent")
    monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, "numba")
    values = np.full((3, 2 * 1 * 4), 2.0**25)
    saturated = np.zeros((2, 4), dtype=bool)
    bounds = np.array([0, 1, 2], np.int64)
    _, exact = kernels.fold_grams(values, 2, 1, 4, 1.0, saturated, bounds)
    assert not exact
    grams, exact = kernels.fold_grams(values / 2.0**4, 2, 1, 4, 1.0, saturated, bounds)
    assert exact and grams[0, 0, 0] == 4 * 2.0**42 and grams[1, 2, 2] == 4  # the ones row counts the blocks
    world = benchmark_world(96, 128, cfa="RGGB")
    frames, spec = [np.asarray(frame, float) for frame in world["frames"]], world["spec"]
    rows = led_stream_rows(frames, spec, "RGGB", 4)
    assert rows.stored_rows() is None
    got = channel_statistics_of_block_rows(rows, spec, cfa="RGGB")
    assert got is not None
    _assert_identical(accumulate_channel_statistics(frames[0], frames[1:], spec, cfa="RGGB", bin_factor=4), got)
