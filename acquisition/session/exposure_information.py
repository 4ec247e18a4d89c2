"""Exposures that maximise the information the unsaturated blocks carry about the LED-only signals.

The estimator (``processing/statistics.py``) bins 4×4 blocks and drops a block saturated in ANY
frame, so a longer exposure buys SNR on the blocks it keeps and loses the blocks it saturates — for
every frame at once. This module chooses the ambient exposure ``T`` and each LED frame's
exposure ``tₖ`` to maximise the Fisher information about the LED-only rates ``d = r − a``
(LED frame rate minus ambient rate, DN/µs) summed over the blocks no frame saturates:

    F(T, t₁…t_K) = Σ_{blocks b kept by every frame} Σ_k Σ_{p∈b, channels} d_p² / Var(d̂_p),
    Var(d̂_p) = v(r_p·tₖ)/tₖ² + v(a_p·T)/T²,   v(S) = S·κ + (σ_r·κ)²   (κ = DN per electron),

the photon + read noise of the difference of the two rate images (the noise model of
:class:`~acquisition.session.led_snr.NoiseModel`; without one, photon noise only, κ = 1: the argmax does not
depend on κ then). A block is lost for a frame when its brightest pixel would pass
``headroom`` × full scale at that exposure: it crosses at ``s_b = headroom·full / max_{p∈b} rate_p``.

Between two crossings ``F`` only grows with an exposure, so each coordinate's optimum sits at a
crossing: coordinate ascent over ``T, t₁ … t_K`` evaluates ``F`` exactly at the crossings (a
geometric ladder of lost fractions, refined around the best), counting a block already lost to
another frame as free (the union effect), and never lets the union of lost blocks pass
``max_lost_fraction``. Each sweep first scales all exposures together (a bright patch pays only
when every frame gives it up: one frame alone is held back by the others' noise), then each one. Each step keeps the current value as a candidate, so ``F`` never decreases.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

LADDER = np.concatenate(([0.0], np.geomspace(1e-4, 0.5, 48)))
"""Lost fractions (of the candidate blocks) at whose crossings ``F`` is evaluated first."""


@dataclass(frozen=True)
class Blocks:
    """Preview rates grouped by estimator block: ``(n_blocks, members)`` arrays (members = pixels × channels)."""

    ambient: np.ndarray
    """Ambient rate a (DN/µs)."""
    leds: tuple[np.ndarray, ...]
    """Each LED frame's rate r = a + d (DN/µs)."""
    ambient_crossing: np.ndarray
    """Exposure (µs) at which each block's brightest ambient pixel reaches the headroom; (n_blocks,)."""
    led_crossings: tuple[np.ndarray, ...]
    """The same for each LED frame."""


def group_blocks(rate: np.ndarray, block: int) -> np.ndarray:
    """``(H, W[, C])`` rates → ``(n_blocks, block·block·C)``: one row per ``block × block`` block (edges cropped)."""
    if rate.ndim == 2:
        rate = rate[..., None]
    rows, cols = rate.shape[0] // block, rate.shape[1] // block
    if rows == 0 or cols == 0:
        raise ValueError(
            f"preview of shape {rate.shape} is smaller than one {block}×{block} block; expected a larger frame"
        )
    cropped = rate[: rows * block, : cols * block]
    grouped = cropped.reshape(rows, block, cols, block, rate.shape[2]).transpose(0, 2, 1, 3, 4)
    return grouped.reshape(rows * cols, -1)


def thin_members(grouped: np.ndarray, block: int, period: int = 1) -> np.ndarray:
    """Every other ``period × period`` cell of each block's members in both directions (¼ of them, every
    CFA phase kept): the information sums, estimated 4× cheaper, up to a common factor (argmax unchanged)."""
    cells = block // period
    if cells < 2:
        return grouped
    shaped = grouped.reshape(grouped.shape[0], cells, period, cells, period, -1)
    return shaped[:, ::2, :, ::2].reshape(grouped.shape[0], -1)


def crossings(rate_blocks: np.ndarray, clipped: np.ndarray, preview_us: float, limit_dn: float) -> np.ndarray:
    """Exposure at which each block's brightest value reaches ``limit_dn``; a block clipped in the preview
    (its rate unknown) crosses at the preview's exposure."""
    brightest = rate_blocks.max(axis=1)
    with np.errstate(divide="ignore"):
        crossing = np.where(brightest > 0, limit_dn / np.maximum(brightest, 1e-300), np.inf)
    return np.where(clipped, np.minimum(crossing, preview_us), crossing)


