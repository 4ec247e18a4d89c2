"""A dask worker preload that holds every worker process of a local cluster at its start until a test lets it go.

Named by ``distributed.worker.preload`` (``DASK_DISTRIBUTED__WORKER__PRELOAD`` in the environment of the process
that starts the cluster: its nannies hand the setting on to the workers they spawn), with :data:`GATE_VARIABLE`
naming the gate file. The worker touches ``worker-PID.held`` beside the gate, then waits for a shared lock on it:
while the test holds the exclusive lock (:func:`workers_held`), no worker can register with the scheduler, so
``LocalCluster(...)`` in the process that starts it cannot return. A test then knows that process is inside the
call, whatever the machine's load, instead of hoping its poll is quicker than the workers' start.
"""

from __future__ import annotations

import fcntl
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

GATE_VARIABLE = "MSFLASH_TEST_WORKER_GATE"
"""The environment variable naming the gate file."""


@dataclass
class HeldWorkers:
    """The gate the workers wait at, held by this process until :meth:`release`."""

    gate: Path
    handle: IO[str]
    preload: str = __file__
    """The ``distributed.worker.preload`` that makes a worker wait at the gate: this file."""
    _released: threading.Event = field(default_factory=threading.Event)

    @property
    def environment(self) -> dict[str, str]:
        """What a process starting a local cluster needs in its environment for its workers to wait here."""
        return {"DASK_DISTRIBUTED__WORKER__PRELOAD": self.preload, GATE_VARIABLE: str(self.gate)}

    def waiting(self) -> list[int]:
        """The workers that reached the gate so far (their process ids)."""
        return [int(path.name.split("-")[1].split(".")[0]) for path in self.gate.parent.glob("worker-*.held")]

    def release(self) -> None:
        """Let the workers go on (once; later calls do nothing)."""
        if not self._released.is_set():
            self._released.set()
            fcntl.flock(self.handle, fcntl.LOCK_UN)


@contextmanager
def workers_held(gate: Path) -> Iterator[HeldWorkers]:
    """Hold the workers at ``gate`` (a file in a folder of its own) until released, at the latest when the block ends."""
    gate.touch()
    with gate.open() as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        held = HeldWorkers(gate, handle)
        try:
            yield held
        finally:
            held.release()


def signal_pending(pid: int, number: int) -> bool:
    """Whether signal ``number`` sent to process ``pid`` waits undelivered (its shared pending set, /proc status)."""
    for line in (Path("/proc") / str(pid) / "status").read_text().splitlines():
        if line.startswith("ShdPnd:"):
            return bool(int(line.split()[1], 16) >> (number - 1) & 1)
    return False


def _wait_at_the_gate() -> None:
    gate = Path(os.environ[GATE_VARIABLE])
    (gate.parent / f"worker-{os.getpid()}.held").touch()
    with gate.open() as handle:
        fcntl.flock(handle, fcntl.LOCK_SH)  # blocks while the test holds the gate
        fcntl.flock(handle, fcntl.LOCK_UN)


if os.environ.get(GATE_VARIABLE) and __name__ != "tests.acquisition.support.held_dask_worker":
    _wait_at_the_gate()  # run as a worker's preload (loaded from its path), not imported by a test
