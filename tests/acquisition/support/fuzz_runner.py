"""Fuzz workers and their runner: the capped worker process the fuzz tests start, and how they start it.

A test runs a worker (``python -m tests.acquisition.fuzz.<worker> --examples N``) through
:func:`run_fuzz_worker`, with a hang guard, and fails with the worker's last output when it found
something. The workers share :func:`worker_main` (the command line, the address-space cap, the crash
log folder and the JSON summary on the last stdout line), :func:`fuzz_settings` (derandomised, no
database, no deadline) and :func:`example_alarm` (each example's wall time capped by ``SIGALRM``,
which raises :class:`ExampleTimeout`, an exception no ``except Exception`` can swallow).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import os
import resource
import signal
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

REPO = Path(__file__).resolve().parents[3]


def run_fuzz_worker(module: str, examples: int, timeout_s: float) -> dict:
    """The summary (last stdout line, JSON) of ``python -m module --examples examples``; a test failure otherwise."""
    try:
        done = subprocess.run(
            [sys.executable, "-m", module, "--examples", str(examples)],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"{module} did not finish {examples} examples within {timeout_s} s (a hang)")
    assert done.returncode == 0, done.stdout[-6000:] + done.stderr[-3000:]
    return json.loads(done.stdout.splitlines()[-1])


class ExampleTimeout(BaseException):
    """Raised by SIGALRM when one example runs too long (a BaseException: ``main`` cannot catch it)."""


class CurrentStderr(io.TextIOBase):
    """A stream writing to whatever ``sys.stderr`` is now (logging's handler outlives each redirect)."""

    def write(self, text: str) -> int:
        return sys.stderr.write(text)


def address_space_cap(extra_gib: float) -> int:
    """Cap this process's address space at its size now plus ``extra_gib`` (``RLIMIT_AS``); the cap in bytes."""
    vm_kib = next(
        int(line.split()[1])
        for line in Path("/proc/self/status").read_text().splitlines()
        if line.startswith("VmSize:")
    )
    cap = vm_kib * 1024 + int(extra_gib * 2**30)
    resource.setrlimit(resource.RLIMIT_AS, (cap, resource.getrlimit(resource.RLIMIT_AS)[1]))
    return cap


def fuzz_settings(examples: int) -> settings:
    """Hypothesis settings of a worker: ``examples`` derandomised examples, no database, deadline or health check."""
    return settings(
        max_examples=examples,
        derandomize=True,
        database=None,
        deadline=None,
        print_blob=False,
        suppress_health_check=list(HealthCheck),
    )


@contextlib.contextmanager
def example_alarm(example_s: int) -> Iterator[None]:
    """Raise :class:`ExampleTimeout` in the block once it has run ``example_s`` seconds."""

    def on_alarm(signum: int, frame: object) -> None:
        raise ExampleTimeout(f"an example ran past {example_s} s")

    signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(example_s)
    try:
        yield
    finally:
        signal.alarm(0)


def worker_main(
    argv: list[str] | None,
    prefix: str,
    fuzz: Callable[[argparse.Namespace, Path], dict[str, Any]],
    more_options: Callable[[argparse.ArgumentParser], None] | None = None,
) -> int:
    """A worker's ``main``: its options, the cap, a work folder and ``fuzz(args, work)``'s summary as JSON.

    ``fuzz`` runs the examples (raising Hypothesis' failure when one breaks a rule) and returns the
    summary's own keys; ``examples`` and ``address_space_cap_bytes`` come first.
    """
    from msflash.acquisition.app.cli import CRASH_LOG_ENV

    parser = argparse.ArgumentParser()
    parser.add_argument("--examples", type=int, default=200)
    parser.add_argument("--memory-gib", type=float, default=2.0)
    parser.add_argument("--example-s", type=int, default=60)
    if more_options is not None:
        more_options(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(stream=CurrentStderr(), format="msflash: %(name)s: %(message)s")
    with tempfile.TemporaryDirectory(prefix=prefix) as temporary:
        work = Path(temporary)
        os.environ[CRASH_LOG_ENV] = str(work / "crashes")
        cap = address_space_cap(args.memory_gib)
        summary = fuzz(args, work)
    print(json.dumps({"examples": args.examples, "address_space_cap_bytes": cap, **summary}))
    return 0
