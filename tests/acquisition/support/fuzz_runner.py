"""Runs a fuzz worker (``python -m tests.acquisition.<worker> --examples N``) and returns its JSON summary.

The workers cap themselves (memory, time per example) and decide what is a bug; this only runs one with a
hang guard and fails the test with the worker's last output when it found something.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]


def run_fuzz_worker(module: str, examples: int, timeout_s: float) -> dict:
    """The summary (last stdout line, JSON) of ``python -m module --examples examples``; a test failure otherwise."""
    try:
        done = subprocess.run(
            [sys.executable, "-m", module, "--examples", str(examples)],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"{module} did not finish {examples} examples within {timeout_s} s (a hang)")
    assert done.returncode == 0, done.stdout[-6000:] + done.stderr[-3000:]
    return json.loads(done.stdout.splitlines()[-1])
