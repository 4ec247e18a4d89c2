"""The accuracy-against-compute chart and the warning ROC of the family model (issue 30, items 4 and 7).

From :mod:`tests.harness.family_study`'s output (one row per case and candidate, one record per case): for
``led`` (``msflash estimate``), each family alone (the family model restricted to that family's candidates,
chosen by the same rule), ``prior``, ``family`` and ``auto``, the mean and worst ratio to the LED bound against
the median compute per estimate; and for every model the ROC of its miss check (the predicted ratio to the LED
bound against the family evidence, :func:`processing.family_checks.predicted_ratio` and ``self_check``), with
the operating point the shipped thresholds give.
"""

from __future__ import annotations

import collections
import csv
import json
import math
from pathlib import Path

import numpy as np

from msflash.processing.family_checks import FAMILY_WARNING, LED_WARNING, MISS_RATIO, PRIOR_WARNING
from msflash.processing.light_families import AUTO_MARGIN, CHECK_TEMPERATURE, SIMPLER_WITHIN

FAMILY_ORDER = ("thermal", "discharge", "solid_state", "transmitted", "mixture")


def load(csv_path: Path) -> tuple[dict[str, list[dict]], dict[str, dict]]:
    """(candidate rows by case, case records by case) of a study run."""
    rows: dict[str, list[dict]] = collections.defaultdict(list)
    with csv_path.open() as handle:
        for row in csv.DictReader(handle):
            if row.get("candidate") != "error":
                rows[row["case"]].append(row)
    records = {r["case"]: r for r in json.loads(csv_path.with_suffix(".cases.json").read_text()) if "error" not in r}
    return {k: v for k, v in rows.items() if k in records}, records


def _choose(candidates: list[dict]) -> dict:
    """The family model's rule on study rows: least held-out error (noise removed), the simplest within the margin."""
    best = min(candidates, key=lambda r: float(r["held_out_clean"]))
    limit = float(best["held_out_clean"]) * (1 + SIMPLER_WITHIN)
    simpler = [
        r
        for r in candidates
        if float(r["held_out_clean"]) <= limit and int(r["n_parameters"]) < int(best["n_parameters"])
    ]
    return min(simpler, key=lambda r: (int(r["n_parameters"]), float(r["held_out_clean"]))) if simpler else best


