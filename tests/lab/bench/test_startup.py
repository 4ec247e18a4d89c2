"""Smoke test of the start-up bench: the ratios are there and a failing command is named (no timed assertion)."""

from __future__ import annotations

import math
from pathlib import Path

from msflash.lab.bench.startup import ESTIMATE_TARGET, HELP_TARGET, startup_bench


def test_startup_bench_reports_both_ratios_from_interleaved_runs() -> None:
    report = startup_bench(rounds=2)
    assert "failed" not in report, report.get("failed")
    for key in ("help_over_numpy", "estimate_over_numpy"):
        assert math.isfinite(report[key]) and report[key] > 0, key
    assert report["help_met"] == (report["help_over_numpy"] <= HELP_TARGET)
    assert report["estimate_met"] == (report["estimate_over_numpy"] <= ESTIMATE_TARGET)
    assert {name: len(times) for name, times in report["times_s"].items()} == {"numpy": 2, "help": 2, "estimate": 2}
    assert isinstance(report["bytecode_cached"], bool)


def test_a_failing_command_is_named_with_its_exit_status(tmp_path: Path) -> None:
    report = startup_bench(rounds=1, sequence=tmp_path / "absent")
    assert set(report) == {"failed"}
    assert report["failed"].startswith("msflash estimate SEQ --json: exit 2: msflash: error:")
