"""The local route of a recorded sequence: the ambient per tile, its flash and synthesis (issue 9).

The global estimate inside a :class:`~processing.local.LocalEstimate` is always
:func:`~acquisition.session.analysis.estimate_sequence`'s, bit for bit; the tiles serve the model
selection and the local model only. The JSON payloads extend the global ones of
:mod:`acquisition.session.analysis`.
"""

from __future__ import annotations

import numpy as np

from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.session.analysis import (
    DEFAULT_BIN_FACTOR,
    FrameStack,
    estimate_payload,
    flash_payload,
    load_frame_stack,
    solve_sequence_flash,
)
from msflash.acquisition.session.estimate_stream import (
    EstimateStream,
    stream_sequence,
)
from msflash.processing.flash import FlashBounds, FlashSolution
from msflash.processing.flicker import applied_offsets
from msflash.processing.local import LocalEstimate, synthesize_local
from msflash.processing.tile_statistics import DEFAULT_TILES


def estimate_sequence_local(
    sequence: Sequence,
    method: str = "auto",
    solver: str = "tikhonov",
    alpha: float | str = "auto",
    tiles: int = DEFAULT_TILES,
    bin_factor: int = DEFAULT_BIN_FACTOR,
    stream: EstimateStream | None = None,
) -> LocalEstimate:
    """Estimate the ambient of a sequence globally or per tile (``method`` auto|global|local, issue 9).

    The global estimate is :func:`estimate_sequence`'s, from the whole frame's statistics, whatever
    the model chosen: every command reporting a sequence's ambient (``estimate``, ``flash``, ``run``,
    ``export``, ``evaluate``, the live view) gives the same global numbers, bit for bit. The tiles'
    statistics serve the model selection and the local model only. Both are accumulated in one pass
    over the frames, read from disk one at a time (or ``stream``, made with ``tiles``, already fed).
    """
    stream = stream or stream_sequence(sequence, bin_factor, tiles)
    return stream.local(method, solver, alpha)


def local_estimate_payload(sequence: Sequence, local: LocalEstimate) -> dict:
    """The ``msflash estimate --method … --json`` object: docs/architecture.md §7 keys plus the model and the tiles.

    ``spectrum`` and ``ambient_weights`` are the global estimate for the global model and the
    area-weighted mean over the tiles for the local one; the tiles are under ``tiles``.
    """
    payload = estimate_payload(sequence, local.global_estimate)
    unit = sequence.spectral_unit
    grid_spectra = local.global_estimate.spectrum

    def to_unit(values: np.ndarray) -> np.ndarray:
        flat = values.reshape(-1, values.shape[-1]).T
        converted = grid_spectra.replace(values=flat, names=tuple(f"t{i}" for i in range(flat.shape[1])))
        return converted.to_unit(unit).values.T.reshape(values.shape)

    payload["method"] = local.model
    payload["method_requested"] = local.method
    payload["model_selection"] = (
        None
        if local.selection is None
        else {
            "chosen": local.selection.model,
            "scores": local.selection.scores,
            "margin": local.selection.margin,
            "best_local_smoothing_tiles": local.selection.best_local,
            "explained_gain": local.selection.explained_gain,
            "min_explained_gain": local.selection.min_explained_gain,
            "criterion": "leave-one-tile-out prediction error relative to the global model's, and its cut relative "
            "to the ambient image's energy",
        }
    )
    payload["warnings"] = payload["warnings"] + list(local.warnings)
    if local.model == "local":
        payload["spectrum"] = to_unit(local.mean_spectrum)
        payload["ambient_weights"] = local.mean_weights
        payload["spectrum_global"] = to_unit(local.global_estimate.spectrum.values[:, 0])
        payload["ambient_weights_global"] = local.global_estimate.ambient_weights
        payload["tiles"] = {
            **_tiles(local),
            "spectra": to_unit(local.tile_spectra),
            "relative_residual": local.tile_residuals,
            "n_samples": local.tile_samples,
        }
    return payload


def solve_sequence_flash_local(
    sequence: Sequence, mode: str, local: LocalEstimate, target: str = "D65", bounds: FlashBounds = "physical"
) -> tuple[FlashSolution, np.ndarray, list[FlashSolution]]:
    """Per-tile flash solutions for a local estimate.

    Returns
    -------
    tuple
        ``(mean, tile_flash_weights, tile_solutions)``: the solution for the area-weighted mean
        ambient weights with the area-weighted mean flash weights (within the bounds, as a mean of
        weights that are), the (ty, tx, k) per-tile weights and the per-tile solutions.
    """
    if local.model == "global":
        solution = solve_sequence_flash(sequence, mode, local.global_estimate.ambient_weights, target, bounds)
        weights = np.broadcast_to(solution.flash_weights, local.tiles.shape + (solution.flash_weights.size,)).copy()
        return solution, weights, [solution]
    solutions = [
        solve_sequence_flash(sequence, mode, local.tile_weights[index], target, bounds)
        for index in np.ndindex(local.tiles.shape)
    ]
    weights = np.array([solution.flash_weights for solution in solutions]).reshape(local.tiles.shape + (-1,))
    areas = local.tiles.areas
    mean_weights = np.einsum("ts,tsk->k", areas, weights) / areas.sum()
    mean_solution = solve_sequence_flash(sequence, mode, local.mean_weights, target, bounds)
    mean = FlashSolution(
        mode=mean_solution.mode,
        ambient_weights=local.mean_weights,
        flash_weights=mean_weights,
        scale=mean_solution.scale,
        relative_error=max(s.relative_error for s in solutions),
        bounds=bounds,
        target_reached=all(s.target_reached for s in solutions),
        warnings=tuple(dict.fromkeys(w for s in solutions for w in s.warnings)),
    )
    return mean, weights, solutions


def local_flash_payload(
    sequence: Sequence, solution: FlashSolution, local: LocalEstimate, tile_weights: np.ndarray, target: str | None
) -> dict:
    """The ``msflash flash --method local|auto --json`` object: :func:`flash_payload` with the model used and,
    for a local model, its tiles and their ambient and flash weights (docs/architecture.md §7)."""
    payload = flash_payload(sequence, solution, target)
    payload["estimate_warnings"] = list(local.global_estimate.warnings) + list(local.warnings)
    payload["method"] = local.model
    payload["method_requested"] = local.method
    if local.model == "local":
        payload["tiles"] = {**_tiles(local), "flash_weights": tile_weights}
    return payload


def synthesize_sequence_local(
    sequence: Sequence, tile_flash_weights: np.ndarray, local: LocalEstimate, stack: FrameStack | None = None
) -> tuple[np.ndarray, np.ndarray, FrameStack]:
    """The spatially varying computational flash image (per-tile weights blended between tile centres), the
    global estimate's flicker shares taken out as :func:`~acquisition.session.analysis.synthesize_sequence` does."""
    stack = stack or load_frame_stack(sequence)
    offsets = applied_offsets(local.global_estimate.flicker)
    image, saturated = synthesize_local(
        stack.ambient, stack.led_frames, stack.spec, tile_flash_weights, local.tiles, offsets
    )
    return image, saturated, stack


def _tiles(local: LocalEstimate) -> dict:
    """What every payload says of a local model's tiles: the grid, its edges, the smoothing, the ambient weights."""
    return {
        "grid": list(local.tiles.shape),
        "row_edges": local.tiles.row_edges,
        "column_edges": local.tiles.column_edges,
        "smoothing_tiles": local.smoothing,
        "ambient_weights": local.tile_weights,
    }
