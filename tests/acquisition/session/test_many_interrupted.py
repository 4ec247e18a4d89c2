"""Ctrl-C or SIGTERM while ``msflash estimate`` over many sequences starts its local dask cluster, end to end.

A real process: exit 130/143 with one line, no output, no traceback, no dask process left. A signal
landing inside ``LocalCluster(...)`` used to leave a cluster nothing could close (dask's exit hook
then printed ``AssertionError: Status.init`` under ``msflash: interrupted``); the workers are held at
their start so that the signal lands there (tests/acquisition/support/held_dask_worker.py). The same
window in-process:
``tests/acquisition/session/test_dask_map.py::test_a_signal_while_the_local_cluster_starts_is_delivered_once_it_can_be_closed``.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.acquisition.support.held_dask_worker import signal_pending, workers_held
from tests.helpers import write_test_sequence


def _descendants(pid: int) -> list[int]:
    found: list[int] = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            found.append(int(entry.name))
    return found + [grandchild for child in found for grandchild in _descendants(child)]


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["sigint", "sigterm"])
def test_a_signal_while_the_cluster_starts_exits_in_one_line_and_leaves_no_process(
    tmp_path: Path, stop: signal.Signals
) -> None:
    """The workers are held at their start (tests/acquisition/support/held_dask_worker.py) until the signal has
    landed: ``LocalCluster(...)`` cannot return before. It was a race: the test signalled once it saw three dask
    processes, and a loaded machine let the cluster start and the sequences' results print before its poll ran
    (stdout not empty)."""
    pytest.importorskip("distributed")
    day = tmp_path / "day"
    first = write_test_sequence(day / "0800")
    shutil.copytree(first, day / "0900")
    gate = tmp_path / "gate" / "workers"
    gate.parent.mkdir()
    children: list[int] = []
    with workers_held(gate) as held:
        process = subprocess.Popen(
            [sys.executable, "-m", "msflash.acquisition.app.cli", "estimate", str(day), "--workers", "2", "--json"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            start_new_session=True,  # its own group: SIGINT is not ignored as in a background job
            env={**os.environ, **held.environment},
        )
        try:
            deadline = time.monotonic() + 120  # a hang guard, not a timing
            while not held.waiting():  # a worker waits at the gate: LocalCluster(...) cannot return
                assert process.poll() is None, process.communicate()
                assert time.monotonic() < deadline, "no dask worker reached the gate"
                time.sleep(0.01)
            children = _descendants(process.pid)
            os.kill(process.pid, stop)
            while signal_pending(process.pid, stop):  # delivered, before the workers may go on
                assert time.monotonic() < deadline, "the signal was never delivered"
                time.sleep(0.01)
        except BaseException:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
            raise
    try:
        out, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    text = err.decode()
    assert process.returncode == 128 + stop, text
    assert "Traceback" not in text and "Exception ignored" not in text, text
    expected = "msflash: interrupted" if stop == signal.SIGINT else "msflash: terminated (SIGTERM)"
    assert text.strip().splitlines()[-1] == expected
    assert out == b""
    assert children
    deadline = time.monotonic() + 60
    while alive := [pid for pid in children if _running(pid)]:
        assert time.monotonic() < deadline, f"dask processes {alive} outlived msflash"
        time.sleep(0.1)


def _running(pid: int) -> bool:
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False
