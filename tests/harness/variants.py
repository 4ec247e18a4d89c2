"""The estimator variants the harness compares: ``name → how to estimate`` (:data:`VARIANTS`).

A variant that is ``msflash estimate`` with extra arguments is one line here::

    "prior": msflash("--model", "prior"),

or, without editing, one option of the harness: ``--variant prior="--model prior"``. msflash
variants run the real command in-process (``acquisition.app.cli.main``) on the sequence on disk, so
whatever the estimator does today is what is measured; the baselines
(:mod:`tests.harness.baselines`) read the same files.
"""

from __future__ import annotations

import json
import shlex
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tests.harness import baselines
from tests.harness.render import REFERENCE_CHART_FILE, REFERENCE_PATCH_FILE
from tests.processing.unseen_sequences import run_cli


@dataclass(frozen=True)
class Estimate:
    """What a variant gave for one sequence (``error`` set when it gave nothing)."""

    spectrum: np.ndarray | None = None
    std: np.ndarray | None = None
    """1σ band in the sequence's unit (None: the variant has no band)."""
    warnings: tuple[str, ...] | None = None
    """Warnings it printed (None: the variant cannot warn)."""
    error: str = ""
    notes: tuple[str, ...] = ()
    """Python warnings or other oddities seen while it ran (flags, not failures)."""


@dataclass(frozen=True)
class Variant:
    """One way of estimating: ``msflash estimate`` with ``arguments``, or a Python function."""

    name: str
    arguments: tuple[str, ...] = ()
    function: Callable[[Path], np.ndarray] | None = field(default=None, compare=False)
    block: str = ""
    """Read ``models[block]`` of the JSON (one model's spectrum, band and warnings) instead of the chosen one."""
    reference_patch: bool = False
    """Pass ``--reference-patch`` with the white card the renderer wrote beside the sequence."""
    reference_chart: bool = False
    """Pass ``--reference-chart`` with the chart of the scene's surfaces the renderer wrote beside the sequence."""

    @property
    def command(self) -> str:
        """How it estimates, for the report."""
        if self.function is not None:
            return f"{self.function.__module__}.{self.function.__name__}"
        command = " ".join(["msflash estimate SEQ --json", *map(shlex.quote, self.arguments)])
        command += " --reference-patch X,Y,W,H (the white card)" if self.reference_patch else ""
        command += " --reference-chart FILE (24 of the scene's surfaces)" if self.reference_chart else ""
        return command + (f" (its models.{self.block})" if self.block else "")

    def estimate(self, directory: Path) -> Estimate:
        """Run this variant on the sequence in ``directory``."""
        if self.function is not None:
            try:
                return Estimate(spectrum=np.asarray(self.function(directory), float))
            except Exception as error:  # noqa: BLE001 — a failing baseline is a result, not a crash
                return Estimate(error=f"{type(error).__name__}: {error}")
        arguments = self.arguments
        if self.reference_patch:
            rect = json.loads((directory / REFERENCE_PATCH_FILE).read_text())
            arguments += ("--reference-patch", ",".join(str(int(v)) for v in rect))
        if self.reference_chart:
            arguments += ("--reference-chart", str(directory / REFERENCE_CHART_FILE))
        status, out, err, caught = _run_estimate(str(directory), arguments)
        if status != 0:
            return Estimate(error=f"status {status}: {err.strip().splitlines()[-1] if err.strip() else ''}")
        payload = json.loads(out)
        if self.block:
            payload = payload["models"][self.block]
        std = payload.get("spectrum_std")
        return Estimate(
            np.asarray(payload["spectrum"], float),
            None if std is None else np.asarray(std, float),
            tuple(payload.get("warnings", ())),
            notes=tuple(caught),
        )


_LAST_RUN: dict[tuple[str, tuple[str, ...]], tuple[int, str, str, list[str]]] = {}


