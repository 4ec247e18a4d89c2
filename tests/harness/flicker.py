"""The flicker study: what mains flicker costs the estimate, with and without the per-frame ambient gain model
(issue 30, item 5; docs/flicker.md).

Each case of the harness (:mod:`tests.harness.cases`: measured lamps, cameras and surfaces, rendered by
:mod:`tests.harness.render`, which shares no image formation with msflash) is rendered twice from the same
random draws: under its steady lamp, and under the same lamp flickering on the mains. The flicker is computed here,
independently of the simulator's :mod:`acquisition.devices.mains_flicker`: the lamp's light over time is a
waveform of its kind (a filament's near-sinusoid, a discharge lamp's rectified supply, an LED driver's clipped
one) with percent flicker :data:`DEPTH`, at 100 or 120 Hz within ±1 %, a random phase; each frame is exposed for
1–3 ms at times a host-paced capture gives (:data:`FRAME_GAP_MS` apart) and sees the waveform's mean over its
window, integrated numerically (:func:`window_mean`).

Each rendering is estimated twice by msflash's LED model (eq. 4–6, the defaults): with the gain model (what
``msflash estimate`` does: :func:`acquisition.session.analysis.estimate_from_statistics`) and without it
(:func:`processing.ambient.estimate_ambient` on the same statistics). The ratio is RMSE ÷ the LED bound (the best
non-negative fit of the truth by the LEDs, :func:`tests.harness.metrics.led_bound`); the truth is the lamp's mean.

Every model is also run the way ``msflash estimate`` runs it (:data:`MODELS`: the LED model global and local, the light
prior, the families and ``auto``; :func:`acquisition.session.one_sequence.estimate_read`), on both renderings, and on the
flickering one again with the gains read but not applied (:func:`processing.flicker.gains_not_applied`).

**Paired draws (the measurement).** Each case is also rendered on :data:`DRAWS` noise draws with both arms on one
noise realisation (:class:`tests.harness.render.CommonNoise`: they differ in the ambient's gain per frame and in
nothing else); the cost is the ratio of the means over cases × draws, with a 95 % interval from resampling whole
cases (:func:`cost_interval`), beside the floor (the true gains applied). The unpaired measurement above (the two
arms' photon draws differing) is kept beside it for comparison.

Tuning rows are the lamp kinds the rule's constants were set on (:data:`TUNING_KINDS`); held-out rows the others.

Run: ``.venv/bin/python -m tests.harness.flicker --jobs 2 --out docs/flicker-results.md`` (``--per-kind N`` cases per
lamp kind, default :data:`PER_KIND`; ``--unpaired-per-kind N``: only the first N of each kind measured unpaired, and
with a larger ``--per-kind`` their paired tables shown apart beside the later cases' alone; ``--split tuning``: the
tuning rows alone; ``--draws N``, default :data:`DRAWS`; ``--rows FILE`` pickles the rows). The larger sample of
docs/decisions/flicker-larger-sample.md: ``--per-kind 36 --unpaired-per-kind 12``.
"""

from __future__ import annotations

import argparse
import math
import pickle
import shutil
import tempfile
import zlib
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import analysis, sequence_spectra
from msflash.acquisition.session.one_sequence import EstimateSettings, estimate_read
from msflash.processing.ambient import estimate_ambient
from msflash.processing.errors import SpectralDataError
from msflash.processing.flicker import gains_applied, gains_not_applied, with_ambient_gains
from tests.harness import metrics
from tests.harness.cases import cases_of
from tests.harness.render import CommonNoise, HarnessCase, render
from tests.helpers import sequence_statistics

DEPTH = 0.3
"""Percent flicker of every flickering lamp, ``(max − min) / (max + min)``."""
EXPOSURE_MS = (1.0, 3.0)
"""Each frame's exposure is drawn uniformly in this range."""
FRAME_GAP_MS = (15.0, 60.0)
"""From one frame's start to the next: drawn uniformly (host pacing: a serial command, a trigger, a readout)."""
PER_KIND = 12
"""Cases per lamp kind (the first of each kind in the harness's two splits)."""
DRAWS = 4
"""Paired noise draws per case (:func:`measure` with ``draw``)."""
TUNING_KINDS = ("incandescent", "fluorescent")
"""Lamp kinds the gain model's constants were set on; the rest are held out."""
MODELS = {
    "led": EstimateSettings(method="global"),
    "local": EstimateSettings(method="local"),
    "prior": EstimateSettings(model="prior"),
    "family": EstimateSettings(model="family"),
    "auto": EstimateSettings(model="auto"),
}
"""Each model as ``msflash estimate`` runs it: ``--method global``, ``--method local``, ``--model prior|family|auto``."""
WAVEFORMS = {"incandescent": "sine", "fluorescent": "rectified", "discharge": "rectified", "led": "clipped"}
"""Each lamp kind's waveform (others: sine)."""


