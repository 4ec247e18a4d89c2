"""What the lab's commands share and the product does not use: an optional ``--out``, a reporter of counts,
spectra scaled for plotting."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from msflash.acquisition.app.cli_common import claimed_output
from msflash.acquisition.app.plot_style import PLOT_UNIT
from msflash.acquisition.progress import count, progress
from msflash.processing.spectra import Spectra, SpectralUnit, WavelengthGrid


@contextlib.contextmanager
def optional_claimed_output(path: str | os.PathLike | None, what: str) -> Iterator[Path | None]:
    """:func:`claimed_output` for an ``--out`` that may be absent (a study printing JSON only): None stays None."""
    if path is None:
        yield None
        return
    with claimed_output(path, what) as out:
        yield out


class _Reporter:
    """What the lab hands to ``processing`` as ``progress``: lines and counts (a ``CountedProgress``)."""

    def __call__(self, message: str, /) -> None:
        progress(message)

    def count(self, label: str, done: int, total: int, unit: str, note: str) -> None:
        count(label, done, total, unit, note)


REPORTER = _Reporter()
"""The reporter to pass as a study's ``progress`` (:mod:`msflash.lab.progress`)."""


def relative_power(
    wavelengths_nm: np.ndarray | list[float], values: np.ndarray | list[float], unit: SpectralUnit
) -> np.ndarray:
    """A spectrum given in ``unit`` on ``wavelengths_nm``, in :data:`PLOT_UNIT`, scaled to a peak of 1 (NaN kept).

    Examples
    --------
    >>> relative_power([400.0, 800.0], [1.0, 1.0], "photons").round(3).tolist()  # energy ∝ photons / λ
    [1.0, 0.5]
    """
    wavelengths = np.asarray(wavelengths_nm, dtype=float)
    data = np.asarray(values, dtype=float)
    step = float(wavelengths[1] - wavelengths[0]) if wavelengths.size > 1 else 1.0
    grid = WavelengthGrid(float(wavelengths[0]), float(wavelengths[-1]), step)
    clean = np.nan_to_num(data)
    converted = Spectra(grid, clean.reshape(-1, 1), ("spectrum",), "spd", unit).to_unit(PLOT_UNIT).values[:, 0]
    converted = np.where(np.isnan(data), np.nan, converted)
    peak = float(np.nanmax(np.abs(converted))) if np.any(np.isfinite(converted)) else 0.0
    return converted / peak if peak > 0 else converted
