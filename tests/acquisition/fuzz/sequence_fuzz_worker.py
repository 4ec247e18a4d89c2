"""The sequence fuzzer's worker: one process, capped in memory, running every example in-process.

``python -m tests.acquisition.fuzz.sequence_fuzz_worker --examples N [--memory-gib G] [--example-s S]``

It writes a valid sequence (:func:`tests.helpers.write_test_sequence`), records what ``estimate``,
``flash``, ``synthesize`` and ``check`` make of it, then lets Hypothesis mutate copies of it
(:mod:`tests.acquisition.fuzz.sequence_mutations`) and runs ``check`` and one of the three others on
each through ``main([...])``. Caps: the address space (``RLIMIT_AS``, the process's size after
its imports plus ``--memory-gib``; running out shows as an "unexpected MemoryError"), and each
example's wall time (``SIGALRM`` after ``--example-s`` seconds raises an exception no ``except
Exception`` can swallow; a hang inside C code that never returns to Python is left to the test's
own timeout on this process). Exit 0 and a JSON summary on the last stdout line if no example
broke a rule (:mod:`tests.acquisition.fuzz.sequence_mutations`); 1 with Hypothesis' falsifying
example(s) otherwise.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import hashlib
import io
import json
import math
import shutil
import sys
from pathlib import Path
from typing import Any

import hypothesis
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.image_files import read_image
from tests.acquisition.fuzz.sequence_mutations import Expect, Mutation, apply_mutation, every_frame_mutation, mutations
from tests.acquisition.support.fuzz_runner import example_alarm, fuzz_settings, worker_main
from tests.helpers import write_test_sequence

WEIGHTS = ",".join(["0.2"] * 7)
COMMANDS = {
    "estimate": lambda seq, out: ["estimate", str(seq), "--json"],
    "flash": lambda seq, out: ["flash", str(seq), "--mode", "complementary", "--json"],
    "synthesize": lambda seq, out: ["synthesize", str(seq), "--weights", WEIGHTS, "--out", str(out)],
    "check": lambda seq, out: ["check", str(seq), "--json"],
}
Result = tuple[int, str, str, str | None, bool]
"""Exit status, stdout, stderr, the SHA-256 of the pixels written (or None), whether its pixels are finite."""
FINITE_KEYS = {"estimate": ("spectrum", "ambient_weights"), "flash": ("ambient_weights", "flash_weights")}


def run_command(command: str, sequence: Path, out: Path) -> Result:
    """``main`` on one command: status, stdout, stderr and the SHA-256 of the written image (synthesize)."""
    out.unlink(missing_ok=True)
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        status = main(COMMANDS[command](sequence, out))
    written, finite = None, False
    if out.is_file():
        pixels = read_image(out)  # pixels, not file bytes: the file carries the time it was written
        written = hashlib.sha256(pixels.tobytes()).hexdigest()
        finite = bool(np.all(np.isfinite(pixels)))
    return status, stdout.getvalue(), stderr.getvalue(), written, finite


def _finite(value: Any) -> bool:
    if isinstance(value, list):
        return all(_finite(v) for v in value)
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def judge(command: str, mutation: Mutation, result: Result, baseline: Result) -> str | None:
    """What rule ``result`` breaks (None: none)."""
    status, stdout, stderr, written, image_finite = result
    if "Traceback" in stderr or "Traceback" in stdout:
        return "a traceback on the terminal"
    if "unexpected" in stderr and status == 1:
        return "a crash: " + stderr.strip().splitlines()[-1]
    if status not in (0, 1, 2):
        return f"exit status {status}"
    if status != 0:
        errors = [line for line in stderr.splitlines() if line.startswith("msflash: error:")]
        if len(errors) != 1:
            return f"exit {status} without exactly one 'msflash: error:' line: {stderr!r:.300}"
    if status == 0 and mutation.expect is Expect.REFUSE:
        return "exit 0 on corrupt data"
    if mutation.expect is Expect.SAME and (status, stdout, written) != (baseline[0], baseline[1], baseline[3]):
        return "a harmless change changed the result"
    if status == 0 and command in FINITE_KEYS:
        payload = json.loads(stdout)
        bad = [key for key in FINITE_KEYS[command] if not _finite(payload.get(key))]
        if bad:
            return f"exit 0 with non-finite {', '.join(bad)}"
    if status == 0 and command == "synthesize" and not image_finite:
        return "exit 0 without a finite image"
    return None


def fuzz(examples: int, example_s: int, work: Path) -> tuple[collections.Counter, list[str]]:
    """Run ``examples`` derandomised examples; raises Hypothesis' failure if any breaks a rule."""
    base = write_test_sequence(work / "base")
    case, out = work / "case" / "seq", work / "out.tiff"
    shutil.copytree(base, case)
    baselines = {command: run_command(command, case, out) for command in COMMANDS}
    assert all(result[0] == 0 for result in baselines.values()), baselines
    document = json.loads((base / "sequence.json").read_text())
    text = (base / "sequence.json").read_bytes()
    tally: collections.Counter = collections.Counter()
    runtime_errors: set[str] = set()

    @fuzz_settings(examples)
    @given(mutations(document, text), st.sampled_from(["estimate", "flash", "synthesize"]))
    def example(mutation: Mutation, command: str) -> None:
        shutil.rmtree(case.parent)
        case.parent.mkdir()
        shutil.copytree(base, case, symlinks=True)
        apply_mutation(case, mutation)
        problems = []
        with example_alarm(example_s):
            for name in ("check", command):
                result = run_command(name, case, out)
                tally[f"{mutation.expect.value} {name} exit {result[0]}"] += 1
                if result[0] == 1:  # a runtime error (a solver giving up…): allowed, but listed in the summary
                    runtime_errors.add(f"{mutation.describe:.60}: {result[2].strip().splitlines()[-1]:.200}")
                problem = judge(name, mutation, result, baselines[name])
                if problem:
                    problems.append(f"{name}: {problem} [{mutation.describe}] stderr: {result[2].strip()[-400:]}")
        assert not problems, "\n".join(problems)

    explicit = every_frame_mutation(1)
    for mutation in explicit:
        example = hypothesis.example(mutation, "estimate")(example)
    tally["explicit examples"] = len(explicit)
    example()
    return tally, sorted(runtime_errors)


def main_worker(argv: list[str] | None = None) -> int:
    def run(args: argparse.Namespace, work: Path) -> dict:
        tally, runtime_errors = fuzz(args.examples, args.example_s, work)
        return {"outcomes": dict(sorted(tally.items())), "runtime_errors": runtime_errors}

    return worker_main(argv, "msflash-fuzz-", run)


if __name__ == "__main__":
    sys.exit(main_worker())
