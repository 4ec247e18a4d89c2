"""The harness end to end on a few small cases, through the real ``msflash estimate`` route."""

from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path

import pytest

from tests.harness import ambient, cases, variants
from tests.harness.run import run_case, run_cases

SMALL = [
    replace(case, n_surfaces=20)
    for case in (cases.cases_of("tuning")[1], cases.cases_of("held_out")[2], cases.cases_of("held_out")[7])
]


def test_every_variant_measures_every_case(tmp_path: Path) -> None:
    chosen = variants.select(None)
    assert {"default", "msflash-lstsq", "authors", "lstsq-pixels"} <= {v.name for v in chosen}
    results = run_cases(SMALL, chosen, jobs=1)
    assert [r.case for r in results] == SMALL
    for result in results:
        assert result.bound > 0
        for measured in result.measured:
            assert not measured.error, measured
            assert 0 < measured.rmse < 1 and math.isfinite(measured.ratio)
        default, authors = result.of("default"), result.of("authors")
        assert default.warnings is not None and authors.warnings is None  # only msflash can warn
        assert 0 <= default.coverage_1 <= default.coverage_2 <= 1 and authors.coverage_1 is None


def test_a_variant_defined_on_the_command_line_reaches_msflash(tmp_path: Path) -> None:
    """``NAME=ARGS`` becomes ``msflash estimate SEQ --json ARGS``: a valid option gives an estimate,
    an invalid one the command's own refusal."""
    good = variants.parse_variant("nonneg=--solver nonneg")
    bad = variants.parse_variant("bogus=--solver no-such-solver")
    result = run_case(SMALL[0], [good, bad, variants.VARIANTS["msflash-lstsq"]], tmp_path)
    assert math.isfinite(result.of("nonneg").ratio)
    assert result.of("bogus").error.startswith("status 2") and "no-such-solver" in result.of("bogus").error
    with pytest.raises(ValueError, match="unknown variant"):
        variants.parse_variant("no-such-variant")


def test_the_command_writes_the_report_and_the_per_case_csv(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "docs" / "harness.md"
    assert (
        ambient.main(
            ["--out", str(out), "--quick", "--split", "held_out", "--variant", "default", "--variant", "authors"]
        )
        == 0
    )
    text = out.read_text()
    count = len(cases.select_cases("held_out", quick=True))
    assert f"| held_out | default | {count} | 0 |" in text and f"| held_out | authors | {count} | 0 |" in text
    for heading in (
        "## Summary",
        "## Warning confusion",
        "## Per family: RGB / Bayer",
        "## Per family: LED count",
        "## Per family: light type",
        "## Per family: wavelength grid",
        "## Worst cases of `default`",
    ):
        assert heading in text
    assert "| tuning |" not in text and "msflash-lstsq" not in text
    with out.with_suffix(".csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == count
    assert all(float(row["default:ratio"]) > 0 and float(row["authors:ratio"]) > 0 for row in rows)
    assert all(row["default:warnings"].isdigit() and row["authors:warnings"] == "" for row in rows)
    assert all(0 <= float(row["default:coverage_1"]) <= 1 and row["authors:coverage_1"] == "" for row in rows)
    assert ambient.main(["--out", str(out), "--variant", "nope"]) == 2
    assert "unknown variant 'nope'" in capsys.readouterr().err
