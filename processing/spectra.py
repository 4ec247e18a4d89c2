"""Spectral data: one wavelength-grid type, one spectra container, the only resampler.

Public objects
--------------
- :class:`WavelengthGrid`: a uniform wavelength grid in nanometres.
- :class:`Spectra`: a set of spectra sampled on one grid, knowing their kind and unit.
- :func:`energy_to_photons` / :func:`photons_to_energy`: the unit conversion, in one place.
- :func:`require_same_grid`: the check every function combining spectra performs.

Everything in msflash that changes the sampling of a spectrum goes through
:meth:`Spectra.resample`; nothing else interpolates spectra.

Units
-----
Spectral power distributions (``kind="spd"``) and camera responsivities
(``kind="responsivity"``) carry a unit: ``"energy"`` or ``"photons"``. The conversion is
``photons = energy · λ / λ_ref`` for power and the inverse for responsivities, so that
``responsivityᵀ · spd`` (a camera response) is the same in both units. ``λ_ref`` is
:data:`PHOTON_REFERENCE_NM`: all spectra in msflash are relative, and the reference keeps
photon-unit values of the same magnitude as the energy-unit ones (the factor ``1/(h c)`` would
only scale every spectrum by ~5e18). Reflectances (``kind="reflectance"``) have no unit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from msflash.processing.errors import SpectralDataError

SpectralKind = Literal["spd", "responsivity", "reflectance"]
SpectralUnit = Literal["energy", "photons", "none"]

PHOTON_REFERENCE_NM = 555.0
"""Reference wavelength of the relative photon unit (see the module notes)."""

_GRID_TOLERANCE_NM = 1e-6

MAX_TABLE_MAGNITUDE = 1e100
"""The largest magnitude a value read from a user's spectral table or spectrometer export may have:
no spectral quantity comes near it in any unit, and beyond it the fits' sums of squares overflow."""

MIN_TABLE_PEAK = 1e-100
"""The smallest largest-magnitude a value column of a user's table may have, unless it is all zero.

With :data:`MAX_TABLE_MAGNITUDE`, it keeps the products of two tables (an LED's spectrum times a
camera's responsivity, counts divided by a spectrometer's response) and their squares normal
floats (``docs/decisions/docstring-history.md``)."""


def tiny_columns(values: np.ndarray) -> list[int]:
    """Indices of the columns of ``values`` (n, k) whose largest magnitude is above 0 but below
    :data:`MIN_TABLE_PEAK` (a table scaled by mistake, or in a unit far from any spectral one).

    >>> tiny_columns(np.array([[0.0, 1e-300, 1.0], [0.0, 0.0, 2.0]]))
    [1]
    """
    peaks = np.max(np.abs(np.asarray(values, dtype=float).reshape(len(values), -1)), axis=0)
    return [int(i) for i in np.flatnonzero((peaks > 0) & (peaks < MIN_TABLE_PEAK))]


