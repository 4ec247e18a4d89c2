"""Fuzzing every file msflash reads besides a sequence folder (issue 32 item 5): spectral tables, spectrometer
exports, calibration folders, a reference chart, camera profiles, each through its command in one worker
process capped in memory and time (:mod:`tests.acquisition.fuzz.user_file_fuzz_worker`; the mutations and the
rule deciding which exit is right: :mod:`tests.acquisition.fuzz.user_file_mutations`). CI runs a small
derandomised count plus every kind of special file (FIFO, ``/dev/zero``, loop, …) on every file of every
surface; the ``study`` marker runs 2000. Results: docs/reliability.md §6."""

from __future__ import annotations

import json

import pytest

from tests.acquisition.fuzz.user_file_mutations import SPECIALS
from tests.acquisition.support.fuzz_runner import run_fuzz_worker


def _fuzz(examples: int, timeout_s: float) -> dict:
    summary = run_fuzz_worker("tests.acquisition.fuzz.user_file_fuzz_worker", examples, timeout_s)
    outcomes = summary["outcomes"]
    explicit = outcomes.pop("explicit examples")
    assert sum(outcomes.values()) == examples + explicit
    # Each file of each surface was replaced by each of the 7 special files: 6 refused, 1 (a link to a copy)
    # read as the original (else the worker failed).
    files = explicit // len(SPECIALS)
    assert sum(count for key, count in outcomes.items() if " refuse exit 2" in key) >= 6 * files
    assert sum(count for key, count in outcomes.items() if " same exit 0" in key) >= files
    return summary


@pytest.mark.timeout(600)
def test_wrong_user_files_are_refused_in_one_line_never_crash() -> None:
    _fuzz(60, 540)


@pytest.mark.study
@pytest.mark.timeout(3600)
def test_wrong_user_files_study() -> None:
    print(json.dumps(_fuzz(2000, 3500)))
