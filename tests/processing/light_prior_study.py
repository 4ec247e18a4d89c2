"""Evaluation of the light prior (issue 17, build 3): RMSE ÷ LED bound of the prior model, of the default
``msflash estimate`` and of ``auto``, on sequences rendered by the independent generator
(:mod:`tests.processing.unseen_sequences`) under library lights.

Surfaces are *not* the reflectance basis's (Natural-100): Macbeth 24, Vrhel's 64 Munsell samples and
12 of Vrhel's objects, plus the generator's 10-step grey strip. Lights:

- ``--split tuning``: lights of the tuning split, in 3 folds by near-copy group; the prior for a fold's
  lights learns without that fold (and near copies of it) — cross-validation *inside* the tuning
  split, where dimensions and regularisation were chosen.
- ``--split held_out``: the held-out lights (run once, after tuning); the prior is the shipped one
  (:func:`processing.light_library.prior_training_lights` + CIE daylight/blackbodies, no near copy of
  a held-out light).
- ``--split family``: a stress test on tuning lights: for each family (LED, fluorescent, incandescent,
  discharge) the prior learns without *any* light of that family (nor a near copy).

Run: ``PYTHONPATH=$PWD .venv/bin/python tests/processing/light_prior_study.py --split tuning``.
The default estimate is :func:`acquisition.session.analysis.estimate_sequence` (what ``msflash estimate`` runs).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import zlib
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from msflash.acquisition.sequence.reader import read_sequence  # noqa: E402
from msflash.acquisition.session.analysis import estimate_sequence  # noqa: E402
from msflash.acquisition.session.prior_route import sequence_channel_statistics  # noqa: E402
from msflash.acquisition.session.sequence_spectra import camera_responsivities_photons, led_spectra_photons  # noqa: E402
from msflash.processing import datasets  # noqa: E402
from msflash.processing.channel_statistics import ChannelStatistics  # noqa: E402
from msflash.processing.light_library import library_lights, light_library  # noqa: E402
from msflash.processing.light_prior import (  # noqa: E402
    CHOICE_MARGIN,
    PriorModel,
    learn_light_prior,
    learn_reflectance_basis,
)
from msflash.processing.prior_choice import choose_model  # noqa: E402
from msflash.processing.spectra import Spectra, WavelengthGrid  # noqa: E402
from tests.processing import unseen_sequences as us  # noqa: E402

CAMERAS = ("Canon 5DMarkII", "Nikon D40", "isetcam:AptinaMT9M031", "Nokia N900", "Point Grey Grasshopper 50S5C")
LED_SETS = ("paper7", "paper:0,3,6", "paper:0,2,3,6", "paper:0,2,3,4,6")
TUNING_FOLDS = 3


def study_surfaces(wavelengths: np.ndarray) -> np.ndarray:
    """Macbeth 24 + Munsell 64 + 12 Vrhel objects (none in Natural-100) + the generator's 10 greys: (n, 110)."""
    grid = WavelengthGrid.from_wavelengths(wavelengths)
    parts = [
        datasets.macbeth().resample(WavelengthGrid(400, 700, 4)),
        datasets.vrhel("munsell"),
        datasets.vrhel("objects").select(list(range(0, 168, 14))),
    ]
    values = np.hstack([p.resample(WavelengthGrid(400, 700, 10)).resample(grid, outside="edge").values for p in parts])
    greys = np.logspace(0, np.log10(0.05), 10)
    return np.clip(np.hstack([values, np.tile(greys, (grid.size, 1))]), 0.0, 1.0)


@contextmanager
def rendering_with(light: np.ndarray, light_nm: np.ndarray):
    """The generator with its ``light_energy("lib")`` a library light and its surfaces :func:`study_surfaces`."""
    saved = us.light_energy, us.reflectances

    def light_energy(name: str, wavelengths: np.ndarray) -> np.ndarray:
        if name == "lib":
            return np.interp(wavelengths, light_nm, light, left=0.0, right=0.0)
        return saved[0](name, wavelengths)

    us.light_energy, us.reflectances = light_energy, study_surfaces
    try:
        yield
    finally:
        us.light_energy, us.reflectances = saved


@dataclass
class Sample:
    """One rendered case reduced to what the evaluation needs."""

    label: str
    light_type: str
    camera: str
    cfa: str | None
    leds: str
    fold: int
    statistics: ChannelStatistics
    led_spectra: Spectra
    responsivities: Spectra
    truth: np.ndarray
    bound: float
    default_rmse: float


