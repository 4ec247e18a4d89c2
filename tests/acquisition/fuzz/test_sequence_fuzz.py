"""Fuzzing at the boundary (issue 19 item 6): structured-but-wrong sequences through ``estimate``,
``flash``, ``synthesize`` and ``check``, run in one worker process capped in memory and time
(:mod:`tests.acquisition.fuzz.sequence_fuzz_worker`; the mutations and the rule deciding which exit is
right: :mod:`tests.acquisition.fuzz.sequence_mutations`). CI runs 200 derandomised examples; the
``study`` marker runs 2000. Results: docs/reliability.md."""

from __future__ import annotations

import json

import pytest

from tests.acquisition.support.fuzz_runner import run_fuzz_worker


def _fuzz(examples: int, timeout_s: float) -> dict:
    summary = run_fuzz_worker("tests.acquisition.fuzz.sequence_fuzz_worker", examples, timeout_s)
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
