"""``msflash bench --part decode``: its report's shape and sense (no timed assertions)."""

from __future__ import annotations

import json

import pytest

from msflash.acquisition.app.cli import main
from msflash.lab.bench.decode import FORMATS, decode_bench


def test_decode_bench_reports_each_format_against_the_mono16_copy() -> None:
    report = decode_bench(width=64, height=8, rounds=3)
    assert report["frame"] == "64x8" and report["rounds"] == 3 and report["mono16_copy_ms"] > 0
    for name in FORMATS:
        assert report[name]["ms"] > 0
        assert report[name]["ratio_to_mono16_copy"] == pytest.approx(report[name]["ms"] / report["mono16_copy_ms"])


def test_the_part_is_offered_by_msflash_bench(capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    import msflash.lab.bench.decode as module

    monkeypatch.setattr(module.decode_bench, "__defaults__", (64, 8, 2, 0))  # a small frame keeps the test short
    assert main(["bench", "--part", "decode", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)["decode"]
    assert report["frame"] == "64x8" and report["rounds"] == 2 and set(FORMATS) <= set(report)
