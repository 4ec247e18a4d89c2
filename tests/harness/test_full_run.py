"""The whole harness (both splits, every registered variant): a study, excluded from CI.

Run with ``python -m pytest -m study tests/harness/test_full_run.py``; the report it checks is the
one ``python -m tests.harness.ambient --out docs/ambient-harness.md --jobs 2`` writes.
"""

from __future__ import annotations

import math

import pytest

from tests.harness import cases, splits
from tests.harness.run import run_cases
from tests.harness.variants import select


@pytest.mark.study
def test_full_harness_runs_every_case_with_every_variant() -> None:
    chosen = select(None)
    results = run_cases(cases.select_cases("both"), chosen, jobs=2)
    assert len(results) == 2 * cases.CASES_PER_SPLIT
    assert {r.case.split for r in results} == set(splits.SPLITS)
    failed = [(r.case.name, m.variant, m.error) for r in results for m in r.measured if m.error]
    assert failed == []
    for result in results:
        assert result.bound > 0
        for measured in result.measured:
            assert math.isfinite(measured.ratio) and measured.ratio > 0
            if measured.coverage_1 is not None:
                assert 0 <= measured.coverage_1 <= measured.coverage_2 <= 1
