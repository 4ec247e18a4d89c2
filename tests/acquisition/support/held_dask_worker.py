"""A dask worker preload that holds every worker process of a local cluster at its start until a test lets it go.

Named by ``DASK_DISTRIBUTED__WORKER__PRELOAD`` in the environment of the process that starts the cluster (its
nannies hand the setting on to the workers they spawn), with :data:`GATE_VARIABLE` naming the gate file. The worker
touches ``worker-PID.held`` beside the gate, then waits for a shared lock on it: while the test holds the exclusive
lock (:func:`workers_held`), no worker can register with the scheduler, so ``LocalCluster(...)`` in the process
that starts it cannot return. A test then knows that process is inside the call, whatever the machine's load,
instead of hoping its poll is quicker than the workers' start.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

GATE_VARIABLE = "MSFLASH_TEST_WORKER_GATE"
"""The environment variable naming the gate file."""


@contextmanager
def workers_held(gate: Path) -> Iterator[dict[str, str]]:
    """Hold the workers at ``gate`` until the block ends; yields the environment a cluster-starting process needs."""
    gate.touch()
    with gate.open() as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield {"DASK_DISTRIBUTED__WORKER__PRELOAD": __file__, GATE_VARIABLE: str(gate)}
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def held_workers(gate: Path) -> list[int]:
    """The workers that reached ``gate`` so far (their process ids)."""
    return [int(path.name.split("-")[1].split(".")[0]) for path in gate.parent.glob("worker-*.held")]


def _wait_at_the_gate() -> None:
    gate = Path(os.environ[GATE_VARIABLE])
    (gate.parent / f"worker-{os.getpid()}.held").touch()
    with gate.open() as handle:
        fcntl.flock(handle, fcntl.LOCK_SH)  # blocks while the test holds the gate
        fcntl.flock(handle, fcntl.LOCK_UN)


if os.environ.get(GATE_VARIABLE) and __name__ != "tests.acquisition.support.held_dask_worker":
    _wait_at_the_gate()  # run as a worker's preload (loaded from its path), not imported by the test