def information(
    led: np.ndarray,
    ambient: np.ndarray,
    led_us: np.ndarray | float,
    ambient_us: np.ndarray | float,
    dn_per_e: float,
    read_dn: float,
) -> np.ndarray:
    """Per-block information d²/Var(d̂) summed over the block's members, at exposures broadcast in front.

    ``led_us`` and ``ambient_us`` have shape ``(m, 1, 1)`` (or scalars); returns ``(m, n_blocks)``.
    """
    signal = np.maximum(led - ambient, 0.0)
    read = read_dn * read_dn
    variance = (np.maximum(led, 0.0) * led_us * dn_per_e + read) / (led_us * led_us) + (
        np.maximum(ambient, 0.0) * ambient_us * dn_per_e + read
    ) / (ambient_us * ambient_us)
    return (signal * signal / np.maximum(variance, 1e-300)).sum(axis=-1)


def _candidates(
    crossing: np.ndarray, lost_elsewhere: np.ndarray, current: float, limits: tuple[float, float], max_lost: int
) -> np.ndarray:
    """Exposures worth evaluating: crossings at the ladder's lost fractions, the current value, the limits."""
    own = np.sort(crossing[~lost_elsewhere])
    budget = max_lost - int(np.count_nonzero(lost_elsewhere))  # more blocks than this may not be lost
    ranks = np.unique(np.minimum((LADDER * own.size).astype(int), max(budget, 0)))
    ranks = ranks[ranks < own.size]
    values = np.concatenate((own[ranks], [current, limits[1]]))
    values = np.clip(values[np.isfinite(values)], limits[0], limits[1])
    return np.unique(values)


def _best(values: np.ndarray, score, crossing: np.ndarray, lost_elsewhere: np.ndarray, max_lost: int) -> float:
    """The candidate with the highest score among those keeping the union of lost blocks within ``max_lost``."""
    lost = (crossing[None, :] < values[:, None]) | lost_elsewhere[None, :]
    allowed = lost.sum(axis=1) <= max_lost
    totals = np.where(allowed, (score(values) * ~lost).sum(axis=1), -np.inf)
    return float(values[int(np.argmax(totals))])


def _refine(
    values: np.ndarray, chosen: float, crossing: np.ndarray, lost_elsewhere: np.ndarray, limits: tuple[float, float]
) -> np.ndarray:
    """Every crossing between the neighbours of ``chosen`` among ``values`` (at most 64, evenly picked)."""
    index = int(np.searchsorted(values, chosen))
    low = values[max(index - 1, 0)]
    high = values[min(index + 1, values.size - 1)]
    inside = crossing[(~lost_elsewhere) & (crossing >= low) & (crossing <= high)]
    inside = np.sort(inside[np.isfinite(inside)])
    if inside.size > 64:
        inside = inside[np.linspace(0, inside.size - 1, 64).astype(int)]
    return np.unique(np.clip(np.concatenate((inside, [chosen])), limits[0], limits[1]))


def most_informative(
    blocks: Blocks,
    start_ambient_us: float,
    start_led_us: Sequence[float],
    limits: tuple[float, float],
    dn_per_e: float,
    read_dn: float,
    max_lost_fraction: float,
    sweeps: int = 3,
) -> tuple[float, tuple[float, ...], float]:
    """Coordinate ascent on ``F``: the ambient exposure, each LED exposure, and the union's lost fraction.

    Starts from ``start_*`` (any feasible plan, e.g. the bright-end rule's); the result's ``F`` is at
    least the start's, provided the start loses at most ``max_lost_fraction`` of the blocks.
    """
    n_blocks = blocks.ambient.shape[0]
    max_lost = int(np.floor(max_lost_fraction * n_blocks))
    ambient_us = float(start_ambient_us)
    led_us = [float(t) for t in start_led_us]
    noise = (dn_per_e, read_dn)
    for _ in range(sweeps):
        before = (ambient_us, tuple(led_us))
        ambient_us, led_us = _ascend_ambient(blocks, ambient_us, led_us, limits, noise, max_lost)
        for k in range(len(blocks.leds)):
            led_us[k] = _ascend_led(blocks, k, ambient_us, led_us, limits, noise, max_lost)
        if (ambient_us, tuple(led_us)) == before:
            break
    lost = _lost_to_all_but(blocks, ambient_us, led_us, -2)
    return ambient_us, tuple(led_us), float(np.count_nonzero(lost)) / n_blocks


