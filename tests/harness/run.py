"""Run variants on cases: render each case once, estimate with every variant, measure.

Cases run in worker processes (``jobs``); each renders into its own temporary directory and
deletes it afterwards, so a full run leaves nothing but the report.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tests.harness import metrics
from tests.harness.render import HarnessCase, render
from tests.harness.variants import Variant


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


def run_case(case: HarnessCase, variants: list[Variant], root: Path | None = None) -> CaseResult:
    """Render ``case`` (under ``root``, or a temporary directory removed afterwards) and measure every variant."""
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