def waveform(kind: str, cycles: np.ndarray, depth: float) -> np.ndarray:
    """The lamp's relative light at ``cycles`` (time × flicker frequency), mean 1 over a period, percent flicker
    ``depth``: a raised cosine, a rectified sine, or a rectified sine clipped at half its peak."""
    x = np.mod(cycles, 1.0)
    shape = WAVEFORMS.get(kind, "sine")
    if shape == "sine":
        raw = np.cos(2 * np.pi * x)
    else:
        raw = np.abs(np.sin(np.pi * x))
        if shape == "clipped":
            raw = np.minimum(raw, 0.5)
    grid = np.mod(np.arange(20000) / 20000.0, 1.0)
    reference = np.cos(2 * np.pi * grid) if shape == "sine" else np.abs(np.sin(np.pi * grid))
    if shape == "clipped":
        reference = np.minimum(reference, 0.5)
    low, high = float(reference.min()), float(reference.max())
    offset = (high - low) * (1.0 / depth - 1.0) / 2.0  # (high − low) / (2·offset + high − low) = depth
    mean = float(np.mean(offset + reference - low))
    return (offset + raw - low) / mean


def window_mean(kind: str, frequency_hz: float, phase: float, start_s: float, duration_s: float) -> float:
    """The lamp's mean over ``[start, start + duration]``, by the midpoint rule on 4000 samples."""
    t = start_s + duration_s * (np.arange(4000) + 0.5) / 4000
    return float(np.mean(waveform(kind, frequency_hz * t + phase, DEPTH)))


@dataclass(frozen=True)
class Timing:
    """A case's frame timing and lamp: one exposure, start and true ambient gain per frame (ambient frame first)."""

    exposures_us: np.ndarray
    starts_s: np.ndarray
    gains: np.ndarray
    frequency_hz: float


def timing(case: HarnessCase) -> Timing:
    """The case's flicker: frequency, phase, exposures and frame starts drawn from its name."""
    rng = np.random.default_rng(zlib.crc32(f"flicker-{case.name}".encode()))
    frames = case.led_count + 1
    nominal = 100.0 if rng.random() < 0.5 else 120.0
    frequency = nominal * (1 + rng.uniform(-0.01, 0.01))
    phase = rng.uniform()
    exposures = rng.uniform(*EXPOSURE_MS, frames) * 1e3
    starts = np.concatenate([[0.0], np.cumsum(rng.uniform(*FRAME_GAP_MS, frames - 1))]) * 1e-3
    gains = np.array([window_mean(case.light_type, frequency, phase, s, e * 1e-6) for s, e in zip(starts, exposures)])
    return Timing(exposures, starts, gains, frequency)


@dataclass(frozen=True)
class Row:
    """One case: the LED bound and the four ratios, what the gain model found."""

    case: HarnessCase
    kind: str
    split: str
    ratios: dict[str, float]
    """``steady``/``flicker`` × ``model``/``plain``/``oracle``: RMSE ÷ LED bound; and per :data:`MODELS` name ``m``,
    ``m steady``, ``m flicker`` and ``m flicker plain`` (the gains read but not applied)."""
    detected_steady: bool
    detected_flicker: bool
    gain_error: float
    """RMS of the estimated frame gains less the true ones (relative to the ambient frame), flickering."""
    true_spread: float
    steady_z: tuple[float, ...]
    """Each LED's |ê_i| ÷ its sigma on the steady rendering (the read's error in its own sigmas)."""
    steady_offset: float
    """The largest |ê_i| on the steady rendering."""
    draw: int | None = None
    """The noise draw of a paired measurement (:func:`measure` with ``draw``); ``None``: the unpaired one."""
    failures: tuple[str, ...] = ()
    """Models that refused a rendering (their ratio NaN): ``"<model> <rendering>: <message>"``."""


def _estimates(directory: Path, true_offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, object]:
    """The LED model's spectrum with and without the gain model, and corrected by the true gains (the oracle), in the
    sequence unit; and the flicker check."""
    sequence = read_sequence(directory)
    stack = analysis.load_frame_stack(sequence)
    statistics = sequence_statistics(stack, sequence.camera.cfa, analysis.DEFAULT_BIN_FACTOR)
    with_model = analysis.estimate_from_statistics(sequence, statistics)
    leds = sequence_spectra.led_spectra_photons(sequence)
    plain = estimate_ambient(statistics, leds, "tikhonov", "auto")
    oracle = estimate_ambient(with_ambient_gains(statistics, true_offsets), leds, "tikhonov", "auto")

    def values(estimate) -> np.ndarray:
        return np.asarray(sequence_spectra.spectrum_in_sequence_unit(sequence, estimate.spectrum), float)

    return values(with_model), values(plain), values(oracle), with_model.flicker


