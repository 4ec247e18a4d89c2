"""``msflash bench --part many``: its report's shape and sense (no timed assertions).

In a process of its own, as the other local-cluster tests (tests/acquisition/session/test_many_sequences.py).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

from msflash.acquisition.sequence.reader import read_sequence
from msflash.lab.cli_bench import _OPTIONAL_PARTS

_SMALL_BENCH = """
import json
import msflash.lab.bench.many as module
from msflash.acquisition.app.cli import main
module.many_bench.__defaults__ = (3, 48, 64, 2)  # 3 small sequences, 2 rounds keep the test short
raise SystemExit(main(["bench", "--part", "many", "--json"]))
"""


def test_the_bench_sequences_are_sequences(tmp_path: Path) -> None:
    from msflash.lab.bench.many import write_bench_sequences

    folders = write_bench_sequences(tmp_path, 2, 24, 32)
    assert folders == [str(tmp_path / "000"), str(tmp_path / "001")]
    sequence = read_sequence(folders[1])
    assert sequence.complete and len(sequence.indices("led")) == len(sequence.leds) == 7


def test_the_part_reports_the_speedup_of_two_workers_with_identical_records() -> None:
    assert _OPTIONAL_PARTS["many"] == ("msflash.lab.bench.many", "many_bench")
    done = subprocess.run(
        [sys.executable, "-c", _SMALL_BENCH],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=Path(__file__).resolve().parents[3],
    )
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(done.stdout)["many"]
    assert report["identical"] is True
    low, high = report["spread"]
    assert 0 < low <= report["speedup_1_to_2_workers"] <= high and math.isfinite(high)
    assert min(report["seconds_serial"], report["seconds_1_worker"], report["seconds_2_workers"]) > 0
    assert report["two_workers_over_serial"] > 0
    assert "3 sequences of 48x64" in report["what"] and "2 interleaved rounds" in report["what"]
