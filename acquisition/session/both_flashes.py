"""Both flashes of one estimate, and what the complementary target could not reach.

``run``, ``live``'s fire button, two-capture runs (replay) and ``evaluate`` report the matching
(eq. 7) and the complementary (eq. 8–9) flash of one ambient estimate. Solving them and keeping
the :class:`~processing.errors.TargetUnreachableWarning` each raised is this one function,
:func:`solve_both`; what solves a mode is a :class:`FlashSolver` (the run's prepared
:class:`~acquisition.session.flash_session.FlashSession`, a sequence's spectra, a study's world).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol
from warnings import WarningMessage

import numpy as np

from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.session import analysis
from msflash.processing.errors import TargetUnreachableWarning
from msflash.processing.flash import FlashSolution

FLASH_MODES = ("matching", "complementary")
"""The two flashes, in the order they are reported."""


class FlashSolver(Protocol):
    """What solves one flash mode for ambient weights (:meth:`FlashSession.solve` is one)."""

    def solve(self, mode: str, ambient_weights: np.ndarray) -> FlashSolution:
        """The ``mode`` flash (``matching`` or ``complementary``) for ``ambient_weights``."""
        ...


@dataclass(frozen=True)
class BothFlashes:
    """The matching and complementary flashes of one estimate, with the warnings solving them raised."""

    solutions: dict[str, FlashSolution]
    """``matching`` and ``complementary``, the first-solved mode first."""
    warnings: tuple[WarningMessage, ...] = field(default=())
    """Every :class:`TargetUnreachableWarning` raised while solving, in order."""

    @property
    def notes(self) -> list[str]:
        """The warnings as one line each (what JSON reports carry)."""
        return [str(caught.message) for caught in self.warnings]


@dataclass(frozen=True)
class SequenceFlashes:
    """The flash solvers of a recorded sequence (its LEDs, camera and ``target``; :func:`analysis.solve_sequence_flash`)."""

    sequence: Sequence
    target: str = "D65"

    def solve(self, mode: str, ambient_weights: np.ndarray) -> FlashSolution:
        return analysis.solve_sequence_flash(self.sequence, mode, ambient_weights, self.target)


def solve_both(
    solver: FlashSolver,
    ambient_weights: np.ndarray,
    first: str = "complementary",
    solved: Mapping[str, FlashSolution] | None = None,
) -> BothFlashes:
    """Solve the matching and the complementary flash for ``ambient_weights``, ``first`` first.

    ``solved`` holds flashes already solved (the one-stream run's, decided before the flash
    frame): they are kept as given and not solved again. Every
    :class:`~processing.errors.TargetUnreachableWarning` raised meanwhile is recorded (never
    shown twice, never lost to a warnings filter) in :attr:`BothFlashes.warnings`.
    """
    if first not in FLASH_MODES:
        raise ValueError(f"flash mode {first!r}: unknown; expected one of {', '.join(FLASH_MODES)}")
    solutions: dict[str, FlashSolution] = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TargetUnreachableWarning)
        for mode in (first, *(m for m in FLASH_MODES if m != first)):
            known = (solved or {}).get(mode)
            solutions[mode] = known if known is not None else solver.solve(mode, ambient_weights)
    return BothFlashes(solutions, tuple(caught))