def _model_ratios(
    directory: Path,
    truth: np.ndarray,
    bound: float,
    rendering: str,
    true_offsets: np.ndarray,
    failures: list[str],
    plain: bool = True,
) -> dict[str, float]:
    """Each of :data:`MODELS` as ``msflash estimate`` runs it, RMSE ÷ LED bound; on the flickering rendering also
    with the gains not applied (``plain``; the paired draws leave it out), and with the true ones (the oracle). A model that refuses the sequence
    (``SpectralDataError``, what ``msflash estimate`` turns into exit 2) gives NaN, its message appended to
    ``failures``; the tables leave that case's draw out of both arms for that model and count it."""
    sequence = read_sequence(directory)
    out: dict[str, float] = {}

    def ratio(name: str, settings: EstimateSettings) -> float:
        try:
            payload = estimate_read(sequence, settings, lambda note: None).payload
        except SpectralDataError as error:
            failures.append(f"{name} {rendering}: {error}")
            return math.nan
        return metrics.rmse(np.asarray(payload["spectrum"], float), truth) / bound

    for name, settings in MODELS.items():
        out[f"{name} {rendering}"] = ratio(name, settings)
        if rendering == "flicker":
            if plain:
                with gains_not_applied():
                    out[f"{name} flicker plain"] = ratio(name, settings)
            with gains_applied(true_offsets):
                out[f"{name} flicker oracle"] = ratio(name, settings)
    return out


def common_noise(case: HarnessCase, draw: int, lamp: Timing) -> CommonNoise:
    """The paired arms' shared noise for ``draw`` of ``case``: one seed from the case's name and the draw, the DN scale
    set by the flickering frames (so neither arm is rescaled to its own brightest frame)."""
    return CommonNoise(zlib.crc32(f"flicker-noise-{case.name}-{draw}".encode()), tuple(lamp.gains))


def measure(case: HarnessCase, draw: int | None = None) -> Row:
    """Render ``case`` steady and flickering (same exposures and times), estimate each with and without gains.

    ``draw=None`` is the first study's measurement: the two renderings' photon draws differ (the Poisson stream
    diverges at the first frame whose mean differs), so their difference holds each model's draw-to-draw spread
    besides the flicker. With a ``draw`` the two renderings are paired on one noise realisation (:func:`common_noise`,
    :class:`tests.harness.render.CommonNoise`): they differ in the ambient's gain per frame and in nothing else.
    """
    lamp = timing(case)
    pairing = None if draw is None else common_noise(case, draw, lamp)
    ratios: dict[str, float] = {}
    failures: list[str] = []
    scratch = Path(tempfile.mkdtemp(prefix="flicker-"))
    try:
        checks = {}
        for name, gains in (("steady", np.ones_like(lamp.gains)), ("flicker", lamp.gains)):
            truth = render(
                case, scratch / name, ambient_gains=gains, exposures_us=lamp.exposures_us, common_noise=pairing
            )
            bound = metrics.led_bound(truth.led_spd, truth.ambient)
            true_offsets = gains[1:] / gains[0] - 1.0  # one LED a frame at full drive: e = g − 1
            model, plain, oracle, check = _estimates(truth.directory, true_offsets)
            ratios[f"{name} model"] = metrics.rmse(model, truth.ambient) / bound
            ratios[f"{name} plain"] = metrics.rmse(plain, truth.ambient) / bound
            ratios[f"{name} oracle"] = metrics.rmse(oracle, truth.ambient) / bound
            ratios.update(
                _model_ratios(truth.directory, truth.ambient, bound, name, true_offsets, failures, draw is None)
            )
            checks[name] = check
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    flickering, steady = checks["flicker"], checks["steady"]
    relative = lamp.gains[1:] / lamp.gains[0]
    gain_error = (
        float(np.sqrt(np.mean((np.asarray(flickering.frame_gains) - relative) ** 2)))
        if flickering.frame_gains is not None
        else math.nan
    )
    offsets = np.asarray(steady.led_gain_offsets if steady.led_gain_offsets is not None else [math.nan])
    sigmas = np.asarray(steady.led_gain_offsets_std if steady.led_gain_offsets_std is not None else [math.nan])
    return Row(
        case,
        case.light_type,
        "tuning" if case.light_type in TUNING_KINDS else "held_out",
        ratios,
        bool(steady.detected),
        bool(flickering.detected),
        gain_error,
        float((lamp.gains.max() - lamp.gains.min()) / (lamp.gains.max() + lamp.gains.min())),
        tuple(float(v) for v in np.abs(offsets) / sigmas),
        float(np.max(np.abs(offsets))),
        draw,
        tuple(failures),
    )


