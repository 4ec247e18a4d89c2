"""Fuzzing the live server (issue 32 item 5): a real ``msflash live`` process, capped in memory, sent hostile HTTP
requests, bytes that are not HTTP, WebSocket sessions the page never opens and calls out of order
(:mod:`tests.acquisition.app.live_fuzz_worker`, which states the rule). CI runs 200 derandomised examples; the
``study`` marker runs 2000. Results: docs/reliability.md."""

from __future__ import annotations

import json

import pytest

from tests.acquisition.support.fuzz_runner import run_fuzz_worker


def _fuzz(examples: int, timeout_s: float) -> dict:
    summary = run_fuzz_worker("tests.acquisition.app.live_fuzz_worker", examples, timeout_s)
    outcomes = summary["outcomes"]
    # The API was reached (valid calls answered 200) and refused (400, 403) and the WebSocket opened.
    assert outcomes.get("http 200", 0) > examples // 10
    assert outcomes.get("http 400", 0) > examples // 10 and outcomes.get("http 403", 0) > 0
    assert outcomes.get("ws 101", 0) > 0 and outcomes.get("order 409", 0) == 4
    return summary


@pytest.mark.timeout(600)
def test_hostile_traffic_never_crashes_hangs_or_fails_the_live_server() -> None:
    _fuzz(200, 540)


@pytest.mark.study
@pytest.mark.timeout(3600)
def test_hostile_traffic_study() -> None:
    print(json.dumps(_fuzz(2000, 3500)))
