"""The block-size sweep (``python -m tests.harness.block_size``) on one small case, and its page and chart."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest

from tests.harness import block_size, cases
from tests.harness.block_size_report import write_outputs


@pytest.fixture(scope="module")
def rows() -> list[dict]:
    case = replace(cases.cases_of("tuning")[1], n_surfaces=20)
    original = block_size.BLOCK_SIZES
    block_size.BLOCK_SIZES = (1, 4)
    try:
        return block_size.sweep_case(case)
    finally:
        block_size.BLOCK_SIZES = original


def test_every_family_and_block_size_is_measured(rows: list[dict]) -> None:
    assert [(row["family"], row["block"]) for row in rows] == [
        (family, block) for block in (1, 4) for family in block_size.FAMILIES
    ]
    for row in rows:
        assert not row.get("error"), row
        assert 0 < row["ratio"] < 3 and math.isfinite(row["reference_ratio"])


def test_the_blocks_agree_with_the_reference_and_every_pixel_does_not(rows: list[dict]) -> None:
    single, blocks = (next(r for r in rows if r["family"] == "led" and r["block"] == b) for b in (1, 4))
    # Every pixel without a noise probe is solved on biased moments; 4 × 4 blocks are denoised.
    assert blocks["worst_z_same_alpha"] < 3 < single["worst_z_same_alpha"]
    assert blocks["within_2sigma_same_alpha"] > single["within_2sigma_same_alpha"]


def test_the_page_keeps_its_text_and_gets_the_tables_and_chart(rows: list[dict], tmp_path: Path) -> None:
    page, chart, table = tmp_path / "page.md", tmp_path / "chart.png", tmp_path / "rows.csv"
    page.write_text("# Block size\n\nHand-written findings.\n\n<!-- generated -->\nold tables\n")
    bench = [
        {**{k: v for k, v in row.items() if k not in ("case", "split", "mosaic", "family")}, "seed": 0}
        | {"rmse": 0.2, "correction": "denoised" if row["block"] > 1 else "none"}
        for row in rows
        if row["family"] == "led"
    ]
    times = [{"family": f, "block": b, "ratio": 2.0 + b} for f in (*block_size.FAMILIES, "reference") for b in (1, 4)]
    write_outputs(page, chart, {"rows": rows, "bench": bench, "times": times, "seconds": 60.0, "rounds": 15}, table)
    text = page.read_text()
    assert text.startswith("# Block size\n\nHand-written findings.") and "old tables" not in text
    assert "| 4 | tuning | 1 |" in text and "![accuracy against time](chart.png)" in text
    assert chart.read_bytes()[:4] == b"\x89PNG"
    assert len(table.read_text().splitlines()) == len(rows) + 1
