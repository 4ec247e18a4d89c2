"""Second moments of rows of samples: Gram matrices over column chunks shared by a process-wide pool of threads.

The chunks' products are added in chunk order whatever the number of threads, so a moment does not depend on it;
products stay below OpenBLAS's threading threshold (its threads' wake-ups cost more than the product on a busy
2-core machine, docs/architecture.md §10).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from typing import TypeVar

import numpy as np

DEFAULT_CHUNK_PIXELS = 1 << 15
"""Pixels per chunk: small enough to stay in cache for k ≈ 8 frames, large enough to amortise numpy calls."""


DEFAULT_WORKERS = 2 if (os.cpu_count() or 1) >= 2 else 1
"""Threads for the image passes (block sums, moments, synthesis): the app runs on 2 cores."""


PRODUCT_COLUMNS = 4096
"""Columns per slice of the weighted moments' products (:func:`gram_matrices`) at most: one thread each
(OpenBLAS threads a matrix–vector product of 9 × 7 000 already, and its threads' wake-ups on a busy machine
cost many times the product: docs/measurements.md)."""


SERIAL_PRODUCT = 1 << 18
"""Multiply-adds (m · n · k) of a matrix product that OpenBLAS still runs on the calling thread. Above, it splits some
products across its threads — a (33 × 1024) Gram matrix, an (8 × 9) map of 16 320 columns — and on a busy 2-core
machine their wake-ups cost many times the product (docs/speed.md)."""


def serial_columns(rows: int, outputs: int) -> int:
    """Columns per slice of a product ``(outputs × rows) @ (rows × columns)`` (or a Gram matrix of ``rows`` rows,
    ``outputs = rows``) that stays within :data:`SERIAL_PRODUCT`.

    Examples
    --------
    >>> serial_columns(33, 33), serial_columns(9, 8)
    (240, 3640)
    """
    return max(1, SERIAL_PRODUCT // max(1, rows * outputs))


@lru_cache(maxsize=4)
def thread_pool(workers: int) -> ThreadPoolExecutor:
    """A process-wide pool of ``workers`` threads for the image passes (created on first use, then reused)."""
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix="msflash-image")


Result = TypeVar("Result")


def shared_tasks(task: Callable[[int], Result], count: int, workers: int) -> list[Result]:
    """``task(i)`` for every ``i`` in ``range(count)``, the results in that order: the calling thread and up to
    ``workers − 1`` of the pool take the next task in turn. The caller works rather than waits for the pool (one
    runnable thread fewer on two cores), and a helper the pool has not started by the end is cancelled, so a call
    from inside the pool cannot wait on itself."""
    if workers <= 1 or count <= 1:
        return [task(index) for index in range(count)]
    results: dict[int, Result] = {}
    following = iter(range(count))
    lock = threading.Lock()

    def take() -> None:
        while True:
            with lock:
                index = next(following, None)
            if index is None:
                return
            results[index] = task(index)

    helpers = [thread_pool(workers).submit(take) for _ in range(min(workers, count) - 1)]
    take()
    for helper in helpers:
        if not helper.cancel():
            helper.result()
    return [results[index] for index in range(count)]


def gram_matrices(
    parts: Sequence[tuple[np.ndarray, np.ndarray | None]], chunk: int, workers: int = 1
) -> list[np.ndarray]:
    """``rows @ rows.T`` (with ``weights``, ``rows @ diag(weights) @ rows.T``) in float64 of several ``(rows, weights)``
    at once, accumulated over column chunks; ``workers`` threads share the chunks of all of them (one map: a part
    with a single chunk does not run alone after the others). Each chunk is weighted while it is in cache.

    The chunks' products are added in chunk order whatever the number of workers, so the result
    does not depend on it.
    """
    chunk = max(chunk, 1)

    def product(task: tuple[int, int]) -> np.ndarray:
        rows, weights = parts[task[0]]
        start = task[1]
        block = rows[:, start : start + chunk]
        if weights is None:
            return block @ block.T
        # Weighted in slices, so that each weighted copy is still in cache for its product and that product stays
        # on this thread (SERIAL_PRODUCT; a slice of a 33-frame stack's rows is then 70 kB, not 1 MB):
        # ``(x·√w)(x·√w)ᵀ``, one symmetric product (BLAS syrk: half the multiplications).
        result = np.zeros((rows.shape[0], rows.shape[0]))
        column_weights = weights[start : start + chunk]
        step = min(PRODUCT_COLUMNS, max(256, serial_columns(rows.shape[0], rows.shape[0])))
        for offset in range(0, block.shape[1], step):
            part = block[:, offset : offset + step] * np.sqrt(column_weights[offset : offset + step])
            result += part @ part.T
        return result

    tasks = [(index, start) for index, (rows, _) in enumerate(parts) for start in range(0, rows.shape[1], chunk)]
    products = thread_pool(workers).map(product, tasks) if workers > 1 and len(tasks) > 1 else map(product, tasks)
    moments = [np.zeros((rows.shape[0], rows.shape[0])) for rows, _ in parts]
    for (index, _), part in zip(tasks, products):
        moments[index] += part
    return moments