def _run_estimate(directory: str, arguments: tuple[str, ...]) -> tuple[int, str, str, list[str]]:
    """``msflash estimate DIRECTORY --json ARGUMENTS``, run once per sequence and arguments in this process: the
    variants that read one model's block of the same ``--model auto`` run share it."""
    key = (directory, arguments)
    if key not in _LAST_RUN:
        _LAST_RUN.clear()  # one sequence at a time: a worker measures every variant of a case before the next
        _LAST_RUN[key] = run_cli(["estimate", directory, "--json", *arguments])
    return _LAST_RUN[key]


def msflash(*arguments: str) -> Callable[[str], Variant]:
    """A registry entry for ``msflash estimate SEQ --json ARGUMENTS``."""
    return lambda name: Variant(name, tuple(arguments))


def python(function: Callable[[Path], np.ndarray]) -> Callable[[str], Variant]:
    """A registry entry for a Python estimator (sequence directory → spectrum in the sequence unit)."""
    return lambda name: Variant(name, function=function)


_REGISTRY: Mapping[str, Callable[[str], Variant]] = {
    "default": msflash(),
    "msflash-lstsq": msflash("--solver", "lstsq"),
    # The models beyond the LEDs all read one `--model auto` run: its `models` block holds each model's spectrum,
    # band and warnings exactly as `--model prior` and `--model family` print them (tests/acquisition/app/test_cli_model.py).
    "prior": lambda name: Variant(name, ("--model", "auto"), block="prior"),
    "family": lambda name: Variant(name, ("--model", "auto"), block="family"),
    "auto": msflash("--model", "auto"),
    "led-checked": lambda name: Variant(name, ("--model", "auto"), block="led"),
    "auto-patch": lambda name: Variant(name, ("--model", "auto"), reference_patch=True),
    "family-patch": lambda name: Variant(name, ("--model", "auto"), block="family", reference_patch=True),
    "auto-chart": lambda name: Variant(name, ("--model", "auto"), reference_chart=True),
    "family-chart": lambda name: Variant(name, ("--model", "auto"), block="family", reference_chart=True),
    "authors": python(baselines.authors_estimate),
    "authors-alpha-scaled": python(baselines.authors_estimate_scaled),
    "lstsq-pixels": python(baselines.lstsq_estimate),
}
"""Every registered variant, in report order (add one line per new msflash option)."""

VARIANTS: dict[str, Variant] = {name: make(name) for name, make in _REGISTRY.items()}


def parse_variant(text: str) -> Variant:
    """``NAME`` (a registered variant) or ``NAME=ARGS`` (``msflash estimate`` with ARGS, shell-split).

    >>> parse_variant('prior=--model prior --alpha 0.1').arguments
    ('--model', 'prior', '--alpha', '0.1')
    >>> parse_variant('authors').name
    'authors'
    """
    name, sep, arguments = text.partition("=")
    name = name.strip()
    if not sep:
        if name not in VARIANTS:
            raise ValueError(f'unknown variant {name!r}; expected one of {", ".join(VARIANTS)} or NAME="ARGS"')
        return VARIANTS[name]
    if not name:
        raise ValueError(f'variant {text!r}: expected NAME="ARGS"')
    return Variant(name, tuple(shlex.split(arguments)))


def select(texts: list[str] | None) -> list[Variant]:
    """The variants a run uses: all registered ones, unless ``texts`` names some.

    Bare names restrict the run to those names; ``NAME=ARGS`` definitions are added (to all
    registered variants when no bare name is given).

    >>> [v.name for v in select(['x=--solver nonneg'])][-2:]
    ['lstsq-pixels', 'x']
    >>> [v.name for v in select(['default', 'x=--solver nonneg'])]
    ['default', 'x']
    """
    parsed = [parse_variant(text) for text in texts or []]
    defined = [v for v, text in zip(parsed, texts or []) if "=" in text]
    named = [v for v, text in zip(parsed, texts or []) if "=" not in text]
    chosen = named if named else list(VARIANTS.values())
    out = {v.name: v for v in chosen}
    out.update({v.name: v for v in defined})
    return list(out.values())