@dataclass(frozen=True)
class WavelengthGrid:
    """A uniform wavelength grid, ``start_nm, start_nm + step_nm, …, stop_nm`` inclusive.

    Examples
    --------
    >>> WavelengthGrid(400, 700, 10).size
    31
    """

    start_nm: float
    stop_nm: float
    """Last wavelength (inclusive)."""
    step_nm: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.start_nm) and np.isfinite(self.stop_nm) and np.isfinite(self.step_nm)):
            raise SpectralDataError(f"wavelength grid {self}: values must be finite")
        if self.step_nm <= 0:
            raise SpectralDataError(f"wavelength grid: step_nm is {self.step_nm}; expected > 0")
        if self.stop_nm < self.start_nm:
            raise SpectralDataError(f"wavelength grid: stop_nm {self.stop_nm} is below start_nm {self.start_nm}")
        count = (self.stop_nm - self.start_nm) / self.step_nm
        if abs(count - round(count)) > 1e-6:
            raise SpectralDataError(
                f"wavelength grid {self.start_nm}–{self.stop_nm} nm: step {self.step_nm} nm does "
                "not divide the range; expected a whole number of steps"
            )

    @property
    def size(self) -> int:
        """Number of wavelengths."""
        return int(round((self.stop_nm - self.start_nm) / self.step_nm)) + 1

    @property
    def wavelengths_nm(self) -> np.ndarray:
        """The wavelengths, shape (n_wavelengths,)."""
        return self.start_nm + self.step_nm * np.arange(self.size, dtype=float)

    def __str__(self) -> str:
        return f"{self.start_nm:g}–{self.stop_nm:g} nm step {self.step_nm:g} nm"

    @classmethod
    def from_wavelengths(
        cls, wavelengths_nm: Sequence[float] | np.ndarray, where: str = "wavelengths"
    ) -> WavelengthGrid:
        """The grid of a list of wavelengths, which must be uniform and increasing.

        ``where`` names the source in error messages (a file and field).

        Raises
        ------
        SpectralDataError
            If the list is empty, not increasing, not uniform or not finite.

        Examples
        --------
        >>> WavelengthGrid.from_wavelengths([400, 410, 420])
        WavelengthGrid(start_nm=400.0, stop_nm=420.0, step_nm=10.0)
        """
        try:
            values = np.asarray(wavelengths_nm, dtype=float)
        except (TypeError, ValueError) as err:
            raise SpectralDataError(f"{where}: expected a list of numbers ({err})") from err
        if values.ndim != 1 or values.size < 2:
            raise SpectralDataError(f"{where}: expected at least two wavelengths, got shape {values.shape}")
        if not np.all(np.isfinite(values)):
            raise SpectralDataError(f"{where}: wavelengths must be finite numbers")
        steps = np.diff(values)
        if np.any(steps <= 0):
            raise SpectralDataError(f"{where}: wavelengths must increase strictly")
        step = float(np.mean(steps))
        if np.max(np.abs(steps - step)) > max(_GRID_TOLERANCE_NM, 1e-6 * step):
            raise SpectralDataError(
                f"{where}: wavelengths are not uniformly spaced (steps {steps.min():g}…{steps.max():g} nm); "
                "expected a uniform grid"
            )
        return cls(float(values[0]), float(values[-1]), step)

    def same_as(self, other: WavelengthGrid) -> bool:
        """Whether two grids sample the same wavelengths."""
        return (
            self.size == other.size
            and abs(self.start_nm - other.start_nm) <= _GRID_TOLERANCE_NM
            and abs(self.step_nm - other.step_nm) <= _GRID_TOLERANCE_NM
        )


DEFAULT_GRID = WavelengthGrid(400.0, 700.0, 10.0)
"""The processing grid of msflash and of the paper's simulations."""


def energy_to_photons(values: np.ndarray, wavelengths_nm: np.ndarray, kind: SpectralKind = "spd") -> np.ndarray:
    """Convert spectra (n_wavelengths,) or (n_wavelengths, n) from energy to (relative) photon units.

    ``kind="spd"`` multiplies by ``λ/λ_ref``; ``"responsivity"`` divides by it, so that a camera
    response ``responsivityᵀ · spd`` is unchanged.

    Examples
    --------
    >>> energy_to_photons(np.array([1.0, 1.0]), np.array([555.0, 1110.0])).tolist()
    [1.0, 2.0]
    """
    factor = np.asarray(wavelengths_nm, dtype=float) / PHOTON_REFERENCE_NM
    factor = factor if kind == "spd" else 1.0 / factor
    values = np.asarray(values, dtype=float)
    return values * (factor[:, None] if values.ndim == 2 else factor)


def photons_to_energy(values: np.ndarray, wavelengths_nm: np.ndarray, kind: SpectralKind = "spd") -> np.ndarray:
    """Convert spectral values from (relative) photon units to energy; inverse of :func:`energy_to_photons`."""
    inverse_kind: SpectralKind = "responsivity" if kind == "spd" else "spd"
    return energy_to_photons(values, wavelengths_nm, inverse_kind)


