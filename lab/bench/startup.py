"""Start-up bench: how long ``msflash`` takes as a whole process, as ratios to ``import numpy`` (issue 18).

Three commands are run as fresh processes of this interpreter, interleaved (numpy, help,
estimate, numpy, help, estimate …) so that load from other work on the machine falls on all three
alike, and their median wall times are compared:

- ``help_over_numpy``: ``msflash --help`` ÷ ``python -c "import numpy"`` — target ≤ 2;
- ``estimate_over_numpy``: ``msflash estimate SEQ --json`` on the demo's sequence (what
  ``msflash capture`` records on the default simulated rig; captured into a temporary folder
  unless one is given) ÷ the same — target ≤ 4.

``msflash`` is run as its entry point does (``acquisition.app.cli.main`` on the arguments), by the
same interpreter, so the figures do not depend on where the script is installed. Whether msflash's
own bytecode is cached (``__pycache__``; not with ``PYTHONDONTWRITEBYTECODE`` set, then every run
compiles msflash's sources) is reported as ``bytecode_cached``: it moves ``estimate_over_numpy``
by about one.
"""

from __future__ import annotations

import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

HELP_TARGET = 2.0
"""``msflash --help`` ÷ ``import numpy``: at most this."""
ESTIMATE_TARGET = 4.0
"""``msflash estimate`` on the demo's sequence ÷ ``import numpy``: at most this."""

_MSFLASH = "import sys; from msflash.acquisition.app.cli import main; sys.exit(main(sys.argv[1:]))"
"""What the ``msflash`` entry point runs."""


class StartupBenchError(RuntimeError):
    """A timed command failed (its exit status and last line of stderr are in the message)."""


def msflash_command(arguments: Sequence[str]) -> list[str]:
    """The command line running ``msflash ARGUMENTS`` with this interpreter.

    >>> msflash_command(["--help"])[-1]
    '--help'
    """
    return [sys.executable, "-c", _MSFLASH, *arguments]


def _run(command: Sequence[str], name: str) -> float:
    """Wall time of one run of ``command`` (called ``name`` in errors); raises :class:`StartupBenchError` when it fails."""
    start = time.perf_counter()
    result = subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, check=False)
    elapsed = time.perf_counter() - start
    if result.returncode != 0:
        last = (result.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise StartupBenchError(f"{name}: exit {result.returncode}: {last}")
    return elapsed


def bytecode_cached() -> bool:
    """Whether the bytecode of msflash's command line and estimator is cached (else each run compiles them)."""
    sources = [
        importlib.util.find_spec(name)
        for name in (
            "msflash.acquisition.app.cli",
            "msflash.acquisition.session.analysis",
            "msflash.processing.ambient",
        )
    ]
    return all(spec is not None and spec.cached is not None and Path(spec.cached).exists() for spec in sources)


def capture_demo_sequence(out: Path) -> Path:
    """Record the demo's sequence (``msflash capture --rig sim``, defaults) under ``out``; returns its folder."""
    _run(msflash_command(["capture", "--rig", "sim", "--out", str(out)]), "msflash capture --rig sim")
    return out / "sequence"


def interleaved_times(commands: dict[str, list[str]], rounds: int) -> dict[str, list[float]]:
    """Wall times of each command over ``rounds`` rounds, one run of each per round in the given order.

    One untimed run of each comes first (files into the page cache, bytecode written if allowed).

    Parameters
    ----------
    commands
        Name → command line.
    rounds
        Runs of each command (≥ 1).

    Returns
    -------
    dict
        Name → the times in seconds, in run order.
    """
    for name, command in commands.items():
        _run(command, name)
    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(rounds):
        for name, command in commands.items():
            times[name].append(_run(command, name))
    return times


def startup_bench(rounds: int = 9, sequence: str | Path | None = None) -> dict[str, Any]:
    """The start-up ratios (see the module notes), measured in this one run.

    Parameters
    ----------
    rounds
        Interleaved rounds; the ratios are of the medians.
    sequence
        The sequence ``estimate`` reads; None captures the demo's into a temporary folder.

    Returns
    -------
    dict
        ``help_over_numpy``, ``estimate_over_numpy`` with their targets and whether they are met,
        the median seconds, every time, and what was run. When a command fails: ``failed``, naming it.
    """
    with tempfile.TemporaryDirectory(prefix="msflash-bench-startup-") as scratch:
        try:
            seq = Path(sequence) if sequence is not None else capture_demo_sequence(Path(scratch))
            commands = {
                'python -c "import numpy"': [sys.executable, "-c", "import numpy"],
                "msflash --help": msflash_command(["--help"]),
                "msflash estimate SEQ --json": msflash_command(["estimate", str(seq), "--json"]),
            }
            times = dict(zip(("numpy", "help", "estimate"), interleaved_times(commands, rounds).values()))
        except StartupBenchError as err:
            return {"failed": str(err)}
    medians = {name: statistics.median(values) for name, values in times.items()}
    help_ratio = medians["help"] / medians["numpy"]
    estimate_ratio = medians["estimate"] / medians["numpy"]
    return {
        "help_over_numpy": help_ratio,
        "help_target": f"<= {HELP_TARGET:g}",
        "help_met": help_ratio <= HELP_TARGET,
        "estimate_over_numpy": estimate_ratio,
        "estimate_target": f"<= {ESTIMATE_TARGET:g}",
        "estimate_met": estimate_ratio <= ESTIMATE_TARGET,
        "median_s": medians,
        "times_s": times,
        "rounds": rounds,
        "bytecode_cached": bytecode_cached(),
        "sequence": "demo (captured on the simulated rig)" if sequence is None else str(sequence),
        "commands": {
            "numpy": 'python -c "import numpy"',
            "help": "msflash --help",
            "estimate": "msflash estimate SEQ --json",
        },
    }