def _measured(job: tuple[HarnessCase, int | None]) -> Row:
    return measure(*job)


def flicker_cases(per_kind: int = PER_KIND) -> list[HarnessCase]:
    """The first ``per_kind`` cases of each lamp kind from both harness splits (all RGB and raw layouts as drawn)."""
    chosen: dict[str, list[HarnessCase]] = {}
    for split in ("tuning", "held_out"):
        for case in cases_of(split):
            kind = case.light_type if case.light_type in (*WAVEFORMS, "other") else "other"
            if len(chosen.setdefault(kind, [])) < per_kind:
                chosen[kind].append(replace(case, light_type=kind, exposures="equal"))
    return [case for kind in sorted(chosen) for case in chosen[kind]]


VARIANTS = ("steady plain", "steady model", "flicker plain", "flicker model", "flicker oracle")


def table(rows: list[Row], title: str) -> list[str]:
    """A markdown table of the ratios (mean, worst) and detection per group of ``rows``."""
    lines = [
        f"### {title}",
        "",
        "| rows | n | " + " | ".join(f"{v} mean (worst)" for v in VARIANTS) + " | cost with model | cost without |"
        " false alarms (steady) | detected (flicker) | gain error RMS |",
        "|---|---|" + "---|" * (len(VARIANTS) + 5),
    ]
    groups: dict[str, list[Row]] = {}
    for row in rows:
        groups.setdefault(row.kind, []).append(row)
    groups["all"] = rows
    for name, members in groups.items():
        mean = {v: float(np.mean([r.ratios[v] for r in members])) for v in VARIANTS}
        worst = {v: float(np.max([r.ratios[v] for r in members])) for v in VARIANTS}
        cost_model = mean["flicker model"] / mean["steady model"] - 1
        cost_plain = mean["flicker plain"] / mean["steady plain"] - 1
        alarms = sum(r.detected_steady for r in members)
        detected = sum(r.detected_flicker for r in members)
        gain_error = float(np.nanmedian([r.gain_error for r in members]))
        lines.append(
            f"| {name} | {len(members)} | "
            + " | ".join(f"{mean[v]:.3f} ({worst[v]:.2f})" for v in VARIANTS)
            + f" | {cost_model:+.1%} | {cost_plain:+.1%} | {alarms}/{len(members)} | {detected}/{len(members)}"
            f" | {gain_error:.3f} |"
        )
    return [*lines, ""]


