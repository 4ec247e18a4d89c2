"""A flickering ambient: each frame's ambient gain read from the pixels, and eq. 5 corrected for it (issue 30, item 5).

Lamps on the mains modulate at 100 or 120 Hz (docs/flicker.md). A frame exposed for less than whole flicker periods
collects the lamp's mean over its own window, so the ambient in LED frame j is ``g_j`` times the ambient frame's, and
the LED-only images the estimate regresses on carry a share of the ambient: with ``L`` the frames' LED levels and
``U = pinv(L)``, ``f̃ = f + e a`` with ``e = U (g − 1)`` (``g`` relative to the ambient frame). When the ambient lies in
the LEDs' span this only rescales the weights; off the span it bends them (docs/flicker.md measures how much).

**Reading e from colour.** An LED is narrow: whatever surface block ``b`` shows, its LED-only response ``f_i,b ∈ R^C``
(C channels: RGB, or a mosaic's CFA planes) lies close to the camera's response to the LED's spectrum, ``d_i = Cᵀ I_i``,
or to that spectrum tilted across its band (a surface's reflectance slope inside the band), ``d'_i = Cᵀ (I_i ·
(λ − λ̄_i))``. The ambient's colour differs from block to block and from the LED's. So with ``P_i`` the projection
orthogonal to ``d_i, d'_i``, ``P_i f̃_i,b = e_i P_i a_b + P_i (model error) + noise``, and least squares over the blocks
gives ``ê_i = tr(P_i Σ f̃ aᵀ) / tr(P_i Σ a aᵀ)`` — two C × C moments per LED, which the one pass over the frames already
takes (:class:`processing.statistics.ChannelMoments`, denoised by the same half-difference probe). It needs the
LED spectra and the camera's responsivities, and a colour camera (C ≥ 3); it needs no timestamp, waveform or
extra frame, so it works in every sync mode and on sequences already recorded.

**Correcting.** ``f = f̃ − e a`` is linear, so the statistics of eq. 4–6 are corrected exactly from what they hold
(:func:`with_ambient_gains`): ``G' = G − e cᵀ − c eᵀ + E e eᵀ``, ``c' = c − E e`` (``E = ‖a‖²``), the noise moments alike.

**Every model, one correction.** Every statistic a model is fitted through is linear in the LED-only images, so the
same ``e``, read once from the whole frame, corrects them all exactly upstream of every model
(:func:`corrected_channel_statistics`, :func:`corrected_tiles`; why exact: docs/flicker.md).

**Deciding.** Each LED's sigma adds to the noise the read's bias (:data:`MODEL_ERROR`, :data:`CURVATURE_ERROR`,
:data:`RESIDUAL_ERROR`). Flicker is detected when some LED's ``|ê_i|`` exceeds :data:`DETECTION_Z` sigmas; the
statistics are then corrected by every ``ê_i`` as read (not shrunk towards 0: docs/decisions/flicker-every-model.md).
What was read is reported in every case (:class:`FlickerCheck`); frame timestamps and exposures, when the sequence
has them, fit the mains frequency and phase to the gains (:func:`fit_mains`) for the report only.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field, replace

import numpy as np

from msflash.processing.channel_statistics import ChannelStatistics, Moments
from msflash.processing.spectra import Spectra
from msflash.processing.statistics import ChannelMoments, NoiseMoments, SequenceStatistics
from msflash.processing.tile_statistics import BlockData, TiledStatistics

MODEL_ERROR = 0.01
"""One sigma of the colour read's bias under steady light that no measured term accounts for, added in quadrature to
the noise's sigma (docs/flicker.md)."""

CURVATURE_ERROR = 0.3
"""The read's bias per unit :func:`curvature_share` (one sigma): what the LED's spectrum alone says of how far a
surface curving inside its band can move its colour (docs/flicker.md)."""

RESIDUAL_ERROR = 0.75
"""The read's bias per unit of the LED image's colour off its two directions that the ambient does not explain,
relative to the ambient's colour off them (``√(R_i / A_i)``, :func:`ambient_gain_offsets`; one sigma). What the
scene itself says of the read: that colour is the surfaces' curvature inside the band, and where it correlates with
the ambient's the read takes it for ambient. The three constants keep every read of the harness's tuning lamp kinds,
steady, within 2σ (how they were set: docs/flicker.md)."""

DETECTION_Z = 3.0
"""Flicker is *detected* (and the gains applied) when some LED's ``|ê_i|`` exceeds this many sigmas."""

