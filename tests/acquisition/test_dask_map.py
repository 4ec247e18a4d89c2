"""``acquisition/session/dask_map.py``: one function over many items, in order, on dask or serially."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from msflash.acquisition.errors import UsageError
from msflash.acquisition.session.dask_map import dask_mapper


def _tenfold(item: int) -> int:
    if item == 1:
        raise ArithmeticError(f"item {item}")
    return 10 * item


def test_serially_an_error_is_raised_or_given_to_on_error_and_the_rest_go_on() -> None:
    with dask_mapper("none") as mapper:
        with pytest.raises(ArithmeticError, match="item 1"):
            list(mapper(_tenfold, [0, 1, 2]))
        assert list(mapper(_tenfold, [0, 1, 2], on_error=lambda item, err: f"{item}: {err}")) == [0, "1: item 1", 20]


def test_something_that_is_not_an_address_is_refused() -> None:
    pytest.importorskip("distributed")
    with pytest.raises(UsageError, match=r"--scheduler no-such: cannot connect \(.*\); expected 'local', 'none'"):
        with dask_mapper("no-such"):
            pass


_DYING_WORKER = """
import json
import os
import dask
from msflash.acquisition.session.dask_map import dask_mapper

def job(item):
    if item == 1:
        os._exit(3)  # the worker process dies
    return 10 * item

# No retry on a fresh worker, and one task at a time on the worker (so only item 1 dies with it).
dask.config.set({"distributed.scheduler.allowed-failures": 0, "distributed.scheduler.worker-saturation": 1.0})
with dask_mapper("local", 1) as mapper:
    print(json.dumps(list(mapper(job, [0, 1, 2], on_error=lambda item, err: [item, type(err).__name__]))))
"""


def test_a_job_whose_worker_dies_is_given_to_on_error_and_the_rest_go_on() -> None:
    """In a process of its own (distributed's event loops are per process; tests/processing/test_study.py)."""
    pytest.importorskip("distributed")
    done = subprocess.run(
        [sys.executable, "-c", _DYING_WORKER],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=Path(__file__).resolve().parents[2],
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(done.stdout) == [0, [1, "KilledWorker"], 20]