def model_table(rows: list[Row], title: str) -> list[str]:
    """Every model (:data:`MODELS`): mean (worst) ratio steady, flickering with the gains applied and not, the cost."""
    lines = [
        f"### {title}",
        "",
        "| model | n | steady mean (worst) | flicker, gains applied | flicker, not applied | flicker, true gains |"
        " cost with gains | cost without | cost with true gains | read's cost (applied ÷ true − 1) | target ≤ 5 % |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in MODELS:
        steady = np.array([r.ratios[f"{name} steady"] for r in rows])
        model = np.array([r.ratios[f"{name} flicker"] for r in rows])
        plain = np.array([r.ratios[f"{name} flicker plain"] for r in rows])
        oracle = np.array([r.ratios[f"{name} flicker oracle"] for r in rows])
        cost, cost_plain = model.mean() / steady.mean() - 1, plain.mean() / steady.mean() - 1
        lines.append(
            f"| {name} | {len(rows)} | {steady.mean():.3f} ({steady.max():.2f}) | {model.mean():.3f} ({model.max():.2f})"
            f" | {plain.mean():.3f} ({plain.max():.2f}) | {oracle.mean():.3f} ({oracle.max():.2f}) | **{cost:+.1%}** |"
            f" {cost_plain:+.1%} | {oracle.mean() / steady.mean() - 1:+.1%} | {model.mean() / oracle.mean() - 1:+.1%} |"
            f" {'met' if cost <= 0.05 else 'missed'} |"
        )
    return [*lines, ""]


BOOTSTRAP = 2000
"""Resamples of the cases for a cost's 95 % interval (:func:`cost_interval`)."""


def cost_interval(rows: list[Row], numerator: str, denominator: str) -> tuple[float, float, float]:
    """``mean(numerator) ÷ mean(denominator) − 1`` over ``rows`` and its 95 % percentile interval, resampling whole
    cases (each with all its draws: the draws of one case are not independent of each other) :data:`BOOTSTRAP`
    times with a fixed seed."""
    rows = [r for r in rows if math.isfinite(r.ratios[numerator]) and math.isfinite(r.ratios[denominator])]
    names = sorted({r.case.name for r in rows})
    top = np.array([sum(r.ratios[numerator] for r in rows if r.case.name == n) for n in names])
    bottom = np.array([sum(r.ratios[denominator] for r in rows if r.case.name == n) for n in names])
    picks = np.random.default_rng(0).integers(0, len(names), (BOOTSTRAP, len(names)))
    resampled = top[picks].sum(axis=1) / bottom[picks].sum(axis=1) - 1
    low, high = np.percentile(resampled, [2.5, 97.5])
    return float(top.sum() / bottom.sum() - 1), float(low), float(high)


def _with_interval(value: tuple[float, float, float]) -> str:
    cost, low, high = value
    return f"{cost:+.1%} [{low:+.1%}, {high:+.1%}]"


def paired_table(rows: list[Row], title: str) -> list[str]:
    """Every model on the paired renderings (one noise realisation per draw, both arms): the cost with its 95 %
    interval; the floor (the cost with the true gains applied); the read's share (applied ÷ true − 1); and the
    cost as the first study measured it, re-made from these draws by pairing each draw's flickering rendering with
    the next draw's steady one (different photon draws: what the unpaired figure can swing by)."""
    if not rows:
        return []
    draws = sorted({r.draw for r in rows if r.draw is not None})
    by_draw = {d: {r.case.name: r for r in rows if r.draw == d} for d in draws}
    crossed = [
        replace(
            r,
            ratios={
                **r.ratios,
                **{f"{m} steady": by_draw[draws[(i + 1) % len(draws)]][n].ratios[f"{m} steady"] for m in MODELS},
            },
        )
        for i, d in enumerate(draws)
        for n, r in by_draw[d].items()
    ]
    lines = [
        f"### {title}",
        "",
        "| model | cases × draws | steady mean (worst) | flicker mean (worst) | true gains mean | **cost** [95 % CI] |"
        " floor: cost with true gains [95 % CI] | read's cost (applied ÷ true − 1) [95 % CI] |"
        " one draw's cost, paired: range over draws | one draw's cost, unpaired: range over draws | target ≤ 5 % |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def spread(source: list[Row], name: str) -> str:
        costs = [
            cost_interval([r for r in source if r.draw == d], f"{name} flicker", f"{name} steady")[0] for d in draws
        ]
        return f"{min(costs):+.1%} to {max(costs):+.1%}"

    for name in MODELS:
        columns = (f"{name} steady", f"{name} flicker", f"{name} flicker oracle")
        valid = [r for r in rows if all(math.isfinite(r.ratios[c]) for c in columns)]
        steady, flicker, oracle = (np.array([r.ratios[c] for r in valid]) for c in columns)
        refused = f" ({len(rows) - len(valid)} refused)" if len(valid) < len(rows) else ""
        cost = cost_interval(rows, f"{name} flicker", f"{name} steady")
        verdict = "met" if cost[2] <= 0.05 else ("met (point)" if cost[0] <= 0.05 else "missed")
        lines.append(
            f"| {name} | {len({r.case.name for r in rows})} × {len(draws)}{refused} | {steady.mean():.3f} ({steady.max():.2f})"
            f" | {flicker.mean():.3f} ({flicker.max():.2f}) | {oracle.mean():.3f} | **{_with_interval(cost)}** |"
            f" {_with_interval(cost_interval(rows, f'{name} flicker oracle', f'{name} steady'))} |"
            f" {_with_interval(cost_interval(rows, f'{name} flicker', f'{name} flicker oracle'))} |"
            f" {spread(rows, name)} | {spread(crossed, name)} | {verdict} |"
        )
    return [*lines, ""]


def _split_tables(rows: list[Row], label: str = "") -> list[str]:
    """:func:`paired_table` of the tuning rows and of the held-out rows (``label`` after each title)."""
    return [
        *paired_table(
            [r for r in rows if r.split == "tuning"], f"Tuning rows (lamp kinds {', '.join(TUNING_KINDS)}){label}"
        ),
        *paired_table(
            [r for r in rows if r.split == "held_out"],
            f"Held-out rows (the other lamp kinds; nothing was set on them){label}",
        ),
    ]


def sources_table(rows: list[Row], title: str) -> list[str]:
    """Where each model's cost on ``rows`` (paired draws) comes from, in shares of the mean steady ratio: the floor
    (flicker with the true gains, less steady) and the read's share (as read, less the true gains) split between the
    sequences whose flicker went undetected (left as they are) and those corrected; false alarms (steady renderings
    corrected); and how far the model moves from one noise draw to the next under steady light alone (each case's
    four steady ratios' standard deviation over their mean: median and 90th percentile of the cases) beside how
    far the true gains (and the read) move it from its steady ratio on the same draw (median, 90th percentile)."""
    if not rows:
        return []
    undetected = [r for r in rows if not r.detected_flicker]
    alarms = [r for r in rows if r.detected_steady]
    alarmed = sorted({r.case.name for r in alarms})
    named = "; ".join(
        f"{n} draw{'s' if sum(r.case.name == n for r in alarms) > 1 else ''} "
        + ", ".join(str(r.draw) for r in alarms if r.case.name == n)
        for n in alarmed
    )
    names = sorted({r.case.name for r in rows})
    lines = [
        f"### {title}",
        "",
        f"{len(undetected)} of {len(rows)} flickering renderings undetected; {len(alarms)} of {len(rows)} steady ones "
        "raised a false alarm (their steady arm corrected by the read)" + (f": {named}." if alarms else "."),
        "",
        "| model | floor (true gains − steady) | read's share (read − true gains) | of it: undetected | of it: corrected |"
        " steady, noise alone: draw-to-draw spread (median / 90th pct of cases) | true gains − steady, absolute "
        "(median / 90th pct) | read − true gains, absolute (median / 90th pct) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in MODELS:
        columns = (f"{name} steady", f"{name} flicker", f"{name} flicker oracle")
        valid = [r for r in rows if all(math.isfinite(r.ratios[c]) for c in columns)]
        steady_sum = sum(r.ratios[f"{name} steady"] for r in valid)

        def share(members: list[Row], a: str, b: str, total: float = steady_sum) -> float:
            return sum(r.ratios[a] - r.ratios[b] for r in members) / total

        read = (f"{name} flicker", f"{name} flicker oracle")
        spreads, moved, missed = [], [], []
        for case in names:
            own = [r for r in valid if r.case.name == case]
            steady = np.array([r.ratios[f"{name} steady"] for r in own])
            if steady.size > 1 and steady.mean() > 0:
                spreads.append(float(np.std(steady, ddof=1) / steady.mean()))
            for r in own:
                level = float(steady.mean()) if steady.size else math.nan
                moved.append(abs(r.ratios[f"{name} flicker oracle"] - r.ratios[f"{name} steady"]) / level)
                missed.append(abs(r.ratios[read[0]] - r.ratios[read[1]]) / level)

        def quantiles(values: list[float]) -> str:
            return f"{np.median(values):.1%} / {np.percentile(values, 90):.1%}" if values else "–"

        lines.append(
            f"| {name} | {share(valid, f'{name} flicker oracle', f'{name} steady'):+.1%} | {share(valid, *read):+.1%} |"
            f" {share([r for r in valid if not r.detected_flicker], *read):+.1%} |"
            f" {share([r for r in valid if r.detected_flicker], *read):+.1%} | {quantiles(spreads)} |"
            f" {quantiles(moved)} | {quantiles(missed)} |"
        )
    return [*lines, ""]


def per_kind_index(cases: Sequence[HarnessCase]) -> dict[str, int]:
    """Each case's place among the cases of its lamp kind (0 for the first), as :func:`flicker_cases` lists them."""
    seen: dict[str, int] = {}
    out = {}
    for case in cases:
        out[case.name] = seen.get(case.light_type, 0)
        seen[case.light_type] = out[case.name] + 1
    return out


def paired_section(rows: list[Row], command: str, first_per_kind: int | None = None) -> list[str]:
    """The paired study's tables (tuning and held-out rows) with how they were made. With ``first_per_kind`` (a
    sample larger than the first study's), the tables of every case come first, then those of the first
    ``first_per_kind`` cases of each lamp kind (the first study's sample) and of the cases after them alone."""
    draws = len({r.draw for r in rows})
    kinds = len({r.kind for r in rows})
    place = per_kind_index(list({r.case.name: r.case for r in rows}.values()))
    subsets: list[str] = []
    if first_per_kind is not None and any(place[r.case.name] >= first_per_kind for r in rows):
        earlier = [r for r in rows if place[r.case.name] < first_per_kind]
        later = [r for r in rows if place[r.case.name] >= first_per_kind]
        subsets = [
            f"**The first {first_per_kind} cases of each lamp kind** (the earlier sample, reproduced by this run):",
            "",
            *_split_tables(earlier, f", first {first_per_kind} per kind"),
            f"**The cases after the first {first_per_kind} of each lamp kind, alone** (a replication):",
            "",
            *_split_tables(later, f", cases after the first {first_per_kind} per kind"),
        ]
    return [
        "## Paired: both arms on one noise realisation (the measurement)",
        "",
        f"Each case rendered {draws} times with different noise (`{command}`); in each draw the steady and the "
        "flickering rendering share the photon and read noise (`tests.harness.render.CommonNoise`: the steady "
        "photon count drawn once per pixel, the flickering frame's extra ambient photons added by superposition or "
        "its missing ones removed by thinning; one DN scale for both), so the two arms differ in the ambient's gain "
        "per frame and in nothing else. Cost = mean flickering ÷ mean steady − 1 over cases × draws; the 95 % "
        f"interval resamples whole cases ({BOOTSTRAP} times). *floor*: the flickering rendering with the true gains "
        "applied (a perfect read); *one draw's cost*: the cost from a single draw of every case (as the first study "
        "measured it), the range over the draws, paired and unpaired (each draw's flickering renderings against the "
        "next draw's steady ones). *met* when the interval's upper end is ≤ 5 %; "
        "*met (point)* when only the point estimate is.",
        "",
        *([f"Every case: {len(place)} cases ({kinds} lamp kinds) × {draws} draws.", ""] if subsets else []),
        *_split_tables(rows),
        *subsets,
        "**Where the cost comes from** (every case; shares of the mean steady ratio, so the floor and the read's "
        "share add up to the cost):",
        "",
        *sources_table([r for r in rows if r.split == "tuning"], "Tuning rows: the cost's sources"),
        *sources_table([r for r in rows if r.split == "held_out"], "Held-out rows: the cost's sources"),
        *(
            [
                "Refused (a model's `SpectralDataError`, what `msflash estimate` exits 2 with; that case's draw is left "
                "out of both arms for that model):",
                "",
                *(f"- {r.case.name} draw {r.draw}: {message}" for r in rows for message in r.failures),
                "",
            ]
            if any(r.failures for r in rows)
            else []
        ),
    ]


def report(rows: list[Row], command: str, paired: list[Row] | None = None, first_per_kind: int | None = None) -> str:
    """docs/flicker-results.md (``first_per_kind``: :func:`paired_section`'s)."""
    tuning = [r for r in rows if r.split == "tuning"]
    held = [r for r in rows if r.split == "held_out"]
    if not tuning or not held:  # one split measured (``--split``): its paired tables alone
        return "\n".join(
            [
                "# Flicker study: results (one split)",
                "",
                f"Generated by `{command}` (tests/harness/flicker.py; the method and the reading are in "
                "docs/flicker.md).",
                "",
                *(paired_section(paired, command, first_per_kind) if paired else []),
            ]
        )
    steady_offsets = [r.steady_offset for r in tuning]
    tuning_z = np.concatenate([r.steady_z for r in tuning])
    held_z = np.concatenate([r.steady_z for r in held])
    lines = [
        "# Flicker study: results",
        "",
        f"Generated by `{command}` (tests/harness/flicker.py; the method and the reading are in docs/flicker.md).",
        "",
        f"{DEPTH:.0%} flicker, {EXPOSURE_MS[0]:g}–{EXPOSURE_MS[1]:g} ms exposures, frames {FRAME_GAP_MS[0]:g}–"
        f"{FRAME_GAP_MS[1]:g} ms apart; ratio = spectrum RMSE ÷ the LED bound (lower is better). *plain*: the LED "
        "model without the gain model; *model*: with it (msflash's default). Cost = mean ratio flickering ÷ "
        "mean ratio steady − 1. *oracle*: the flickering rendering corrected by the true gains (what a perfect "
        "read would give; it differs from *steady* by the noise alone, the two renderings' photon draws differing).",
        "",
        *(paired_section(paired, command, first_per_kind) if paired else []),
        "## Every model, as `msflash estimate` runs it"
        + (" (unpaired: the first study's measurement)" if paired else ""),
        "",
        *(
            [
                "Kept beside the paired tables for comparison: here the two renderings' photon draws differ (each "
                "rendered from the case's stream, which diverges at the first frame whose mean differs), so a "
                "difference of means holds each model's draw-to-draw spread as well as the flicker.",
                "",
            ]
            if paired
            else []
        ),
        "*led* `--method global`, *local* `--method local`, *prior*/*family*/*auto* `--model …` (default method). "
        "*gains applied*: msflash's default; *not applied*: the same read, the statistics left as they are "
        "(`processing.flicker.gains_not_applied`). Cost = mean flickering ÷ mean steady − 1.",
        "",
        *model_table(tuning, f"Tuning rows (lamp kinds {', '.join(TUNING_KINDS)})"),
        *model_table(held, "Held-out rows (the other lamp kinds; nothing was set on them)"),
        "## The LED model in detail",
        "",
        *table(tuning, f"Tuning rows (lamp kinds {', '.join(TUNING_KINDS)})"),
        *table(held, "Held-out rows (the other lamp kinds)"),
        "### The colour read under steady light (tuning rows)",
        "",
        f"Largest |ê_i| per case: median {np.median(steady_offsets):.3f}, 90th percentile "
        f"{np.percentile(steady_offsets, 90):.3f}, max {np.max(steady_offsets):.3f} "
        "",
        "Each LED's steady read in its own sigma (noise, MODEL_ERROR, CURVATURE_ERROR × its curvature share, "
        "RESIDUAL_ERROR × the colour the ambient leaves unexplained): "
        f"within ±1σ {np.mean(tuning_z <= 1):.0%} of {tuning_z.size} reads, ±2σ {np.mean(tuning_z <= 2):.0%}, beyond "
        f"the detection threshold {np.mean(tuning_z > 3):.1%} (tuning rows); held-out rows {np.mean(held_z <= 1):.0%}, "
        f"{np.mean(held_z <= 2):.0%}, {np.mean(held_z > 3):.1%} of {held_z.size}.",
        "",
        "### Per case",
        "",
        "| case | kind | split | camera | CFA | "
        + " | ".join(VARIANTS)
        + " | true spread | gain error | alarm | detected | "
        + " | ".join(f"{m} steady / flicker / plain / true gains" for m in MODELS if m != "led")
        + " |",
        "|---|---|---|---|---|" + "---|" * (len(VARIANTS) + 4 + len(MODELS) - 1),
    ]
    for r in rows:
        lines.append(
            f"| {r.case.name} | {r.kind} | {r.split} | {r.case.camera} | {r.case.cfa or 'RGB'} | "
            + " | ".join(f"{r.ratios[v]:.3f}" for v in VARIANTS)
            + f" | {r.true_spread:.3f} | {r.gain_error:.3f} | {'yes' if r.detected_steady else ''} | "
            f"{'yes' if r.detected_flicker else ''} | "
            + " | ".join(
                " / ".join(
                    f"{r.ratios[f'{m} {v}']:.3f}" for v in ("steady", "flicker", "flicker plain", "flicker oracle")
                )
                for m in MODELS
                if m != "led"
            )
            + " |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.harness.flicker", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="write the markdown report here (default: print it)")
    parser.add_argument("--per-kind", type=int, default=PER_KIND, help="cases per lamp kind of the paired measurement")
    parser.add_argument(
        "--unpaired-per-kind",
        type=int,
        default=None,
        help="measure only the first N cases of each lamp kind unpaired (default: every case); with a larger "
        "--per-kind their paired tables are shown apart too, beside the later cases' alone",
    )
    parser.add_argument(
        "--split",
        choices=("both", "tuning", "held_out"),
        default="both",
        help="measure only the tuning rows (lamp kinds the constants were set on) or only the held-out ones",
    )
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument(
        "--draws", type=int, default=DRAWS, help="paired noise draws per case (0: only the unpaired measurement)"
    )
    parser.add_argument("--rows", default=None, help="also pickle the measured rows here (for a closer look)")
    parser.add_argument(
        "--from-rows",
        default=None,
        help="write the report from rows pickled by --rows (measured with the same options) instead of measuring",
    )
    args = parser.parse_args(argv)
    cases = flicker_cases(args.per_kind)
    if args.split != "both":
        cases = [c for c in cases if (c.light_type in TUNING_KINDS) == (args.split == "tuning")]
    place = per_kind_index(cases)
    unpaired = args.per_kind if args.unpaired_per_kind is None else args.unpaired_per_kind
    jobs: list[tuple[HarnessCase, int | None]] = [
        (c, d) for c in cases for d in ((None,) if place[c.name] < unpaired else ()) + tuple(range(args.draws))
    ]
    if args.from_rows:
        measured = pickle.loads(Path(args.from_rows).read_bytes())
    elif args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            measured = list(pool.map(_measured, jobs, chunksize=1))
    else:
        measured = [_measured(job) for job in jobs]
    if args.rows and not args.from_rows:
        Path(args.rows).write_bytes(pickle.dumps(measured))
    rows = [r for r in measured if r.draw is None]
    paired = [r for r in measured if r.draw is not None]
    command = (
        "python -m tests.harness.flicker --jobs 2"
        + (f" --per-kind {args.per_kind}" if args.per_kind != PER_KIND else "")
        + (f" --unpaired-per-kind {args.unpaired_per_kind}" if args.unpaired_per_kind is not None else "")
        + (f" --split {args.split}" if args.split != "both" else "")
        + (f" --draws {args.draws}" if args.draws != DRAWS else "")
    )
    text = report(
        rows,
        command + (f" --out {args.out}" if args.out else ""),
        paired,
        unpaired if unpaired < args.per_kind else None,
    )
    if args.out:
        Path(args.out).write_text(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