@dataclass(frozen=True)
class Spectra:
    """A set of spectra sampled on one wavelength grid.

    ``values`` is made read-only on construction, so a frozen ``Spectra`` really is frozen.
    """

    grid: WavelengthGrid
    values: np.ndarray
    """The spectra, shape (n_wavelengths, n), one column per spectrum."""
    names: tuple[str, ...]
    """One name per column."""
    kind: SpectralKind = "spd"
    """What the spectra are: power distributions, camera responsivities or reflectances."""
    unit: SpectralUnit = "energy"
    """``"energy"`` or ``"photons"`` for power and responsivity, ``"none"`` for reflectance."""
    source: str = ""
    """Where the data came from (a file, a dataset, a computation), for messages and provenance."""
    metadata: dict = field(default_factory=dict, compare=False)
    """Free-form extra information (licence, peak wavelengths…)."""

    def __post_init__(self) -> None:
        where = self.source or "spectra"
        values = np.array(self.values, dtype=float, copy=True)
        if values.ndim == 1:
            values = values[:, None]
        if values.ndim != 2:
            raise SpectralDataError(f"{where}: values have shape {values.shape}; expected (n_wavelengths, n)")
        if values.shape[0] != self.grid.size:
            raise SpectralDataError(
                f"{where}: {values.shape[0]} samples per spectrum but the grid {self.grid} has "
                f"{self.grid.size}; expected one value per wavelength"
            )
        if not np.all(np.isfinite(values)):
            bad = np.argwhere(~np.isfinite(values))[0]
            name = self.names[bad[1]] if len(self.names) > bad[1] else str(bad[1])
            raise SpectralDataError(
                f"{where}: spectrum '{name}' has a non-finite value at "
                f"{self.grid.wavelengths_nm[bad[0]]:g} nm; expected finite numbers"
            )
        names = tuple(str(n) for n in self.names)
        if len(names) != values.shape[1]:
            raise SpectralDataError(f"{where}: {len(names)} names for {values.shape[1]} spectra")
        if self.kind not in ("spd", "responsivity", "reflectance"):
            raise SpectralDataError(f"{where}: kind '{self.kind}'; expected spd, responsivity or reflectance")
        expected_units = ("none",) if self.kind == "reflectance" else ("energy", "photons")
        if self.unit not in expected_units:
            raise SpectralDataError(
                f"{where}: unit '{self.unit}' for kind '{self.kind}'; expected one of {', '.join(expected_units)}"
            )
        values.flags.writeable = False
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "names", names)

    # -- basic accessors --------------------------------------------------------------------
    @property
    def count(self) -> int:
        """Number of spectra (columns)."""
        return self.values.shape[1]

    @property
    def wavelengths_nm(self) -> np.ndarray:
        """The grid's wavelengths, shape (n_wavelengths,)."""
        return self.grid.wavelengths_nm

    def column(self, name: str) -> np.ndarray:
        """One spectrum by name, shape (n_wavelengths,)."""
        try:
            return self.values[:, self.names.index(name)]
        except ValueError:
            raise SpectralDataError(
                f"{self.source or 'spectra'}: no spectrum named '{name}'; available: {', '.join(self.names)}"
            ) from None

    def select(self, which: Sequence[int] | Sequence[str]) -> Spectra:
        """A subset of the spectra, by index or by name, in the order given."""
        indices = [self.names.index(w) if isinstance(w, str) else int(w) for w in which]
        return self.replace(values=self.values[:, indices], names=tuple(self.names[i] for i in indices))

    def replace(self, **changes: Any) -> Spectra:
        """A copy with some fields changed, re-validated; its ``metadata`` a copy unless given."""
        return replace(self, **{"metadata": dict(self.metadata), **changes})

    @classmethod
    def from_samples(
        cls,
        wavelengths_nm: Sequence[float] | np.ndarray,
        values: np.ndarray,
        names: Sequence[str],
        kind: SpectralKind = "spd",
        unit: SpectralUnit = "energy",
        source: str = "",
    ) -> Spectra:
        """Spectra from samples on any increasing wavelengths (an instrument's own grid).

        Uniform samples are kept as they are. Non-uniform ones (spectrometers sample unevenly)
        become box-car means over 1-nm bins (finer if every sample step is much finer): the
        running integral of the piecewise-linear curve through the samples, differenced at the
        bin edges — what a coarser spectral sample means. This and :meth:`resample` are the only
        places where msflash changes the sampling of a spectrum. ``values`` is (n_samples,) or
        (n_samples, n).

        Examples
        --------
        >>> s = Spectra.from_samples([400.0, 400.5, 402.0], [1.0, 1.0, 1.0], ("flat",))
        >>> s.grid.step_nm, s.values[:, 0].tolist()
        (1.0, [1.0, 1.0, 1.0])
        """
        where = source or "samples"
        wavelengths = np.asarray(wavelengths_nm, dtype=float)
        data = np.asarray(values, dtype=float)
        data = data[:, None] if data.ndim == 1 else data
        if wavelengths.ndim != 1 or wavelengths.size < 2 or data.shape[0] != wavelengths.size:
            raise SpectralDataError(
                f"{where}: {wavelengths.size} wavelengths for values of shape {data.shape}; expected one row per wavelength"
            )
        steps = np.diff(wavelengths)
        if not np.all(np.isfinite(wavelengths)) or np.any(steps <= 0):
            raise SpectralDataError(f"{where}: wavelengths must be finite and increase strictly")
        step = float(np.mean(steps))
        if np.max(np.abs(steps - step)) <= max(_GRID_TOLERANCE_NM, 1e-6 * step):
            grid = WavelengthGrid(float(wavelengths[0]), float(wavelengths[0]) + step * (wavelengths.size - 1), step)
            return cls(grid, data, tuple(names), kind, unit, source)
        coarsest = float(np.max(steps))
        bin_nm = 1.0 / min(10, int(np.floor(1.0 / coarsest))) if coarsest < 0.5 else 1.0
        start = float(np.ceil(wavelengths[0] / bin_nm) * bin_nm)
        stop = float(np.floor(wavelengths[-1] / bin_nm) * bin_nm)
        grid = WavelengthGrid(start, stop, bin_nm)
        centres = grid.wavelengths_nm
        edges = np.clip(
            np.concatenate([[centres[0] - bin_nm / 2], centres + bin_nm / 2]), wavelengths[0], wavelengths[-1]
        )
        binned = np.empty((grid.size, data.shape[1]))
        for column in range(data.shape[1]):
            running = np.concatenate([[0.0], np.cumsum(steps * (data[1:, column] + data[:-1, column]) / 2)])
            binned[:, column] = np.diff(np.interp(edges, wavelengths, running)) / np.diff(edges)
        return cls(grid, binned, tuple(names), kind, unit, source)

    # -- units and normalisation ------------------------------------------------------------
    def to_unit(self, unit: SpectralUnit) -> Spectra:
        """The same spectra in another unit (see the module notes); reflectances are unchanged."""
        if self.kind == "reflectance" or unit == self.unit:
            return self
        if unit not in ("energy", "photons"):
            raise SpectralDataError(f"{self.source or 'spectra'}: cannot convert to unit '{unit}'")
        convert = energy_to_photons if unit == "photons" else photons_to_energy
        return self.replace(values=convert(self.values, self.wavelengths_nm, self.kind), unit=unit)

    def normalised(self, how: Literal["max", "each_max"] = "max") -> Spectra:
        """Scaled so the largest value of all spectra (``"max"``) or of each (``"each_max"``) is 1."""
        values = self.values
        peak = np.max(np.abs(values), axis=0 if how == "each_max" else None)
        peak = np.where(peak > 0, peak, 1.0)
        return self.replace(values=values / peak)

    # -- the one resampler -----------------------------------------------------------------
    def resample(self, grid: WavelengthGrid, outside: Literal["error", "zero", "edge"] = "error") -> Spectra:
        """The spectra on another grid, by linear interpolation; the only resampler in msflash.

        Target wavelengths outside the source range: ``outside="error"`` raises, ``"zero"`` fills
        with zeros (right for emission spectra measured beyond their support), ``"edge"`` repeats
        the end values.

        Raises
        ------
        SpectralDataError
            If ``outside="error"`` and the target grid extends beyond the source grid.

        Examples
        --------
        >>> s = Spectra(WavelengthGrid(400, 700, 100), [0.0, 1.0, 2.0, 3.0], ("ramp",))
        >>> s.resample(WavelengthGrid(400, 700, 50)).values[:, 0].tolist()
        [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
        """
        if grid.same_as(self.grid):
            return self
        source_nm = self.wavelengths_nm
        target_nm = grid.wavelengths_nm
        beyond = (target_nm < source_nm[0] - _GRID_TOLERANCE_NM) | (target_nm > source_nm[-1] + _GRID_TOLERANCE_NM)
        if np.any(beyond) and outside == "error":
            raise SpectralDataError(
                f"{self.source or 'spectra'}: cannot resample from {self.grid} to {grid} without "
                "extrapolating; expected a target grid inside the measured range (or outside='zero')"
            )
        values = np.empty((grid.size, self.count))
        for column in range(self.count):
            values[:, column] = np.interp(target_nm, source_nm, self.values[:, column])
        if outside == "zero":
            values[beyond, :] = 0.0
        return self.replace(grid=grid, values=values)


def require_same_grid(*spectra: Spectra) -> WavelengthGrid:
    """Check that spectra share one grid and return it.

    Raises
    ------
    SpectralDataError
        Naming both sources and both grids, on the first mismatch.
    """
    first = spectra[0]
    for other in spectra[1:]:
        if not other.grid.same_as(first.grid):
            raise SpectralDataError(
                f"{first.source or 'spectra'} is sampled on {first.grid} but {other.source or 'spectra'} on "
                f"{other.grid}; expected one grid (resample with Spectra.resample first)"
            )
    return first.grid


def require_unit(spectra: Spectra, unit: SpectralUnit) -> Spectra:
    """Check that power/responsivity spectra are in ``unit``; reflectances pass unchanged."""
    if spectra.kind != "reflectance" and spectra.unit != unit:
        raise SpectralDataError(
            f"{spectra.source or 'spectra'}: in unit '{spectra.unit}'; expected '{unit}' (convert with to_unit)"
        )
    return spectra
