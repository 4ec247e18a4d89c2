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

from msflash.processing.family_checks import MISS_RATIO, led_bound, paper_rmse

MODELS = ("led", "prior", "family", "auto")

RULES: dict[str, dict[str, tuple[tuple[str, float], ...]]] = {
    "led": {
        "shipped (1.13)": (("shipped", 1.13),),
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
    shipped["auto"] = shipped["led"] / 1.13 if auto_is_led else shipped["family"] / 1.05

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

    out: dict[str, dict[str, float]] = {}
    for name in MODELS:
        own = bounds[name]
        row = {
            "shipped": shipped[name],
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
    best = (0.0, math.inf, 0.0)
    for threshold in np.unique(score):
        warned = score >= threshold
        alarms = (warned & ~miss).sum() / negatives.size
        recall = (warned & miss).sum() / positives.size
        if alarms <= 0.2 and recall > best[0]:
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
    args = parser.parse_args(argv)
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