MAX_COLOUR_MISFIT = 0.05
"""An LED image with more than this share of its energy off its two colour directions is not the colour the
responsivities say (steady or flickering, the harness's LED images leave at most 0.1 %): the gains are not read."""

MAINS_HZ = (100.0, 120.0)
"""The flicker frequencies of lamps on 50 Hz and 60 Hz mains."""

MAINS_TOLERANCE = 0.01
"""The supply's frequency is searched within ±1 % of nominal."""

_CHANNEL_INDEX = {"R": 0, "G": 1, "B": 2}

_APPLY_GAINS: ContextVar[bool | np.ndarray] = ContextVar("msflash_apply_ambient_gains", default=True)
"""True: a detected flicker's gains are applied as read; False: none are (:func:`gains_not_applied`); an array: these
shares are applied whatever was read (:func:`gains_applied`). The last two serve studies."""


@contextmanager
def gains_not_applied() -> Iterator[None]:
    """Within the block, flicker is still read and reported but no statistics are corrected: what the estimate
    would be without the gain model (the flicker study's *plain* columns, tests/harness/flicker.py)."""
    token = _APPLY_GAINS.set(False)
    try:
        yield
    finally:
        _APPLY_GAINS.reset(token)


@contextmanager
def gains_applied(offsets: np.ndarray) -> Iterator[None]:
    """Within the block, every check corrects the LED images by ``offsets`` (one share per LED) whatever it read:
    what the estimate would be with a perfect read (the flicker study's *oracle* columns, tests/harness/flicker.py)."""
    token = _APPLY_GAINS.set(np.array(offsets, dtype=float))
    try:
        yield
    finally:
        _APPLY_GAINS.reset(token)


@dataclass(frozen=True)
class MainsFit:
    """The mains flicker fitted to the frames' gains, timestamps and exposures (:func:`fit_mains`)."""

    frequency_hz: float
    """The flicker frequency that fits best (twice the supply's)."""
    depth: float
    """The first harmonic's percent flicker, ``m`` in ``1 + m cos(2π f t + φ)`` (what the windows' means show)."""
    phase_cycles: float
    """``φ / 2π`` at the first frame's exposure start."""
    residual: float
    """RMS of the gains about the fit."""
    decisive: bool
    """Whether this frequency fits clearly better than every other in the search (else the gains cannot tell)."""


@dataclass(frozen=True)
class FlickerCheck:
    """What the estimate found out about a flickering ambient (the JSON's ``flicker``)."""

    checked: bool
    """Whether the gains could be read (colour camera, LED spectra and responsivities, channel moments)."""
    detected: bool = False
    corrected: bool = False
    led_gain_offsets: np.ndarray | None = None
    """``ê``: each LED-only image's share of the ambient image (0 under steady light), shape (k,)."""
    led_gain_offsets_std: np.ndarray | None = None
    frame_gains: np.ndarray | None = None
    """Each LED frame's ambient relative to the ambient frame's, ``1 + L ê``, shape (n_led_frames,)."""
    spread: float | None = None
    """``(max − min) / (max + min)`` of the gains of all frames, the ambient frame's 1 included: the flicker the
    frames saw (a lower bound of the lamp's percent flicker)."""
    fit: MainsFit | None = None
    reason: str = ""
    """Why it was not checked, or what was decided and why."""
    warnings: tuple[str, ...] = field(default=())
    applied_offsets: np.ndarray | None = None
    """The shares the LED images were corrected by (``ê`` as read), or None when not corrected."""

    def summary(self) -> str | None:
        """One line for the run's output when flicker was detected (None otherwise: a steady light stays quiet)."""
        if not self.detected or self.frame_gains is None:
            return None
        every = np.concatenate([[1.0], self.frame_gains])
        line = (
            f"flicker: the LED frames saw {every.min():.2f}–{every.max():.2f}× the ambient frame's light "
            f"(spread {self.spread:.0%}); each frame's ambient gain {'applied' if self.corrected else 'not applied'}"
        )
        fit = self.fit
        if fit is not None and fit.decisive:
            line += f"; fitted {fit.frequency_hz:.1f} Hz, depth {fit.depth:.0%}"
        return line

    def to_dict(self) -> dict:
        """The JSON object ``flicker`` (docs/architecture.md §7)."""

        def listed(values: np.ndarray | None) -> list[float] | None:
            return None if values is None else [float(v) for v in values]

        fit = self.fit
        return {
            "checked": self.checked,
            "detected": self.detected,
            "corrected": self.corrected,
            "frame_gains": listed(self.frame_gains),
            "led_gain_offsets": listed(self.led_gain_offsets),
            "led_gain_offsets_std": listed(self.led_gain_offsets_std),
            "applied_gain_offsets": listed(self.applied_offsets),
            "spread": self.spread,
            "frequency_hz": fit.frequency_hz if fit is not None and fit.decisive else None,
            "depth": fit.depth if fit is not None and fit.decisive else None,
            "phase_cycles": fit.phase_cycles if fit is not None and fit.decisive else None,
            "fit_residual": fit.residual if fit is not None else None,
            "reason": self.reason,
            "warnings": list(self.warnings),
        }