def _lost_to_all_but(blocks: Blocks, ambient_us: float, led_us: Sequence[float], skip: int) -> np.ndarray:
    """The blocks saturated in some frame other than ``skip``: -1 the ambient, k LED k, -2 none."""
    lost = np.zeros(blocks.ambient.shape[0], dtype=bool) if skip == -1 else blocks.ambient_crossing < ambient_us
    for k, crossing in enumerate(blocks.led_crossings):
        if k != skip:
            lost |= crossing < led_us[k]
    return lost


def _ascend_ambient(
    blocks: Blocks,
    ambient_us: float,
    led_us: list[float],
    limits: tuple[float, float],
    noise: tuple[float, float],
    max_lost: int,
) -> tuple[float, list[float]]:
    """One ascent step on the ambient: every exposure scaled at once (a bright patch given up by all frames
    together), then the ambient exposure alone."""
    dn_per_e, read_dn = noise
    n_blocks = blocks.ambient.shape[0]
    exposures = np.array([ambient_us, *led_us])
    joint = np.min(np.stack((blocks.ambient_crossing, *blocks.led_crossings)) / exposures[:, None], axis=0)
    scale_limits = (float(np.max(limits[0] / exposures)), float(np.min(limits[1] / exposures)))

    def joint_score(values: np.ndarray) -> np.ndarray:
        scale = values[:, None, None]
        return sum(
            (
                information(r, blocks.ambient, scale * led_us[k], scale * ambient_us, dn_per_e, read_dn)
                for k, r in enumerate(blocks.leds)
            ),
            np.zeros(()),
        )

    if scale_limits[0] <= 1.0 <= scale_limits[1]:
        factor = _optimise(joint, np.zeros(n_blocks, dtype=bool), 1.0, scale_limits, max_lost, joint_score)
        ambient_us, led_us = ambient_us * factor, [t * factor for t in led_us]
    elsewhere = _lost_to_all_but(blocks, ambient_us, led_us, -1)

    def ambient_score(values: np.ndarray) -> np.ndarray:
        shape = values[:, None, None]
        return sum(
            (
                information(r, blocks.ambient, np.float64(led_us[k]), shape, dn_per_e, read_dn)
                for k, r in enumerate(blocks.leds)
            ),
            np.zeros(()),
        )

    return _optimise(blocks.ambient_crossing, elsewhere, ambient_us, limits, max_lost, ambient_score), led_us


def _ascend_led(
    blocks: Blocks,
    k: int,
    ambient_us: float,
    led_us: Sequence[float],
    limits: tuple[float, float],
    noise: tuple[float, float],
    max_lost: int,
) -> float:
    """One ascent step on LED ``k``'s exposure, the other frames' information held."""
    dn_per_e, read_dn = noise
    leds = blocks.leds
    others = sum(
        (
            information(r, blocks.ambient, np.float64(led_us[j]), np.float64(ambient_us), dn_per_e, read_dn)
            for j, r in enumerate(leds)
            if j != k
        ),
        np.zeros(blocks.ambient.shape[0]),
    )

    def led_score(values: np.ndarray) -> np.ndarray:
        own = information(leds[k], blocks.ambient, values[:, None, None], np.float64(ambient_us), dn_per_e, read_dn)
        return own + others[None, :]

    elsewhere = _lost_to_all_but(blocks, ambient_us, led_us, k)
    return _optimise(blocks.led_crossings[k], elsewhere, led_us[k], limits, max_lost, led_score)


def _optimise(
    crossing: np.ndarray, elsewhere: np.ndarray, current: float, limits: tuple[float, float], max_lost: int, score
) -> float:
    """One coordinate: the best crossing on the ladder, then the best crossing near it."""
    values = _candidates(crossing, elsewhere, current, limits, max_lost)
    chosen = _best(values, score, crossing, elsewhere, max_lost)
    return _best(_refine(values, chosen, crossing, elsewhere, limits), score, crossing, elsewhere, max_lost)