FAMILIES = ("led", "fluorescent", "incandescent", "discharge")


def light_cases(split: str, per_fold: int, seed: int = 0) -> list[tuple[str, str, int]]:
    """(label, type, fold) of the lights evaluated: a fixed sample of the split (fold by near-copy group, or by
    family for ``family``: tuning lights, fold = index in :data:`FAMILIES`)."""
    lights = [light for light in library_lights() if light.split == ("held_out" if split == "held_out" else "tuning")]
    rng = np.random.default_rng(seed)
    chosen = []
    folds = {"tuning": TUNING_FOLDS, "family": len(FAMILIES)}.get(split, 1)
    for fold in range(folds):
        if split == "family":
            members = [light for light in lights if light.light_type == FAMILIES[fold]]
        else:
            members = [light for light in lights if folds == 1 or zlib.crc32(str(light.group).encode()) % folds == fold]
        picks = rng.choice(len(members), size=min(per_fold, len(members)), replace=False)
        chosen += [(members[i].label, members[i].light_type, fold) for i in sorted(picks)]
    return chosen


def render_samples(split: str, per_fold: int, root: Path) -> list[Sample]:
    """Render every (light, camera, CFA, LED set) case of the study and reduce it to a :class:`Sample`."""
    library = light_library()
    samples = []
    for n, (label, kind, fold) in enumerate(light_cases(split, per_fold)):
        spd = library.column(label)
        for m, (camera, cfa, leds) in enumerate(_configurations(n)):
            case = us.Case(f"c{n}-{m}", camera=camera, cfa=cfa, leds=leds, light="lib", patch_px=16, seed=n * 7 + m)
            with rendering_with(spd, library.wavelengths_nm):
                rendered = us.render_case(case, root / case.name)
            sequence = read_sequence(rendered.directory)
            default = estimate_sequence(sequence)
            statistics = sequence_channel_statistics(sequence)
            samples.append(
                Sample(
                    label,
                    kind,
                    camera,
                    cfa,
                    leds,
                    fold,
                    statistics,
                    led_spectra_photons(sequence),
                    camera_responsivities_photons(sequence),
                    rendered.truth,
                    us.led_bound(rendered),
                    us.rmse(default.spectrum.values[:, 0], rendered.truth),
                )
            )
    return samples


def _configurations(n: int) -> list[tuple[str, str | None, str]]:
    """Four (camera, CFA, LED set) per light, rotating through cameras and LED sets; RGB and Bayer each twice."""
    return [
        (CAMERAS[(n + j) % len(CAMERAS)], None if j % 2 == 0 else "RGGB", LED_SETS[(n + j) % len(LED_SETS)])
        for j in range(4)
    ]


def evaluate(
    samples: list[Sample],
    *,
    light_dims: int,
    reflectance_dims: int,
    ridge: float,
    kappa: float,
    split_span: bool = True,
    exclude_folds: bool = True,
    margin: float = CHOICE_MARGIN,
    with_auto: bool = True,
    exclusions: dict[int, tuple[str, ...]] | None = None,
) -> dict[str, np.ndarray]:
    """Ratios (RMSE ÷ LED bound) of the prior model, the default estimate and auto, per sample; the band's coverage.

    ``exclude_folds``: the prior for a fold's samples learns without their lights (and near copies);
    ``exclusions`` (fold → labels) replaces that list.
    """
    prior_ratio, default_ratio, auto_ratio, chose_prior, coverage = [], [], [], [], []
    grid = samples[0].led_spectra.grid
    if exclusions is None:
        exclusions = {}
        for sample in samples if exclude_folds else ():
            exclusions.setdefault(sample.fold, ())
            if sample.label not in exclusions[sample.fold]:
                exclusions[sample.fold] += (sample.label,)
    models: dict[tuple, PriorModel] = {}
    for sample in samples:
        key = (sample.fold, sample.camera, sample.cfa, sample.leds)
        if key not in models:
            prior = learn_light_prior(grid, light_dims, exclusions.get(sample.fold, ()))
            models[key] = PriorModel(
                sample.led_spectra,
                sample.responsivities,
                sample.statistics.channels,
                prior,
                learn_reflectance_basis(grid, reflectance_dims),
                ridge,
                kappa,
                split_span,
            )
        model = models[key]
        estimate = model.estimate(sample.statistics)
        spectrum = estimate.spectrum.values[:, 0]
        prior_rmse = us.rmse(spectrum, sample.truth)
        prior_ratio.append(prior_rmse / sample.bound)
        # Band coverage in the RMSE's frame: estimate max-normalised, truth least-squares scaled onto it.
        peak = np.max(np.abs(spectrum))
        truth = sample.truth * (sample.truth @ spectrum) / (sample.truth @ sample.truth)
        z = np.abs(spectrum - truth) / np.maximum(estimate.spectrum_std, 1e-12 * peak)
        coverage.append([np.mean(z <= 1), np.mean(z <= 2), np.median(estimate.spectrum_std) / peak])
        default_ratio.append(sample.default_rmse / sample.bound)
        if with_auto:
            choice = choose_model(sample.statistics, model, margin)
            chose_prior.append(choice.model == "prior")
            auto_ratio.append(prior_ratio[-1] if choice.model == "prior" else default_ratio[-1])
    return {
        "prior": np.array(prior_ratio),
        "default": np.array(default_ratio),
        "auto": np.array(auto_ratio),
        "chose_prior": np.array(chose_prior),
        "coverage": np.array(coverage),
    }


