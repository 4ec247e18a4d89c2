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
    """In a process of its own (distributed's event loops are per process; tests/lab/study/test_study.py)."""
    pytest.importorskip("distributed")
    done = subprocess.run(
        [sys.executable, "-c", _DYING_WORKER],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=Path(__file__).resolve().parents[3],
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(done.stdout) == [0, [1, "KilledWorker"], 20]


def test_more_local_workers_than_the_cpus_can_serve_are_refused_before_any_starts() -> None:
    # Was: LocalCluster(n_workers=100000) started, one process each, on a 2-CPU machine.
    import os

    from msflash.acquisition.session.dask_map import MAX_WORKERS_PER_CPU

    pytest.importorskip("distributed")
    limit = MAX_WORKERS_PER_CPU * (os.cpu_count() or 1)
    with pytest.raises(UsageError, match=rf"--workers {limit + 1}: .* expected at most {limit}"):
        with dask_mapper("local", limit + 1):
            pass


@pytest.mark.parametrize("blank", ["", " "])
def test_a_blank_scheduler_is_refused_not_taken_for_local(tmp_path: Path, capsys, blank: str) -> None:
    from msflash.acquisition.app.cli import main

    assert main(["estimate", str(tmp_path / "a"), str(tmp_path / "b"), "--scheduler", blank]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert (
        line
        == f"msflash: error: argument --scheduler: {blank!r}: expected 'local', 'none' or a dask scheduler address (tcp://HOST:PORT)"
    )


@pytest.mark.parametrize("stop", ["SIGINT", "SIGTERM"])
def test_a_signal_while_the_local_cluster_starts_is_delivered_once_it_can_be_closed(
    stop: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The worker is held at its start (tests/acquisition/support/held_dask_worker.py) until the signal has landed:
    ``LocalCluster(...)`` cannot return before. (A thread that signalled once the cluster object existed raced the
    cluster's start on a loaded machine: signalled late, the signal fell outside ``pytest.raises``.)"""
    # Was: the signal unwound out of LocalCluster(...) half-started; nothing could close it, and
    # dask's exit hook failed to ("AssertionError: Status.init", a traceback under msflash's line).
    import os
    import signal
    import threading
    import time

    pytest.importorskip("distributed")
    import dask
    from distributed.deploy.spec import SpecCluster

    from msflash.acquisition.signals import Terminated, sigterm_as_exit
    from tests.acquisition.support.held_dask_worker import GATE_VARIABLE, signal_pending, workers_held

    number = getattr(signal, stop)
    known = set(SpecCluster._instances)
    gate = tmp_path / "gate" / "worker"
    gate.parent.mkdir()
    failures: list[str] = []

    def signal_once_the_worker_waits(held) -> None:
        try:
            deadline = time.monotonic() + 120  # a hang guard, not a timing
            while not held.waiting():  # the worker waits at the gate: LocalCluster(...) cannot return
                if time.monotonic() > deadline:
                    failures.append("no dask worker reached the gate")
                    return
                time.sleep(0.01)
            os.kill(os.getpid(), number)
            while signal_pending(os.getpid(), number):  # delivered, before the worker may go on
                time.sleep(0.01)
        finally:
            held.release()

    raised = KeyboardInterrupt if stop == "SIGINT" else Terminated
    with workers_held(gate) as held:
        monkeypatch.setenv(GATE_VARIABLE, str(gate))  # the worker process inherits it
        sender = threading.Thread(target=signal_once_the_worker_waits, args=(held,))
        with dask.config.set({"distributed.worker.preload": [held.preload]}):
            with pytest.raises(raised), sigterm_as_exit():  # the stop leaves the block: caught outside it
                sender.start()
                with dask_mapper("local", 1) as mapper:
                    list(mapper(_tenfold, [0]))
        sender.join()
    assert not failures
    started = set(SpecCluster._instances) - known
    assert started and all(cluster.status.name == "closed" for cluster in started)


def test_a_signal_just_after_the_cluster_started_still_closes_it() -> None:
    """Ctrl-C between the deferred start (the handlers back) and the cleanup taking charge: the cluster is closed.
    It was left running, to dask's exit hook at best. The signal is raised on that line by a trace hook in the main
    thread, not by a race."""
    import inspect
    import signal
    import sys

    pytest.importorskip("distributed")
    from distributed.deploy.spec import SpecCluster

    from msflash.acquisition.session import dask_map

    code = dask_map.dask_mapper.__wrapped__.__code__  # type: ignore[attr-defined]
    source, first = inspect.getsourcelines(code)
    line = first + next(i for i, text in enumerate(source) if 'progress(f"dask: local cluster' in text)

    def on_the_line(frame, event: str, _arg):
        if event == "line" and frame.f_lineno == line:
            signal.raise_signal(signal.SIGINT)  # the handler is Python's again: KeyboardInterrupt here
        return on_the_line

    known = set(SpecCluster._instances)
    sys.settrace(lambda frame, _event, _arg: on_the_line if frame.f_code is code else None)
    try:
        with pytest.raises(KeyboardInterrupt):
            with dask_mapper("local", 1) as mapper:
                list(mapper(_tenfold, [0]))
    finally:
        sys.settrace(None)
    started = set(SpecCluster._instances) - known
    statuses = [cluster.status.name for cluster in started]
    for cluster in started:
        cluster.close()  # a no-op when closed; after a failure here, not left to the next test
    assert statuses == ["closed"]


_WITHOUT_DASK = """
import sys
sys.modules["distributed"] = None  # as on an install without the study/batch extra: importing it fails
sys.modules["dask"] = None
from msflash.acquisition.app.cli import main
raise SystemExit(main(sys.argv[1:]))
"""


def test_without_dask_a_batch_runs_serially_and_an_address_is_refused(tmp_path: Path) -> None:
    """dask is the ``study``/``batch`` extra (pyproject): without it ``--scheduler local`` (the default) runs the
    sequences one after another in this process, with one note, and a scheduler address is a one-line usage error."""
    from tests.helpers import write_test_sequence

    sequences = [str(write_test_sequence(tmp_path / name)) for name in ("a", "b")]
    run = subprocess.run(
        [sys.executable, "-c", _WITHOUT_DASK, "estimate", *sequences, "--json"], capture_output=True, text=True
    )
    assert run.returncode == 0, run.stderr
    lines = [json.loads(line) for line in run.stdout.splitlines()]
    assert [Path(line["sequence"]).name for line in lines] == ["a", "b"] and all("spectrum" in line for line in lines)
    assert "dask.distributed is not installed; running serially" in run.stderr
    refused = subprocess.run(
        [sys.executable, "-c", _WITHOUT_DASK, "estimate", *sequences, "--scheduler", "tcp://127.0.0.1:1"],
        capture_output=True,
        text=True,
    )
    assert refused.returncode == 2
    assert (
        refused.stderr.strip()
        .splitlines()[-1]
        .startswith("msflash: error: --scheduler tcp://127.0.0.1:1: dask.distributed is not installed")
    )
