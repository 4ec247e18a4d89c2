"""Fuzzing at the boundary (issue 19 item 6): structured-but-wrong sequences through ``estimate``,
``flash``, ``synthesize`` and ``check``, run in one worker process capped in memory and time
(:mod:`tests.acquisition.sequence_fuzz_worker`; the mutations and the rule deciding which exit is
right: :mod:`tests.acquisition.sequence_mutations`). CI runs 200 derandomised examples; the
``study`` marker runs 2000. Results: docs/reliability.md."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _fuzz(examples: int, timeout_s: float) -> dict:
    try:
        done = subprocess.run(
            [sys.executable, "-m", "tests.acquisition.sequence_fuzz_worker", "--examples", str(examples)],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"the fuzz worker did not finish {examples} examples within {timeout_s} s (a hang)")
    assert done.returncode == 0, done.stdout[-6000:] + done.stderr[-6000:]
    summary = json.loads(done.stdout.splitlines()[-1])
    outcomes = summary["outcomes"]
    # Every example (drawn, plus each kind of frame change) ran check and one other command; every
    # corrupt one was refused (else the worker failed).
    explicit = outcomes.pop("explicit examples")
    assert sum(outcomes.values()) == 2 * (examples + explicit)
    assert outcomes.get("refuse check exit 2", 0) > examples // 2
    return summary


@pytest.mark.timeout(400)
def test_structured_but_wrong_sequences_are_refused_never_crash() -> None:
    _fuzz(200, 360)


@pytest.mark.study
@pytest.mark.timeout(3600)
def test_structured_but_wrong_sequences_study() -> None:
    print(json.dumps(_fuzz(2000, 3500)))