def led_directions(led_spectra: Spectra, responsivities: Spectra, channels: Sequence[str]) -> np.ndarray:
    """Each LED's response direction, its tilt across its band and its curvature, per channel: shape (k, 3, C).

    ``channels`` name each channel ``R``, ``G`` or ``B`` (a mosaic's planes in CFA order). Both spectra in one unit
    on one grid (photons inside processing). The gains are read off the first two (module notes); the third, a
    surface's reflectance curving inside the band, is what the read cannot tell from the ambient
    (:func:`curvature_share`).
    """
    columns = [_CHANNEL_INDEX[c] for c in channels]
    camera = responsivities.values[:, columns]
    nm = led_spectra.wavelengths_nm
    out = np.zeros((led_spectra.count, 3, len(columns)))
    for i in range(led_spectra.count):
        spd = np.clip(led_spectra.values[:, i], 0.0, None)
        total = float(spd.sum())
        if total <= 0:
            continue
        centre = float((nm * spd).sum() / total)
        width = math.sqrt(float(((nm - centre) ** 2 * spd).sum() / total)) or 1.0
        x = (nm - centre) / width
        out[i, 0] = camera.T @ spd
        out[i, 1] = camera.T @ (spd * x)
        out[i, 2] = camera.T @ (spd * (x * x - 1.0))
    return out


def curvature_share(directions: np.ndarray) -> np.ndarray:
    """``‖P_i d''_i‖ / ‖d_i‖`` per LED: how far the LED's colour moves off its two read directions when a surface's
    reflectance curves across the band (0.05–0.25 for most LEDs; 0.35–0.56 for an amber LED where a camera's R and
    G cross, whose read is biased by up to 0.2 under steady light: docs/flicker.md)."""
    out = np.zeros(directions.shape[0])
    for i, (d0, d1, d2) in enumerate(directions[:, :3]):
        norm = float(np.linalg.norm(d0))
        if norm <= 0:
            continue
        q, _ = np.linalg.qr(np.column_stack([d0, d1]))
        out[i] = float(np.linalg.norm(d2 - q @ (q.T @ d2))) / norm
    return out


