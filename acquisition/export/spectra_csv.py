"""Spectra as a CSV table: wavelength first, one column per spectrum, units in the header.

The header row names every column as ``name [unit]`` (``wavelength [nm]`` first), so any CSV
reader (the csv module, pandas, a spreadsheet) gets the units without a side file; values are
written with ``repr`` precision.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass
from pathlib import Path

import numpy as np

WAVELENGTH_HEADER = "wavelength [nm]"
"""The first column's header."""


@dataclass(frozen=True)
class SpectrumColumn:
    """One column of the table."""

    name: str
    """What the spectrum is (``ambient estimate``, ``LED led440 at full drive``…)."""
    unit: str
    """Its unit, written in brackets after the name."""
    values: np.ndarray
    """One value per wavelength."""

    @property
    def header(self) -> str:
        """``name [unit]``."""
        return f"{self.name} [{self.unit}]"


def write_spectra_csv(path: str | os.PathLike, wavelengths_nm: np.ndarray, columns: SequenceOf[SpectrumColumn]) -> Path:
    """Write ``wavelength [nm]`` and the columns, one row per wavelength.

    Raises
    ------
    ValueError
        If a column has not one value per wavelength, or two columns share a header.
    """
    wavelengths = np.asarray(wavelengths_nm, dtype=float)
    headers = [WAVELENGTH_HEADER] + [column.header for column in columns]
    if len(set(headers)) != len(headers):
        raise ValueError(f"{path}: column headers {headers} repeat; expected unique names")
    table = [wavelengths]
    for column in columns:
        values = np.asarray(column.values, dtype=float)
        if values.shape != wavelengths.shape:
            raise ValueError(f"{path}: column '{column.header}' has {values.size} values; expected {wavelengths.size}")
        table.append(values)
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(headers)
        for row in np.column_stack(table):
            writer.writerow([repr(float(v)) for v in row])
    return path
