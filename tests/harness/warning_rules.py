"""``python -m tests.harness.warning_rules RECORDS.json …``: warning evidence evaluated offline on cached records.

Reads :mod:`tests.harness.warning_study`'s records and computes, per model (``led``, ``prior``, ``family``,
``auto``), the scores a warning could rest on — the shipped checks and the physics-motivated candidates (module
functions) — with each score's ROC area and its best recall at ≤ 20 % false alarms. Thresholds are chosen on the
**tuning** records only.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from msflash.processing.family_checks import (
    FAMILY_WARNING,
    LED_WARNING,
    MISS_RATIO,
    led_bound,
    paper_rmse,
)

MODELS = ("led", "prior", "family", "auto")
TRIED_LED, TRIED_LED_HALF = 1.168, 0.842
"""The LEDs' check tried and withdrawn (docs/decisions/2026-11-warning-evidence.md): the distance from the family
estimate from 1.168, or the LEDs' split half from 0.842 of the family's LED bound."""

RULES: dict[str, dict[str, tuple[tuple[str, float], ...]]] = {
    "led": {
        "shipped (1.13)": (("shipped", 1.13),),
        "tried: distance or split half": (("checked", TRIED_LED),),
        "split half": (("half:full/own", 0.687),),
        "jackknife": (("jack:std/own", 0.168),),
        "shipped or split half": (("shipped", 1.168), ("half:full/own", 0.842)),
    },
    "prior": {
        "shipped (1.2)": (("shipped", 1.2),),
        "split half": (("half:full/own", 0.338),),
        "jackknife": (("jack:std/own", 0.184),),
        "shipped or candidates' band": (("shipped", 1.22), ("band_f/own", 3.475)),
    },
    "family": {
        "shipped (1.05)": (("shipped", 1.05),),
        "split half": (("half:full/own", 1.026),),
        "jackknife": (("jack:std/own", 1.202),),
        "split half or candidates' band": (("half:full/own", 1.099), ("band_f/own", 4.476)),
    },
    "auto": {
        "shipped": (("shipped", 1.0),),
        "tried: with the LEDs' split half": (("checked", 1.0),),
        "split half": (("half:full/own", 0.833),),
        "jackknife": (("jack:std/own", 0.914),),
        "shipped or split half": (("shipped", 1.06), ("half:full/own", 1.208)),
    },
}
"""Candidate rules, frozen on the pooled **tuning** records of both suites before any held-out record was computed
(each a warning when any of its scores reaches its threshold). Single scores: the threshold of most tuning misses
at ≤ 15 % false alarms in each suite (``shipped``: the thresholds in :mod:`processing.family_checks`); pairs: the
best of a search over every pair of scores and thresholds at the same cap (in-sample, so optimistic)."""


def _bounded(spectrum: np.ndarray, leds: np.ndarray) -> float:
    bound = led_bound(leds, spectrum)
    return bound if bound > 0 else math.nan


def _tolerated(record: dict, tolerance: float) -> list[dict]:
    """Candidates whose evidence is within ``tolerance`` (relative) of the best."""
    candidates = [c for c in record["candidates"] if c["family"] not in ("prior",)]
    best = min(c["evidence"] for c in record["candidates"])
    return [c for c in candidates if c["evidence"] <= best * (1 + tolerance)]


def features(record: dict) -> dict[str, dict[str, float]]:
    """Per model, every score (larger = more likely a miss)."""
    unit = np.asarray(record["unit"])
    leds = np.asarray(record["led_spd"])
    family = np.asarray(record["family_spectrum"]) * unit
    prior = np.asarray(record["prior"]) * unit
    led = np.asarray(record["led_seq"])
    auto_is_led = record["auto_model"] == "led"
    auto = led if auto_is_led else family
    estimates = {"led": led, "prior": prior, "family": family, "auto": auto}
    bounds = {name: _bounded(x, leds) for name, x in estimates.items()}
    # An estimate in the LEDs' span has no bound of its own: the family estimate stands in for the truth.
    bounds["led"] = bounds["family"]
    if auto_is_led:
        bounds["auto"] = bounds["family"]
    plausible = [np.asarray(c["spectrum"]) * unit for c in _tolerated(record, 0.2)] + [family, prior]
    least_bound = min(_bounded(s, leds) for s in plausible)
    peak = float(np.max(family)) or 1.0
    spread = np.asarray(record["spread"]) * unit
    spread_score = float(np.sqrt(np.mean((spread / peak) ** 2))) / bounds["family"] * record["relative_error"]
    shipped = {
        "led": paper_rmse(led, family) / bounds["family"],
        "prior": paper_rmse(prior, family) / bounds["family"],
        "family": spread_score,
    }
    shipped["auto"] = shipped["led"] / LED_WARNING if auto_is_led else shipped["family"] / FAMILY_WARNING

    # Split-half consistency: each model's estimate from two disjoint halves of the folds.
    halves = [h for h in record["halves"] if "error" not in h]
    half = {}
    if len(halves) == 2:
        a, b = halves
        half_est = {
            "led": (np.asarray(a["led"]) * unit, np.asarray(b["led"]) * unit),
            "prior": (np.asarray(a["prior"]) * unit, np.asarray(b["prior"]) * unit),
            "family": (np.asarray(a["family"]) * unit, np.asarray(b["family"]) * unit),
        }
        half_est["auto"] = half_est["led"] if auto_is_led else half_est["family"]
        for name, (x, y) in half_est.items():
            own = bounds[name]
            half[name] = {
                "half:pair/own": paper_rmse(x, y) / own,
                "half:pair/fam": paper_rmse(x, y) / bounds["family"],
                "half:full/own": max(paper_rmse(x, estimates[name]), paper_rmse(y, estimates[name])) / own,
            }
        half["family"]["half:choice_differs"] = float(a["chosen"] != b["chosen"])
        half["auto"]["half:auto_differs"] = float((a["auto_model"] == "led") != (b["auto_model"] == "led"))
        half["auto"]["half:auto_any_led"] = float((a["auto_model"] == "led") or (b["auto_model"] == "led"))
    # Jackknife: each model's estimate with one fold of block rows left out (a light the pixels pin reads the same).
    jack: dict[str, dict[str, float]] = {}
    parts = [j for j in record.get("jackknife", []) if "error" not in j]
    if parts:
        led_full = np.asarray(record["led_candidate"]["spectrum"]) * unit
        replicas = {
            "led": ([np.asarray(j["led"]) * unit for j in parts], led_full),
            "prior": ([np.asarray(j["prior"]) * unit for j in parts], prior),
            "family": ([np.asarray(j["family"]) * unit for j in parts], family),
            "auto": ([led if j["auto_model"] == "led" else np.asarray(j["family"]) * unit for j in parts], auto),
        }
        n = len(parts)
        for name, (spectra, full) in replicas.items():
            d = np.array([paper_rmse(x, full) for x in spectra])
            jack[name] = {
                "jack:std/own": float(np.sqrt((n - 1) * np.mean(d**2))) / bounds[name],
                "jack:max/own": float(d.max()) / bounds[name],
                "jack:std/fam": float(np.sqrt((n - 1) * np.mean(d**2))) / bounds["family"],
            }
        cheap = [np.asarray(x) * unit for x in record.get("amplitude_jackknife", [])]
        if cheap:
            d = np.array([paper_rmse(x, family) for x in cheap])
            for name in ("family", "auto"):
                if name == "auto" and auto_is_led:
                    continue
                jack[name]["ajack:std/own"] = float(np.sqrt((len(d) - 1) * np.mean(d**2))) / bounds["family"]
                jack[name]["ajack:max/own"] = float(d.max()) / bounds["family"]
        jack["family"]["jack:choice_changes"] = float(np.mean([j["chosen"] != record["chosen"] for j in parts]))
        jack["auto"]["jack:auto_changes"] = float(np.mean([(j["auto_model"] == "led") != auto_is_led for j in parts]))
    # Surface halves: every model read from reddish and bluish blocks, from dark and bright ones.
    surface: dict[str, dict[str, float]] = {}
    for split, readings in record.get("surface_halves", {}).items():
        good = [h for h in readings if "error" not in h]
        if len(good) != 2:
            continue
        a, b = good
        pairs_of = {
            "led": (np.asarray(a["led"]) * unit, np.asarray(b["led"]) * unit),
            "prior": (np.asarray(a["prior"]) * unit, np.asarray(b["prior"]) * unit),
            "family": (np.asarray(a["family"]) * unit, np.asarray(b["family"]) * unit),
        }
        pairs_of["auto"] = pairs_of["led"] if auto_is_led else pairs_of["family"]
        for name, (x, y) in pairs_of.items():
            row = surface.setdefault(name, {})
            row[f"surf:{split}:pair/own"] = paper_rmse(x, y) / bounds[name]
            row[f"surf:{split}:full/own"] = (
                max(paper_rmse(x, estimates[name]), paper_rmse(y, estimates[name])) / (bounds[name])
            )
    for row in surface.values():
        if row:
            row["surf:max/own"] = max(v for k, v in row.items() if k.endswith("full/own"))
            row["surf:pairmax/own"] = max(v for k, v in row.items() if k.endswith("pair/own"))
    # Spread over candidates within the evidence's tolerance, in the metric of the LED bound.
    tol = {}
    for tolerance in (0.05, 0.1, 0.2, 0.5):
        near = _tolerated(record, tolerance)
        spectra = [np.asarray(c["spectrum"]) * unit for c in near]
        for name, x in estimates.items():
            dist = [paper_rmse(s, x) for s in spectra] or [0.0]
            tol.setdefault(name, {})[f"tol{tolerance}:max/own"] = max(dist) / bounds[name]
            tol[name][f"tol{tolerance}:rms/own"] = float(np.sqrt(np.mean(np.square(dist)))) / bounds[name]
        tol.setdefault("family", {})[f"tol{tolerance}:count"] = float(len(near))
    # The camera-and-LED null space: the part of a candidate's difference that L cannot see.
    lift = np.asarray(record["lift"])
    null = np.eye(lift.shape[1]) - np.linalg.pinv(lift) @ lift
    chosen = np.asarray(record["family_spectrum"])
    null_scores = {}
    for tolerance in (0.1, 0.5):
        near = _tolerated(record, tolerance)
        diffs = []
        for c in near:
            s = np.asarray(c["spectrum"])
            s = s * (float(s @ chosen) / float(s @ s)) if float(s @ s) > 0 else s
            diffs.append(np.sqrt(np.mean(((null @ (s - chosen)) * unit / peak) ** 2)))
        null_scores[f"null{tolerance}"] = (max(diffs) if diffs else 0.0) / bounds["family"]
    # Energy where the camera is nearly blind (< 10 % of its peak), as a share of each estimate's.
    planes = np.asarray(record["camera_planes"]).max(axis=1)
    blind = planes < 0.1 * planes.max()
    blind_share = {}
    for name, x in estimates.items():
        photons = x / np.where(unit > 0, unit, 1)
        total = float(photons @ photons)
        blind_share[name] = float(photons[blind] @ photons[blind]) / total if total > 0 else 0.0
    # Bands: the family's posterior over the LEDs' band; and against the bound.
    fstd = np.asarray(record["family_std"]) * unit
    band_f = float(np.sqrt(np.mean((fstd / peak) ** 2)))
    led_peak = float(np.max(led)) or 1.0
    band_l = float(np.sqrt(np.mean((np.asarray(record["led_std_seq"]) / led_peak) ** 2)))
    prior_peak = float(np.max(prior)) or 1.0
    band_p = float(np.sqrt(np.mean((np.asarray(record["prior_std"]) * unit / prior_peak) ** 2)))
    # Disagreement among the three in the LED-bound metric.
    pairs = {
        "led-prior": paper_rmse(led, prior),
        "led-family": paper_rmse(led, family),
        "prior-family": paper_rmse(prior, family),
    }
    led_c = record["led_candidate"]
    best = min(c["evidence"] for c in record["candidates"])
    dim = planes < 0.2 * planes.max()

    def region_gap(x: np.ndarray, s: np.ndarray, where: np.ndarray) -> float:
        xs, ss = x / (float(np.max(x)) or 1.0), s / (float(np.max(s)) or 1.0)
        return float(np.sqrt(np.sum((xs - ss)[where] ** 2) / xs.size))

    # The LEDs' check tried and withdrawn: the distance or, rescaled, the split half (the LEDs' span's).
    if "led" in half:
        led_checked = max(shipped["led"], half["led"]["half:full/own"] * TRIED_LED / TRIED_LED_HALF)
        checked = {"led": led_checked, "prior": shipped["prior"], "family": shipped["family"]}
        checked["auto"] = led_checked / TRIED_LED if auto_is_led else shipped["family"] / FAMILY_WARNING
    else:
        checked = dict(shipped)
    out: dict[str, dict[str, float]] = {}
    for name in MODELS:
        own = bounds[name]
        row = {
            "shipped": shipped[name],
            "checked": checked[name],
            "own_bound_inv": 1.0 / own,
            "blind": blind_share[name],
            "blind/own": blind_share[name] / own,
            "band_f/own": band_f / own,
            "band_f/band_l": band_f / band_l if band_l > 0 else math.nan,
            "band_p/own": band_p / own,
            "pair_max/own": max(pairs.values()) / own,
            "from_others/own": max(paper_rmse(estimates[name], x) for o, x in estimates.items() if o != name) / own,
            "noise/led": led_c["noise_share"] / max(led_c["held_out"] ** 2, 1e-300),
            "gain": 1 - best / max(led_c["evidence"], 1e-300),
            "blind_gap": max(region_gap(estimates[name], s, blind) for s in [*plausible, led]) / own,
            "dim_gap": max(region_gap(estimates[name], s, dim) for s in [*plausible, led]) / own,
            "seen_gap": max(region_gap(estimates[name], s, ~dim) for s in [*plausible, led]) / own,
            "led_rel": paper_rmse(estimates[name], led) / own * record["relative_error"],
            "led_rel2": paper_rmse(estimates[name], led) / own * record["relative_error"] ** 2,
            "worst_plausible": max(paper_rmse(estimates[name], s) for s in plausible) / least_bound,
            "from_led/least": paper_rmse(estimates[name], led) / least_bound,
            "from_prior/least": paper_rmse(estimates[name], prior) / least_bound,
            "from_family/least": paper_rmse(estimates[name], family) / least_bound,
            **null_scores,
            **half.get(name, {}),
            **jack.get(name, {}),
            **surface.get(name, {}),
            **tol.get(name, {}),
        }
        out[name] = row
    return out


def truth_miss(record: dict, model: str) -> bool:
    """Whether ``model``'s estimate is a miss (> :data:`MISS_RATIO` × the truth's LED bound)."""
    return bool(record["ratio"][model] > MISS_RATIO)


def roc(score: np.ndarray, miss: np.ndarray) -> tuple[float, float, float, float]:
    """ROC area, and the best recall at ≤ 20 % false alarms with its threshold and false-alarm rate."""
    score = np.nan_to_num(score, nan=-np.inf)
    positives, negatives = score[miss], score[~miss]
    if not positives.size or not negatives.size:
        return math.nan, math.nan, math.nan, math.nan
    auc = float(np.mean([(p > negatives).mean() + 0.5 * (p == negatives).mean() for p in positives]))
    best = (0.0, math.inf, 1.0)
    for threshold in np.unique(score):
        warned = score >= threshold
        alarms = (warned & ~miss).sum() / negatives.size
        recall = (warned & miss).sum() / positives.size
        if alarms <= 0.2 and (recall, -alarms) > (best[0], -best[2]):
            best = (recall, float(threshold), alarms)
    return auc, *best


def rule_table(records: list[dict], label: str) -> list[str]:
    """Markdown rows: every frozen rule's recall and false alarms on ``records`` (one suite, one split), overall and
    per light kind (the suite's family or library class)."""
    table = [features(r) for r in records]
    kinds = sorted({r["family"] for r in records})
    lines = []
    for model, rules in RULES.items():
        miss = np.array([truth_miss(r, model) for r in records])
        for rule, parts in rules.items():
            warned = np.zeros(len(records), bool)
            for key, threshold in parts:
                warned |= (
                    np.nan_to_num(np.array([t[model].get(key, math.nan) for t in table], float), nan=-1) >= threshold
                )
            cells = []
            for kind in kinds:
                of = np.array([r["family"] == kind for r in records])
                cells.append(
                    f"{(warned & miss & of).sum()}/{(miss & of).sum()}, {(warned & ~miss & of).sum()}/{(~miss & of).sum()}"
                )
            recall = (warned & miss).sum() / max(miss.sum(), 1)
            alarms = (warned & ~miss).sum() / max((~miss).sum(), 1)
            lines.append(
                f"| {label} | {model} | {rule} | {(warned & miss).sum()} of {miss.sum()} ({recall:.0%}) | {alarms:.0%} | "
                + " ; ".join(f"{k} {c}" for k, c in zip(kinds, cells))
                + " |"
            )
    return lines


SHOWN = {
    "shipped": "the shipped check (the LEDs', the prior's: distance from the family estimate; the family's: its "
    "candidates' spread)",
    "checked": "the LEDs' check with their split half (tried, withdrawn)",
    "half:full/own": "split half: the farther half's reading from the estimate, over the LED bound",
    "half:pair/own": "split half: the two halves' readings apart, over the LED bound",
    "jack:std/own": "jackknife over the five folds (each left out), over the LED bound",
    "tol0.2:max/own": "the farthest candidate within 20 % of the best evidence, over the LED bound",
    "null0.5": "that spread in the null space of the lift (what camera and LEDs cannot see)",
    "blind": "the estimate's energy share where the camera is below 10 % of its peak",
    "band_f/band_l": "the family's band over the LEDs' band",
    "pair_max/own": "the largest disagreement of LEDs, prior and family, over the LED bound",
    "worst_plausible": "the farthest plausible spectrum over the least plausible LED bound",
}
"""The scores the generated page shows (every score in :func:`features` is printed by the command line)."""


def _roc_curve(score: np.ndarray, miss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    score = np.nan_to_num(score, nan=-np.inf)
    order = np.argsort(-score)
    hits = np.concatenate([[0], np.cumsum(miss[order])]) / max(miss.sum(), 1)
    alarms = np.concatenate([[0], np.cumsum(~miss[order])]) / max((~miss).sum(), 1)
    return alarms, hits


def draw(records: list[dict], path: Path, title: str) -> None:
    """One ROC panel per model: the shipped check, the tried LED check, the split half and the jackknife."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = [features(r) for r in records]
    figure, axes = plt.subplots(1, 4, figsize=(14, 3.8), sharey=True)
    for axis, model in zip(axes, MODELS):
        miss = np.array([truth_miss(r, model) for r in records])
        for key in ("shipped", "checked", "half:full/own", "jack:std/own"):
            score = np.array([t[model].get(key, math.nan) for t in table], float)
            auc = roc(score, miss)[0]
            axis.plot(*_roc_curve(score, miss), label=f"{key.split(':')[0]} ({auc:.2f})")
        axis.plot([0, 1], [0, 1], color="grey", lw=0.8, ls=":")
        axis.axvline(0.2, color="grey", lw=0.6, ls="--")
        axis.axhline(0.8, color="grey", lw=0.6, ls="--")
        axis.set_title(f"{model}: {miss.sum()} misses of {miss.size}", fontsize=9)
        axis.set_xlabel("false alarms")
        axis.legend(fontsize=7, loc="lower right")
    axes[0].set_ylabel("recall")
    figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def document(paths: list[Path], out: Path) -> None:
    """``out`` (markdown) and its ROC charts beside it, from record files named ``<suite>-<split>.json``."""
    lines = [
        "# Warning evidence on cached harness records (issue 30, item 4)",
        "",
        "Generated by `python -m tests.harness.warning_rules --doc "
        + str(out.name)
        + " RECORDS…` from `python -m tests.harness.warning_study --suite library|physics --split tuning|held_out`; "
        "do not edit by hand. What was chosen and why: `docs/light-families.md` (Warnings) and "
        "`docs/decisions/2026-11-warning-evidence.md`. A miss is a ratio above 1.3 to the truth's LED bound; rules "
        "were frozen on the tuning records of both suites before any held-out record was computed.",
        "",
        "## ROC area of each score (larger = more likely a miss)",
        "",
        "| records | model | misses | " + " | ".join(SHOWN) + " |",
        "|---|---|---|" + "---|" * len(SHOWN),
    ]
    for path in paths:
        records = load([path])
        table = [features(r) for r in records]
        for model in MODELS:
            miss = np.array([truth_miss(r, model) for r in records])
            areas = [roc(np.array([t[model].get(k, math.nan) for t in table], float), miss)[0] for k in SHOWN]
            lines.append(
                f"| {path.stem} | {model} | {miss.sum()} of {miss.size} | "
                + " | ".join("—" if math.isnan(a) else f"{a:.2f}" for a in areas)
                + " |"
            )
    lines += ["", "Scores: " + "; ".join(f"`{k}` — {v}" for k, v in SHOWN.items()) + ".", ""]
    lines += [
        "## The frozen rules (recall and false alarms; per kind: warned misses / misses, warned / non-misses)",
        "",
        "| records | model | rule | recall | false alarms | per kind |",
        "|---|---|---|---|---|---|",
    ]
    for path in paths:
        lines += rule_table(load([path]), path.stem)
    lines += ["", "## ROC charts (shipped, the tried LED check, split half, jackknife; ROC area in brackets)", ""]
    for path in paths:
        chart = out.with_name(f"{out.stem}-{path.stem}.png")
        draw(load([path]), chart, path.stem)
        lines += [f"### {path.stem}", "", f"![{path.stem}]({chart.name})", ""]
    out.write_text("\n".join(lines))


def load(paths: list[Path]) -> list[dict]:
    """Records of every file, failed cases dropped."""
    records = []
    for path in paths:
        records += [r for r in json.loads(path.read_text()) if "error" not in r]
    return records


def main(argv: list[str] | None = None) -> int:
    """Print every score's ROC area and best operating point per model; 0 on success."""
    parser = argparse.ArgumentParser(prog="python -m tests.harness.warning_rules")
    parser.add_argument("records", type=Path, nargs="+")
    parser.add_argument("--model", action="append", choices=MODELS)
    parser.add_argument("--rules", action="store_true", help="the frozen rules' recall and false alarms instead")
    parser.add_argument("--doc", type=Path, help="write the markdown page (and its ROC charts) here instead")
    args = parser.parse_args(argv)
    if args.doc:
        document(args.records, args.doc)
        return 0
    records = load(args.records)
    if args.rules:
        print(
            "| records | model | rule | recall | false alarms | per kind: warned misses / misses, warned / non-misses |"
        )
        print("|---|---|---|---|---|---|")
        for path in args.records:
            print("\n".join(rule_table(load([path]), path.stem)))
        return 0
    table = [features(r) for r in records]
    for model in args.model or MODELS:
        miss = np.array([truth_miss(r, model) for r in records])
        print(f"\n{model}: {len(records)} cases, {miss.sum()} misses")
        keys = list(table[0][model])
        rows = []
        for key in keys:
            score = np.array([t[model].get(key, math.nan) for t in table], float)
            rows.append((key, *roc(score, miss)))
        for key, auc, recall, threshold, alarms in sorted(rows, key=lambda r: -np.nan_to_num(r[1])):
            print(f"  {key:24s} area {auc:.2f}  recall {recall:.0%} at {alarms:.0%} (from {threshold:.3g})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