def ambient_gain_offsets(moments: ChannelMoments, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``ê``, its sigma (noise, :data:`MODEL_ERROR`, :data:`CURVATURE_ERROR` and :data:`RESIDUAL_ERROR`) and each LED
    image's colour misfit from channel moments and :func:`led_directions`.

    The misfit is the share of ``f̃ − ê a``'s energy off the LED's two directions: a few per cent where the LED
    colours are what the responsivities say; near 1 where they are not (a mono camera recorded as three equal
    channels, responsivities of another camera). NaN for an LED whose directions leave no channel (C ≤ 2) or no
    ambient colour orthogonal to them.
    """
    clean = moments.denoised()
    k, channels = clean.fa.shape[0], clean.n_channels
    curvature = curvature_share(directions) if directions.shape[1] > 2 else np.zeros(k)
    offsets, sigmas, misfits = np.full(k, np.nan), np.full(k, np.nan), np.full(k, np.nan)
    for i in range(k):
        basis = directions[i, :2].T  # (C, 2)
        if not np.any(basis):
            continue
        q, r = np.linalg.qr(basis)
        keep = np.abs(np.diag(r)) > 1e-9 * np.abs(r).max()
        q = q[:, keep]
        projector = np.eye(channels) - q @ q.T
        ambient = float(np.trace(projector @ clean.aa))
        if channels - q.shape[1] < 1 or not ambient > 1e-12 * max(float(np.trace(clean.aa)), 1e-300):
            continue
        offset = float(np.trace(projector @ clean.fa[i])) / ambient
        residual = float(np.trace(projector @ clean.ff[i])) - 2 * offset * float(np.trace(projector @ clean.fa[i]))
        residual += offset * offset * ambient
        # The scatter about the fit, the noise included (the raw moments: the denoised ones have had it taken out).
        scatter = float(np.trace(projector @ moments.ff[i])) - 2 * offset * float(np.trace(projector @ moments.fa[i]))
        scatter += offset * offset * float(np.trace(projector @ moments.aa))
        dof = max(clean.n_blocks * (channels - q.shape[1]) - 1, 1)
        noise_var = max(scatter, residual, 0.0) / dof / ambient
        unexplained = max(residual, 0.0) / ambient  # the LED's own off-direction colour, in the ambient's units
        offsets[i] = offset
        sigmas[i] = math.sqrt(
            noise_var + MODEL_ERROR**2 + (CURVATURE_ERROR * curvature[i]) ** 2 + RESIDUAL_ERROR**2 * unexplained
        )
        energy = float(np.trace(clean.ff[i])) - 2 * offset * float(np.trace(clean.fa[i]))
        energy += offset * offset * float(np.trace(clean.aa))
        misfits[i] = max(residual, 0.0) / energy if energy > 0 else math.inf
    return offsets, sigmas, misfits


def with_ambient_gains(statistics: SequenceStatistics, offsets: np.ndarray) -> SequenceStatistics:
    """The statistics of the LED-only images ``f = f̃ − e a`` (module notes): eq. 4–6 as if the ambient were steady.

    Examples
    --------
    >>> steady = SequenceStatistics(np.eye(2), np.array([1.0, 0.5]), 2.0, 10, 10, 3.0, np.ones(2))
    >>> flickered = with_ambient_gains(steady, np.array([-0.2, 0.1]))  # f̃ = f + e a, e = (0.2, −0.1)
    >>> back = with_ambient_gains(flickered, np.array([0.2, -0.1]))
    >>> bool(np.allclose(back.gram, steady.gram) and np.allclose(back.cross, steady.cross))
    True
    """
    e = np.asarray(offsets, dtype=float)

    def moved(gram: np.ndarray, cross: np.ndarray, energy: float) -> tuple[np.ndarray, np.ndarray]:
        return gram - np.outer(e, cross) - np.outer(cross, e) + energy * np.outer(e, e), cross - energy * e

    gram, cross = moved(statistics.gram, statistics.cross, statistics.ambient_energy)
    noise = statistics.noise
    if noise is not None:
        noise = NoiseMoments(*moved(noise.gram, noise.cross, noise.ambient_energy), noise.ambient_energy)
    return replace(
        statistics,
        gram=gram,
        cross=cross,
        led_sums=statistics.led_sums - e * statistics.ambient_sum,
        noise=noise,
        channels=None,
    )


def fit_mains(
    starts_s: np.ndarray, exposures_s: np.ndarray, gains: np.ndarray, nominal: Sequence[float] = MAINS_HZ
) -> MainsFit | None:
    """The first harmonic of mains flicker that best explains frame ``gains`` (each relative to a common level).

    A frame exposed over ``[t, t + T]`` sees ``c (1 + m sinc(f T) cos(2π f (t + T/2) + φ))`` of a lamp at ``f`` Hz;
    for each ``f`` within :data:`MAINS_TOLERANCE` of a nominal frequency the model is linear in ``c``, ``c m cos φ``,
    ``c m sin φ``, so a grid over ``f`` with least squares at each finds the best. *Decisive* when the best residual
    is under a third of the best at any frequency more than one resolution step away (frames a few tens of ms apart
    sample a 100 Hz flicker sparsely: many frequencies may fit as well). None with fewer than five frames.
    """
    starts, exposures, values = (np.asarray(v, dtype=float) for v in (starts_s, exposures_s, gains))
    if values.size < 5 or not (np.all(np.isfinite(starts)) and np.all(np.isfinite(values))):
        return None
    times = starts - starts.min()
    span = float(times.max() + exposures.max())
    step = 0.05 / max(span, 1e-3)  # a twentieth of the frequency resolution
    best: list[tuple[float, float, np.ndarray]] = []
    for hz in nominal:
        for f in np.arange(hz * (1 - MAINS_TOLERANCE), hz * (1 + MAINS_TOLERANCE) + step / 2, step):
            centre = 2 * np.pi * f * (times + exposures / 2)
            smear = np.sinc(f * exposures)
            design = np.column_stack([np.ones_like(values), smear * np.cos(centre), -smear * np.sin(centre)])
            coefficients, *_ = np.linalg.lstsq(design, values, rcond=None)
            residual = float(np.sqrt(np.mean((design @ coefficients - values) ** 2)))
            best.append((residual, float(f), coefficients))
    residual, frequency, (level, cosine, sine) = min(best, key=lambda item: item[0])
    resolution = 1.0 / max(span, 1e-3)
    others = [r for r, f, _ in best if abs(f - frequency) > resolution]
    decisive = bool(others) and residual < min(others) / 3.0
    depth = math.hypot(cosine, sine) / level if level > 0 else math.nan
    return MainsFit(
        frequency_hz=frequency,
        depth=float(depth),
        phase_cycles=float((math.atan2(sine, cosine) / (2 * np.pi)) % 1.0),
        residual=residual,
        decisive=decisive,
    )


def check_flicker(
    statistics: SequenceStatistics,
    led_spectra: Spectra,
    responsivities: Spectra | None,
    channels: Sequence[str] | None,
    led_levels: np.ndarray,
) -> FlickerCheck:
    """Read each frame's ambient gain from ``statistics.channels`` and decide whether to apply it (module notes).

    ``channels`` name the channels (``("R", "G", "B")`` or a mosaic's CFA letters); ``led_levels`` are the LED
    frames' levels (the statistics' spec), which map ``ê`` to frame gains.
    """
    moments = statistics.channels
    if moments is None:
        return FlickerCheck(False, reason="no channel-resolved statistics (all-pixel statistics, --bin 1)")
    if responsivities is None:
        return FlickerCheck(False, reason="the camera's responsivities are not recorded: no LED colour to tell apart")
    if channels is None or moments.n_channels < 3 or len(channels) != moments.n_channels:
        return FlickerCheck(False, reason="a mono camera: no colour to tell the ambient from the LEDs")
    offsets, sigmas, misfits = ambient_gain_offsets(moments, led_directions(led_spectra, responsivities, channels))
    if not np.all(np.isfinite(offsets)):
        return FlickerCheck(False, reason="the ambient's colour does not differ from the LEDs' in these frames")
    if np.max(misfits) > MAX_COLOUR_MISFIT:
        worst = int(np.argmax(misfits))
        return FlickerCheck(
            False,
            reason=f"LED {worst + 1}'s image is not the colour the responsivities give it ({misfits[worst]:.0%} of its "
            "energy off them: a mono camera, or another camera's responsivities)",
        )
    levels = np.asarray(led_levels, dtype=float)
    frame_gains = 1.0 + levels @ offsets
    every = np.concatenate([[1.0], frame_gains])
    spread = float((every.max() - every.min()) / (every.max() + every.min())) if every.max() > 0 else math.nan
    z = np.abs(offsets) / sigmas
    detected = bool(np.max(z) > DETECTION_Z)
    reason = (
        f"frame gains {every.min():.3f}–{every.max():.3f} of the ambient frame's (LED {int(np.argmax(z)) + 1}: "
        f"{float(np.max(z)):.1f} σ): applied to the LED images"
        if detected
        else f"no LED's ambient share is beyond {DETECTION_Z:g} σ (largest {float(np.max(z)):.1f} σ): steady"
    )
    # Every LED's share as read, once some LED shows flicker, not shrunk towards 0 (docs/decisions/flicker-every-model.md).
    applied = offsets
    setting = _APPLY_GAINS.get()
    corrected = detected and setting is True
    if isinstance(setting, np.ndarray):
        applied, corrected = setting, True
        reason += "; the shares given applied instead (a study's oracle)"
    elif detected and not corrected:
        reason = reason.replace("applied to the LED images", "not applied (switched off)")
    return FlickerCheck(
        True,
        detected,
        corrected,
        offsets,
        sigmas,
        frame_gains,
        spread,
        reason=reason,
        applied_offsets=applied if corrected else None,
    )


def with_fit(check: FlickerCheck, starts_s: np.ndarray | None, exposures_s: np.ndarray | None) -> FlickerCheck:
    """``check`` with the mains fitted to its frame gains (ambient frame first in ``starts_s`` and ``exposures_s``)."""
    if not check.detected or check.frame_gains is None or starts_s is None or exposures_s is None:
        return check
    gains = np.concatenate([[1.0], check.frame_gains])
    if len(starts_s) != gains.size:
        return check
    return replace(check, fit=fit_mains(np.asarray(starts_s), np.asarray(exposures_s), gains))


def applied_offsets(check: FlickerCheck | None) -> np.ndarray | None:
    """The shares ``e`` a check corrects the LED images by, or None when it corrects nothing."""
    if check is None or not check.corrected or check.applied_offsets is None:
        return None
    return np.asarray(check.applied_offsets, dtype=float)


def corrected_channel_statistics(statistics: ChannelStatistics, check: FlickerCheck | None) -> ChannelStatistics:
    """The channel-resolved statistics (:mod:`processing.channel_statistics`: the light prior's and the families')
    of the LED-only images ``f_(c,i) = f̃_(c,i) − e_i a_c`` (module notes); ``statistics`` itself when ``check``
    corrects nothing.

    With ``E = I_C ⊗ e`` (C·k × C), ``f = f̃ − E a`` block by block, so fold by fold ``S_ff' = S_ff − E S_afᵀ −
    S_fa Eᵀ + E S_aa Eᵀ``, ``S_fa' = S_fa − E S_aa``, ``Σ f' = Σ f̃ − E Σ a``, and the noise probe's moments alike.
    """
    e = applied_offsets(check)
    if e is None:
        return statistics
    if e.size != statistics.n_leds:
        raise ValueError(f"flicker correction: {e.size} LED shares for {statistics.n_leds} LEDs")
    mixing = np.kron(np.eye(statistics.n_channels), e[:, None])  # (C·k, C)

    def moved(moments: Moments) -> Moments:
        fa_e = moments.fa @ mixing.T  # (folds, C·k, C·k): S_fa Eᵀ
        e_aa = mixing @ moments.aa  # (folds, C·k, C): E S_aa
        ff = moments.ff - fa_e - fa_e.transpose(0, 2, 1) + e_aa @ mixing.T
        return Moments(ff, moments.fa - e_aa, moments.aa)

    return replace(
        statistics,
        moments=moved(statistics.moments),
        noise=None if statistics.noise is None else moved(statistics.noise),
        led_sums=statistics.led_sums - statistics.ambient_sums @ mixing.T,
    )


def _corrected_tile_moments(tiles: TiledStatistics, e: np.ndarray) -> TiledStatistics:
    """Eq. 4–6's statistics of every tile with ``f = f̃ − e a``: ``G − e cᵀ − c eᵀ + E e eᵀ``, ``c − E e``."""
    cross, energy = tiles.cross, tiles.ambient_energy[..., None]
    outer = cross[..., :, None] * e[None, None, None, :]
    return replace(
        tiles,
        gram=tiles.gram - outer - outer.swapaxes(-1, -2) + energy[..., None] * np.outer(e, e),
        cross=cross - energy * e,
        led_sums=tiles.led_sums - tiles.ambient_sum[..., None] * e,
    )


def _corrected_blocks(blocks: BlockData, e: np.ndarray) -> BlockData:
    """The block rows ``[F_1 … F_n, A, 1]`` with each LED frame's extra ambient subtracted: ``F_j − δ_j (s_a / s_j)
    (A − b)`` with ``δ = L e``, which maps to ``f̃ − e a`` (``pinv(L) L = I``)."""
    spec = blocks.spec
    n = len(spec.led_scales)
    share = (np.asarray(spec.led_levels, dtype=float) @ e) * spec.ambient_scale / np.asarray(spec.led_scales)
    raw = blocks.raw.copy()
    raw[:n] -= share[:, None, None, None] * (raw[n] - spec.black_level * raw[n + 1])[None]
    differences = blocks.differences
    if differences is not None:  # the ones row has no noise: its half difference is 0
        differences = differences.copy()
        differences[:n] -= share[:, None, None, None] * differences[n][None]
    return replace(blocks, raw=raw, differences=differences)


def corrected_tiles(tiles: TiledStatistics, check: FlickerCheck | None) -> TiledStatistics:
    """The local model's tiles (:mod:`processing.tile_statistics`) with each LED image's ambient share ``e`` taken
    out (module notes): their moments, their noise-free part (:attr:`TiledStatistics.denoised`) and the block rows
    the regions are segmented from; ``tiles`` itself when ``check`` corrects nothing. The same ``e`` for every tile:
    a frame's ambient gain is the frame's (a global shutter; docs/flicker.md for a rolling one)."""
    e = applied_offsets(check)
    if e is None:
        return tiles
    if e.size != tiles.n_leds:
        raise ValueError(f"flicker correction: {e.size} LED shares for {tiles.n_leds} LEDs")
    out = _corrected_tile_moments(tiles, e)
    return replace(
        out,
        denoised=None if tiles.denoised is None else _corrected_tile_moments(tiles.denoised, e),
        blocks=None if tiles.blocks is None else _corrected_blocks(tiles.blocks, e),
    )
