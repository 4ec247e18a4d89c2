"""Run one function over many items on dask, results in the items' order.

The one way msflash spreads independent jobs over processes or machines: the studies' cameras and
illuminants (``msflash study``) and many recorded sequences (``msflash estimate``/``flash`` on
several sequences, :mod:`acquisition.session.many`). ``scheduler`` is

- ``local``: a local dask cluster of ``workers`` processes (default: the CPUs), one thread each,
  the scheduler, workers and dashboard on 127.0.0.1 only;
- ``none``: serially, in this process (no dask needed);
- an address (``tcp://HOST:PORT``): a running dask scheduler, whose workers must have msflash
  installed (the function travels by reference). Connecting gives up after
  :data:`CONNECT_TIMEOUT_S` with a :class:`~acquisition.errors.UsageError` naming the address.

dask's own logs stay silent below errors unless ``verbose``. ``distributed`` is imported only when a
cluster is used, so a command's ``--help`` does not import it.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, Protocol

from msflash.acquisition.errors import UsageError
from msflash.acquisition.progress import progress
from msflash.acquisition.signals import deliver_deferred, signals_deferred

OnError = Callable[[Any, Exception], Any]
"""``on_error(item, error)``: what to yield for an item whose job raised (or whose worker died)."""


class Mapper(Protocol):
    """``mapper(function, items)``: ``function(item)`` for each item, yielded in the items' order.

    With ``on_error``, an item whose job raised, or whose worker process died, yields
    ``on_error(item, error)`` and the others go on; without, the error is raised.
    """

    def __call__(
        self, function: Callable[[Any], Any], items: Sequence[Any], on_error: OnError | None = None
    ) -> Iterator[Any]: ...


LOCAL = "local"
SERIAL = "none"
CONNECT_TIMEOUT_S = 10
"""How long connecting to a scheduler address may take before the command gives up (exit 2)."""
MAX_WORKERS_PER_CPU = 4
"""``--workers`` of a local cluster beyond this many per CPU are refused: each is a process, and a
slip of the keyboard (``--workers 100000``) would otherwise start that many."""


def serial_map(function: Callable[[Any], Any], items: Sequence[Any], on_error: OnError | None = None) -> Iterator[Any]:
    """The serial :class:`Mapper`: ``function`` over ``items`` in this process, in order."""
    for item in items:
        try:
            result = function(item)
        except Exception as err:
            if on_error is None:
                raise
            result = on_error(item, err)
        yield result


@contextmanager
def _quiet_dask(verbose: bool) -> Iterator[None]:
    """dask's loggers at ERROR while the block runs (worker processes inherit it through the environment)."""
    if verbose:
        yield
        return
    names = ("distributed", "dask")
    previous_levels = [logging.getLogger(name).level for name in names]
    previous_env = os.environ.get("DASK_LOGGING__DISTRIBUTED")
    os.environ["DASK_LOGGING__DISTRIBUTED"] = "critical"
    for name in names:
        logging.getLogger(name).setLevel(logging.ERROR)
    try:
        yield
    finally:
        for name, level in zip(names, previous_levels, strict=True):
            logging.getLogger(name).setLevel(level)
        if previous_env is None:
            os.environ.pop("DASK_LOGGING__DISTRIBUTED", None)
        else:
            os.environ["DASK_LOGGING__DISTRIBUTED"] = previous_env


@contextmanager
def dask_mapper(scheduler: str, workers: int | None = None, *, verbose: bool = False) -> Iterator[Mapper]:
    """A :data:`Mapper` running on ``scheduler`` (``local``, ``none`` or an address; module docstring).

    ``workers``: processes of the local cluster (default: the CPUs); ``verbose`` lets dask log below errors.

    Raises
    ------
    UsageError
        An address that is not one, or whose scheduler does not answer within :data:`CONNECT_TIMEOUT_S`;
        an address when dask.distributed is not installed; more local workers than
        :data:`MAX_WORKERS_PER_CPU` per CPU.
    """
    if scheduler == SERIAL:
        yield serial_map
        return
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        if scheduler == LOCAL:
            progress("dask.distributed is not installed; running serially")
            yield serial_map
            return
        raise UsageError(
            f"--scheduler {scheduler}: dask.distributed is not installed (pip install 'dask[distributed]')"
        ) from None
    with _quiet_dask(verbose):
        cluster = client = None
        held: list[int] = []
        # The cleanup takes charge before the cluster exists: a signal just after the deferred start (the handlers
        # back) must still close it.
        try:
            if scheduler == LOCAL:
                n = _local_workers(workers)
                with signals_deferred(held):
                    cluster = _local_cluster(LocalCluster, n, verbose)
                    client = Client(cluster)
                progress(f"dask: local cluster with {n} workers")
            else:
                client = _connect(Client, scheduler)
            deliver_deferred(held)  # a Ctrl-C while the cluster started: now that it can be closed
            yield _client_mapper(client)
        finally:
            with signals_deferred(held):
                if client is not None:
                    client.close()
                if cluster is not None:
                    cluster.close()
            deliver_deferred(held)


def _local_workers(workers: int | None) -> int:
    """The local cluster's processes: ``workers``, default the CPUs, at most :data:`MAX_WORKERS_PER_CPU` per CPU."""
    cpus = os.cpu_count() or 1
    n = workers or cpus
    if n > MAX_WORKERS_PER_CPU * cpus:
        raise UsageError(
            f"--workers {n}: more worker processes than this machine's {cpus} CPUs can serve; expected at "
            f"most {MAX_WORKERS_PER_CPU * cpus} ({MAX_WORKERS_PER_CPU} per CPU)"
        )
    return n


def _local_cluster(cluster_type: Any, n: int, verbose: bool) -> Any:
    """A local cluster of ``n`` single-threaded worker processes on 127.0.0.1."""
    # Loopback only: the scheduler, workers and dashboard never listen on other interfaces.
    return cluster_type(
        n_workers=n,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
        # Worker processes log on their own stderr: without -v only CRITICAL records (a
        # worker's heartbeat racing the scheduler's shutdown logged an ERROR and a 30-line
        # traceback after a finished study); a task's own failure reaches us as its exception.
        silence_logs=logging.INFO if verbose else logging.CRITICAL,
    )


def _connect(client_type: Any, scheduler: str) -> Any:
    """A client of the running scheduler at ``scheduler``, or a :class:`UsageError` naming the address."""
    try:
        client = client_type(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError, ValueError, TypeError) as err:  # ValueError: not an address at all
        raise UsageError(
            f"--scheduler {scheduler}: cannot connect ({' '.join(str(err).split())}); expected 'local', "
            "'none' or a dask scheduler address (tcp://HOST:PORT) that answers"
        ) from None
    progress(f"dask: scheduler {scheduler}")
    return client


def _client_mapper(client: Any) -> Mapper:
    """The :class:`Mapper` of a dask client: every item submitted at once, results yielded in the items' order."""

    def mapper(function: Callable[[Any], Any], items: Sequence[Any], on_error: OnError | None = None) -> Iterator[Any]:
        items = list(items)
        futures = client.map(function, items, pure=False)
        for item, future in zip(items, futures, strict=True):  # in order, aligned with the items
            try:
                result = future.result()
            except Exception as err:  # the job's own error, or KilledWorker when its process died
                if on_error is None:
                    raise
                result = on_error(item, err)
            yield result

    return mapper
