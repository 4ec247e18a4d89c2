"""Run variants on cases: render each case once, estimate with every variant, measure.

Cases run in worker processes (``jobs``); each renders into its own temporary directory and
deletes it afterwards, so a full run leaves nothing but the report — unless a cache directory is given
(``--cache``, :data:`CACHE_ENV`): rendered cases are then kept there, keyed by the case's fields and
:data:`RENDER_VERSION`, and read back on the next run (rendering is deterministic).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
import zlib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tests.harness import metrics
from tests.harness.render import HarnessCase, Truth, render
from tests.harness.variants import Variant

CACHE_ENV = "MSFLASH_HARNESS_CACHE"
"""Environment variable naming the rendered-case cache directory (set by ``--cache``; unset: no cache)."""
RENDER_VERSION = 3
"""Bumped whenever the renderer's output changes, so a cache never serves an old rendering."""


@dataclass(frozen=True)
class Measured:
    """One variant on one case."""

    variant: str
    rmse: float = math.nan
    ratio: float = math.nan
    """RMSE ÷ LED bound (NaN when the variant failed)."""
    coverage_1: float | None = None
    """Share of wavelengths with the truth within ±1σ (None: no band)."""
    coverage_2: float | None = None
    warnings: tuple[str, ...] | None = None
    """None: the variant cannot warn."""
    error: str = ""
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class CaseResult:
    """Every variant on one case."""

    case: HarnessCase
    bound: float
    measured: tuple[Measured, ...]

    def of(self, variant: str) -> Measured | None:
        """The measurement of one variant (None if it did not run)."""
        return next((m for m in self.measured if m.variant == variant), None)


def measure(variant: Variant, directory: Path, truth: np.ndarray, bound: float) -> Measured:
    """Estimate with ``variant`` and measure against ``truth``."""
    estimate = variant.estimate(directory)
    if estimate.spectrum is None:
        return Measured(variant.name, error=estimate.error, notes=estimate.notes)
    if (
        estimate.spectrum.shape != truth.shape
        or not np.all(np.isfinite(estimate.spectrum))
        or not np.any(estimate.spectrum)
    ):
        return Measured(
            variant.name, error=f"unusable spectrum (shape {estimate.spectrum.shape})", notes=estimate.notes
        )
    error = metrics.rmse(estimate.spectrum, truth)
    coverage = (None, None)
    if estimate.std is not None and estimate.std.shape == truth.shape:
        coverage = metrics.band_coverage(estimate.spectrum, estimate.std, truth)
    return Measured(
        variant.name,
        error,
        error / bound if bound > 0 else math.inf,
        coverage[0],
        coverage[1],
        estimate.warnings,
        notes=estimate.notes,
    )


def cached_render(case: HarnessCase, cache: Path) -> Truth:
    """``render(case)`` kept under ``cache`` (rendered once; the truth beside the sequence in ``truth.json``)."""
    key = f"{case.name}-{zlib.crc32(repr((RENDER_VERSION, case)).encode()):08x}"
    directory = cache / key
    stored = directory / "truth.json"
    if stored.is_file():
        data = json.loads(stored.read_text())
        return Truth(directory, np.array(data["wavelengths_nm"]), np.array(data["ambient"]), np.array(data["led_spd"]))
    partial = cache / f".{key}.{os.getpid()}"
    shutil.rmtree(partial, ignore_errors=True)
    truth = render(case, partial)
    (partial / "truth.json").write_text(
        json.dumps(
            {
                "wavelengths_nm": truth.wavelengths_nm.tolist(),
                "ambient": truth.ambient.tolist(),
                "led_spd": truth.led_spd.tolist(),
            }
        )
    )
    try:
        partial.rename(directory)
    except OSError:  # another worker rendered it first: the same bytes
        shutil.rmtree(partial, ignore_errors=True)
    return Truth(directory, truth.wavelengths_nm, truth.ambient, truth.led_spd)


def run_case(case: HarnessCase, variants: list[Variant], root: Path | None = None) -> CaseResult:
    """Render ``case`` (under ``root``, from the cache named by :data:`CACHE_ENV`, or in a temporary directory
    removed afterwards) and measure every variant."""
    cache = os.environ.get(CACHE_ENV)
    if root is None and cache:
        Path(cache).mkdir(parents=True, exist_ok=True)
        truth = cached_render(case, Path(cache))
        bound = metrics.led_bound(truth.led_spd, truth.ambient)
        return CaseResult(case, bound, tuple(measure(v, truth.directory, truth.ambient, bound) for v in variants))
    scratch = Path(tempfile.mkdtemp(prefix="harness-")) if root is None else root
    try:
        truth = render(case, scratch / case.name)
        bound = metrics.led_bound(truth.led_spd, truth.ambient)
        measured = tuple(measure(v, truth.directory, truth.ambient, bound) for v in variants)
        return CaseResult(case, bound, measured)
    finally:
        if root is None:
            shutil.rmtree(scratch, ignore_errors=True)


def _run_one(arguments: tuple[HarnessCase, list[Variant]]) -> CaseResult:
    return run_case(*arguments)


def run_cases(
    cases: list[HarnessCase], variants: list[Variant], jobs: int = 1, progress: bool = False
) -> list[CaseResult]:
    """Every case with every variant, in case order (``jobs`` worker processes)."""
    work = [(case, variants) for case in cases]
    results: list[CaseResult] = []
    if jobs <= 1:
        iterator = map(_run_one, work)
        executor = None
    else:
        executor = ProcessPoolExecutor(jobs)
        iterator = executor.map(_run_one, work, chunksize=1)
    try:
        for index, result in enumerate(iterator, 1):
            results.append(result)
            if progress and index % 10 == 0:
                print(f"  {index}/{len(cases)} cases", flush=True)
    finally:
        if executor is not None:
            executor.shutdown()
    return results


def case_record(result: CaseResult) -> dict:
    """A case's conditions and its LED bound, flat (for the per-case CSV)."""
    record = {key: value for key, value in asdict(result.case).items() if key not in ("surface_sets", "ratio", "seed")}
    record = {key: f"{value:.4g}" if isinstance(value, float) else value for key, value in record.items()}
    record["ambient_flash_ratio"] = f"{result.case.ratio:.3g}"
    record["grid"] = result.case.grid_label
    record["mosaic"] = result.case.mosaic
    record["led_count"] = result.case.led_count
    return record