def points(rows: dict[str, list[dict]], records: dict[str, dict]) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(label, ratios, seconds) per model: led, each family alone, prior, family, auto."""
    out = []

    def series(label: str, ratio_of, seconds_of) -> None:  # noqa: ANN001 — small closures
        ratios = np.array([ratio_of(case) for case in rows], float)
        seconds = np.array([seconds_of(case) for case in rows], float)
        out.append((label, ratios, seconds))

    series("led", lambda c: records[c]["led:ratio"], lambda c: records[c]["t:led"])
    for family in FAMILY_ORDER:

        def ratio(case: str, family: str = family) -> float:
            own = [r for r in rows[case] if r["candidate_family"] == family]
            return float(_choose(own)["ratio"]) if own else math.nan

        def seconds(case: str, family: str = family) -> float:
            wanted = {family} if family != "mixture" else set(FAMILY_ORDER)
            spent = sum(float(r.get("seconds") or 0) for r in rows[case] if r["candidate_family"] in wanted)
            return records[case]["t:statistics"] + spent

        series(family, ratio, seconds)
    series("prior", lambda c: records[c]["prior:ratio"], lambda c: records[c]["t:statistics"] + records[c]["t:prior"])
    total = {c: records[c]["t:statistics"] + records[c]["t:prior"] + records[c]["t:family"] for c in rows}
    series("family (all)", lambda c: records[c]["family:ratio"], lambda c: total[c])
    series("auto", lambda c: records[c]["auto:ratio"], lambda c: total[c] + records[c]["t:led"])
    return out


def chart_table(series: list[tuple[str, np.ndarray, np.ndarray]]) -> list[str]:
    """Markdown rows: model, mean, worst, misses, median compute."""
    lines = [
        "| model | cases | mean ratio | worst | misses (> 1.3) | median compute per estimate (ms) |",
        "|---|---|---|---|---|---|",
    ]
    for label, ratios, seconds in series:
        ok = ratios[np.isfinite(ratios)]
        lines.append(
            f"| {label} | {ok.size} | {ok.mean():.2f} | {ok.max():.2f} | {np.mean(ok > MISS_RATIO):.0%} "
            f"| {1000 * np.median(seconds):.0f} |"
        )
    return lines


def draw_chart(series: list[tuple[str, np.ndarray, np.ndarray]], path: Path, title: str) -> None:
    """Mean ratio (and worst, as a bar) against the median compute, log time axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(7, 4.5))
    for index, (label, ratios, seconds) in enumerate(series):
        ok = ratios[np.isfinite(ratios)]
        x = 1000 * float(np.median(seconds))
        axes.errorbar(x, ok.mean(), yerr=[[0], [ok.max() - ok.mean()]], fmt="o", capsize=3)
        offset = (5, -10 - 9 * (index % 3))  # neighbours at one compute stay readable
        axes.annotate(label, (x, ok.mean()), textcoords="offset points", xytext=offset, fontsize=8)
    axes.axhline(1.0, color="grey", lw=0.8, ls=":")
    axes.set_xscale("log")
    axes.set_xlabel("median compute per estimate (ms; statistics + fit + held-out judgement)")
    axes.set_ylabel("RMSE ÷ LED bound (mean; bar to the worst)")
    axes.set_title(title, fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _roc(score: np.ndarray, miss: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    order = np.argsort(-score)
    hits = np.concatenate([[0], np.cumsum(miss[order])]) / max(miss.sum(), 1)
    alarms = np.concatenate([[0], np.cumsum(~miss[order])]) / max((~miss).sum(), 1)
    positives, negatives = score[miss], score[~miss]
    auc = (
        float(np.mean([(p > negatives).mean() + 0.5 * (p == negatives).mean() for p in positives]))
        if positives.size and negatives.size
        else math.nan
    )
    return alarms, hits, auc


def warning_scores(records: dict[str, dict]) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
    """Per model: (predicted ratio, truly a miss, threshold) — the shipped checks recomputed from the study."""
    cases = list(records.values())
    tau = f"{CHECK_TEMPERATURE:g}"  # the τ of the spread self_check reads (the distances do not depend on τ)

    def column(key: str, default: float = 0.0) -> np.ndarray:
        return np.nan_to_num(np.array([float(c.get(key, default)) for c in cases]), nan=0.0)

    led, prior = column(f"d:led:chosen:{tau}"), column(f"d:prior:chosen:{tau}")
    # self_check's score: the spread over the bound, times the chosen candidate's held-out error over the LEDs'.
    led_error = column("led_held_out_clean", 1.0)
    relative = np.where(led_error > 0, column("chosen_held_out_clean", 1.0) / np.where(led_error > 0, led_error, 1), 1)
    spread = column(f"spread:chosen:{tau}") * relative
    auto_led = np.array([c["auto"] == "led" for c in cases])
    return {
        "led": (led, column("led:ratio") > MISS_RATIO, LED_WARNING),
        "prior": (prior, column("prior:ratio") > MISS_RATIO, PRIOR_WARNING),
        "family": (spread, column("family:ratio") > MISS_RATIO, FAMILY_WARNING),
        "auto": (
            np.where(auto_led, led / LED_WARNING, spread / FAMILY_WARNING),
            column("auto:ratio") > MISS_RATIO,
            1.0,
        ),
    }


def roc_table(scores: dict[str, tuple[np.ndarray, np.ndarray, float]]) -> list[str]:
    """Markdown rows: model, misses, AUC, recall and false alarms at the shipped threshold."""
    lines = [
        "| model | cases | misses | ROC area | recall at the threshold | false alarms |",
        "|---|---|---|---|---|---|",
    ]
    for model, (score, miss, threshold) in scores.items():
        _, _, auc = _roc(score, miss)
        warned = score >= threshold
        recall = (warned & miss).sum() / max(miss.sum(), 1)
        alarms = (warned & ~miss).sum() / max((~miss).sum(), 1)
        lines.append(
            f"| {model} | {miss.size} | {miss.sum()} | {auc:.2f} | {recall:.0%} ({(warned & miss).sum()} of "
            f"{miss.sum()}) | {alarms:.0%} |"
        )
    return lines


def draw_roc(scores: dict[str, tuple[np.ndarray, np.ndarray, float]], path: Path, title: str) -> None:
    """The ROC curves, each model's shipped threshold marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(5.5, 5))
    for model, (score, miss, threshold) in scores.items():
        alarms, hits, auc = _roc(score, miss)
        (line,) = axes.plot(alarms, hits, label=f"{model} (area {auc:.2f})")
        warned = score >= threshold
        axes.plot(
            (warned & ~miss).sum() / max((~miss).sum(), 1),
            (warned & miss).sum() / max(miss.sum(), 1),
            "o",
            color=line.get_color(),
        )
    axes.plot([0, 1], [0, 1], color="grey", lw=0.8, ls=":")
    axes.axvline(0.2, color="grey", lw=0.6, ls="--")
    axes.axhline(0.8, color="grey", lw=0.6, ls="--")
    axes.set_xlabel("false alarms (warned non-misses ÷ non-misses)")
    axes.set_ylabel("recall (warned misses ÷ misses)")
    axes.set_title(title, fontsize=10)
    axes.legend(fontsize=8, loc="lower right")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def markdown(study: Path, out_dir: Path, label: str) -> list[str]:
    """The chart and ROC of one study run, written beside ``out_dir``, and their tables."""
    rows, records = load(study)
    series = points(rows, records)
    chart = out_dir / f"light-families-compute-{label}.png"
    draw_chart(series, chart, f"Accuracy against compute, physics suite, {label} rows ({len(rows)} cases)")
    scores = warning_scores(records)
    roc = out_dir / f"light-families-roc-{label}.png"
    draw_roc(scores, roc, f"Miss checks, physics suite, {label} rows")
    return [
        f"### Accuracy against compute ({label} rows)",
        "",
        f"![accuracy against compute]({chart.name})",
        "",
        *chart_table(series),
        "",
        f"### Warning ROC ({label} rows; thresholds chosen on tuning rows, auto margin {AUTO_MARGIN:g})",
        "",
        f"![ROC]({roc.name})",
        "",
        *roc_table(scores),
        "",
    ]