def summary(name: str, ratios: np.ndarray) -> str:
    return (
        f"{name:8s} mean {ratios.mean():.3f}  median {np.median(ratios):.3f}  worst {ratios.max():.3f}  "
        f"above 1: {np.mean(ratios > 1):.0%}"
    )


def report(samples: list[Sample], results: dict[str, np.ndarray]) -> None:
    print(f"{len(samples)} cases, {len({s.label for s in samples})} lights")
    for name in ("prior", "default", "auto"):
        if results[name].size:
            print(summary(name, results[name]))
    if results["chose_prior"].size:
        chose = results["chose_prior"]
        better = results["prior"] < results["default"]
        print(
            f"auto chose the prior in {chose.mean():.0%} of the cases; its choice had the lower RMSE in "
            f"{np.mean(chose == better):.0%}"
        )
    one, two, width = results["coverage"].mean(axis=0)
    print(
        f"band: truth within 1σ at {one:.0%} and within 2σ at {two:.0%} of wavelengths; median 1σ {width:.3f} of the peak"
    )
    for attribute, _values in (("light_type", None), ("cfa", None), ("leds", None), ("camera", None)):
        groups = sorted({str(getattr(s, attribute)) for s in samples})
        for group in groups:
            index = np.array([str(getattr(s, attribute)) == group for s in samples])
            line = (
                f"  {attribute}={group:32s} n={index.sum():3d}  prior {results['prior'][index].mean():.3f}/"
                f"{results['prior'][index].max():.3f}  default {results['default'][index].mean():.3f}/"
                f"{results['default'][index].max():.3f}"
            )
            if results["auto"].size:
                line += f"  auto {results['auto'][index].mean():.3f}/{results['auto'][index].max():.3f}"
            print(line)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--split",
        choices=("tuning", "held_out", "family"),
        default="tuning",
        help="family: tuning lights of one family, the prior learnt without any light of it",
    )
    parser.add_argument("--per-fold", type=int, default=12, help="lights per fold (tuning) or in all (held_out)")
    parser.add_argument("--sweep", action="store_true", help="tuning: sweep dimensions and regularisation")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as root:
        samples = render_samples(args.split, args.per_fold, Path(root))
    from msflash.processing import light_prior as lp

    defaults = dict(light_dims=lp.LIGHT_DIMS, reflectance_dims=lp.REFLECTANCE_DIMS, ridge=lp.RIDGE, kappa=lp.KAPPA)
    if args.sweep:
        for light_dims in (8, 12, 16, 24):
            for reflectance_dims in (6, 8, 10, 12):
                for ridge in (1e-4, 1e-3, 1e-2):
                    for kappa in (10.0, 100.0, 1000.0):
                        ratios = evaluate(
                            samples,
                            light_dims=light_dims,
                            reflectance_dims=reflectance_dims,
                            ridge=ridge,
                            kappa=kappa,
                            with_auto=False,
                        )["prior"]
                        print(
                            f"q={light_dims:2d} p={reflectance_dims:2d} ridge={ridge:g} kappa={kappa:g}: "
                            f"{summary('prior', ratios)}",
                            flush=True,
                        )
        return
    exclusions = None
    if args.split == "family":
        exclusions = {
            fold: tuple(
                light.label for light in library_lights() if light.split == "tuning" and light.light_type == family
            )
            for fold, family in enumerate(FAMILIES)
        }
    results = evaluate(samples, exclude_folds=args.split == "tuning", exclusions=exclusions, **defaults)
    report(samples, results)


if __name__ == "__main__":
    main()
