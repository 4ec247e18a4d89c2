"""Flash spectra: matching (eq. 7) and complementary (eq. 8–9) LED mixes.

Both modes compare illuminants through the camera: ``A = Cᵀ I`` (3 × k) maps LED weights to
the camera response of a white surface. ``A`` has rank ≤ 3 while k is usually larger, so many
mixes look the same to the camera; every mode therefore breaks ties explicitly, by adding to the
objective small terms that only choose among (near-)optimal solutions:

- **matching** prefers the mix whose *spectrum* is closest to the ambient's (so the match holds
  for every surface and observer, not only for the camera on white), then rescales to
  ``max(w_f) = 1`` (most light, same colour cast);
- **complementary** prefers the least total LED power ``Σ w_f`` (less heat, less glare, least
  noise added).

The tie-break weights are :data:`TIE_BREAK` and :data:`TIE_BREAK_CHANGE` relative to the problem's scale: far below any visible
change in the objective, far above round-off.

Bounds (``bounds=``): ``"physical"`` is ``0 ≤ w_f ≤ 1`` (the LEDs' drive range, for a
re-capture); ``"nonnegative"`` drops the upper bound (the computational mode of the paper: the
image is synthesised, so the flash images can be scaled up, at the price of noise);
``"free"`` drops both (negative weights subtract LED images; the complementary scale ``s`` is
then fixed to the non-negative solution's, otherwise ``s = 0, w_f = −w_a`` would trivially win).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Literal

import numpy as np

from msflash.processing.errors import SolverError, SpectralDataError, TargetUnreachableWarning
from msflash.processing.least_squares import FactoredQuadratic, minimise_quadratic
from msflash.processing.spectra import Spectra, require_same_grid, require_unit

FlashBounds = Literal["physical", "nonnegative", "free"]

TIE_BREAK = 1e-6
"""Relative weight of the first tie-break (spectral closeness; least total power)."""
TIE_BREAK_CHANGE = 1e-8
"""Relative weight of the ridge that keeps the rank-3 camera problems strictly convex."""
UNREACHABLE_RELATIVE_ERROR = 0.02
"""Relative camera-space error ``‖A(w_a + w_f) − s t‖ / ‖s t‖`` above which the target counts as not reached."""
MATCHING_ROUND_OFF = 1e-7
"""Matching weights (goal normalised to ``max |w_a| = 1``) below this are the QP's round-off (its
feasibility tolerance) and become 0 before ``max(w_f) = 1`` rescales them; otherwise an ambient
whose best non-negative match is no light at all (weights ~1e-10 of either sign) would be blown
up into a full-drive mix with negative weights."""


@dataclass(frozen=True)
class FlashSolution:
    """A flash LED mix and how well it does its job."""

    mode: str
    """``matching`` or ``complementary``."""
    ambient_weights: np.ndarray
    """``w_a``, shape (k,)."""
    flash_weights: np.ndarray
    """``w_f``, shape (k,), in LED drive units (1 = full drive at the capture's exposure)."""
    scale: float | None
    """The complementary slack ``s`` of eq. 8–9 (None for matching)."""
    relative_error: float
    """Camera-space error of the result relative to its goal (0 = exact)."""
    bounds: str
    """``physical``, ``nonnegative`` or ``free``."""
    target_reached: bool
    """Whether the relative error is within :data:`UNREACHABLE_RELATIVE_ERROR`."""
    warnings: tuple[str, ...] = field(default=())
    """Human-readable warnings."""


def camera_led_matrix(camera_responsivities: Spectra, led_spectra: Spectra) -> np.ndarray:
    """``A = Cᵀ I``: camera response of a white surface to each LED at full drive, shape (3, k)."""
    require_same_grid(camera_responsivities, led_spectra)
    require_unit(camera_responsivities, "photons")
    require_unit(led_spectra, "photons")
    return camera_responsivities.values.T @ led_spectra.values


def _norm(vector: np.ndarray) -> float:
    """Euclidean norm of a vector, without np.linalg.norm's checks (docs/measurements.md)."""
    return math.sqrt(float(vector.dot(vector)))


@lru_cache(maxsize=64)
def _box(k: int, bounds: str) -> tuple[np.ndarray, np.ndarray]:
    """Constraint rows ``G w ≥ h`` for the flash weights (cached; the arrays are read-only)."""
    constraints, limits = _box_rows(k, bounds)
    constraints.flags.writeable = False
    limits.flags.writeable = False
    return constraints, limits


def _box_rows(k: int, bounds: str) -> tuple[np.ndarray, np.ndarray]:
    if bounds == "physical":
        return np.vstack([np.eye(k), -np.eye(k)]), np.concatenate([np.zeros(k), -np.ones(k)])
    if bounds == "nonnegative":
        return np.eye(k), np.zeros(k)
    if bounds == "free":
        return np.zeros((0, k)), np.zeros(0)
    raise ValueError(f"flash bounds '{bounds}' are unknown; expected physical, nonnegative or free")


@dataclass(frozen=True)
class FlashModel:
    """The flash problem of one LED set and one camera, prepared once and solved per ambient.

    Everything that depends only on the LEDs and the camera (``A = Cᵀ I``, the tie-break
    matrices, the bound constraints) is computed at construction; :meth:`matching` and
    :meth:`complementary` then cost one small quadratic programme each — what a video-rate
    re-solve, or a benchmark against a general-purpose solver, needs.
    """

    led_spectra: Spectra
    """``I`` in photons."""
    camera_responsivities: Spectra
    """``C`` in photons, same grid."""
    matrix: np.ndarray = field(init=False, repr=False)
    """``A = Cᵀ I``, shape (3, k)."""
    _matching_hessian: np.ndarray = field(init=False, repr=False)
    _matching_problems: dict[str, FactoredQuadratic] = field(init=False, repr=False)
    _design: np.ndarray = field(init=False, repr=False)
    _complementary_rows: dict[str, FactoredQuadratic] = field(init=False, repr=False)
    _power_tie_break: np.ndarray = field(init=False, repr=False)
    _full_flash_norm: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        matrix = camera_led_matrix(self.camera_responsivities, self.led_spectra)
        spectra = self.led_spectra.values
        k = matrix.shape[1]
        # Frobenius norms: any consistent scale makes the tie-break weight relative.
        norm = max(float((matrix * matrix).sum()), 1e-300)
        spectral_norm = max(float((spectra * spectra).sum()), 1e-300)
        # ½‖A(g − w)‖² + ½ε‖I(g − w)‖², scaled so the camera term has unit size.
        hessian = (
            matrix.T @ matrix / norm + TIE_BREAK * spectra.T @ spectra / spectral_norm + TIE_BREAK_CHANGE * np.eye(k)
        )
        object.__setattr__(self, "matrix", matrix)
        object.__setattr__(self, "_matching_hessian", hessian)
        # The matching problem's Hessian and bound rows depend on the LEDs and camera alone: factor
        # them once per bound set, so a solve pays only for its ambient-dependent linear term.
        object.__setattr__(
            self,
            "_matching_problems",
            {
                name: FactoredQuadratic.prepare(hessian, *_box(k, name), where="matching flash")
                for name in ("physical", "nonnegative", "free")
            },
        )
        object.__setattr__(self, "_full_flash_norm", _norm(matrix.sum(axis=1)))
        # Complementary: [A, ·] (the last column is the target's, set per solve) and the least-power
        # tie-break on [w_f, s] — per-solve work is then only what depends on the ambient.
        design = np.zeros((matrix.shape[0], k + 1))
        design[:, :k] = matrix
        power = np.zeros(k + 1)
        power[:k] = TIE_BREAK
        for name, value in (("_design", design), ("_power_tie_break", power)):
            value.flags.writeable = False
            object.__setattr__(self, name, value)
        # Its bound rows on [w_f, s] (and their tolerances) are fixed too; only H changes per solve.
        object.__setattr__(
            self,
            "_complementary_rows",
            {
                name: FactoredQuadratic.prepare(np.eye(k + 1), *_with_scale(k, name), where="complementary flash")
                for name in ("physical", "nonnegative")
            },
        )

    @property
    def n_leds(self) -> int:
        """Number of LEDs k."""
        return self.matrix.shape[1]

    def target_response(self, target: Spectra) -> np.ndarray:
        """``Cᵀ i_d``: the camera's response to a white surface under the target, shape (3,)."""
        require_same_grid(self.led_spectra, target)
        require_unit(target, "photons")
        if target.count != 1:
            raise SpectralDataError(
                f"{target.source or 'target'}: {target.count} spectra; expected one target illuminant"
            )
        response = self.camera_responsivities.values.T @ target.values[:, 0]
        if _norm(response) == 0:
            raise SpectralDataError(f"{target.source or 'target'}: the camera sees nothing of the target illuminant")
        return response

    def matching(self, ambient_weights: np.ndarray, bounds: FlashBounds = "physical") -> FlashSolution:
        """Matching flash, eq. 7 (see :func:`solve_matching`)."""
        ambient_weights = np.asarray(ambient_weights, dtype=float)
        _check_count(ambient_weights, self.matrix, self.led_spectra)
        peak = float(abs(ambient_weights).max())
        if peak == 0:
            raise SolverError("matching flash: the ambient weights are all zero; expected an estimated ambient")
        goal = ambient_weights / peak
        if bounds not in self._matching_problems:
            _box_rows(self.n_leds, bounds)  # raises the unknown-bounds error
        weights = self._matching_problems[bounds].minimise(self._matching_hessian @ goal).x
        weights[abs(weights) < MATCHING_ROUND_OFF] = 0.0
        top = float(weights.max())
        if top <= 0:
            raise SolverError(
                "matching flash: no non-negative LED mix matches the ambient's colour; "
                "expected an ambient inside the LEDs' gamut"
            )
        weights = weights / top
        relative_error = _chromatic_error(self.matrix @ weights, self.matrix @ goal)
        return _finish("matching", ambient_weights, weights, None, relative_error, bounds)

    def complementary(
        self,
        ambient_weights: np.ndarray,
        target: Spectra | np.ndarray,
        bounds: FlashBounds = "physical",
    ) -> FlashSolution:
        """Complementary flash, eq. 8–9 (see :func:`solve_complementary`); ``target`` may be ``Cᵀ i_d``."""
        ambient_weights = np.asarray(ambient_weights, dtype=float)
        _check_count(ambient_weights, self.matrix, self.led_spectra)
        target_response = (
            self.target_response(target) if isinstance(target, Spectra) else np.asarray(target, dtype=float)
        )
        matrix, k = self.matrix, self.n_leds
        ambient_response = matrix.dot(ambient_weights)
        target_norm = _norm(target_response)
        # Normalise so the ambient (or, with no ambient, the full flash) has unit camera response and
        # the target's response unit norm: the tie-break weights are then relative.
        unit = max(_norm(ambient_response), self._full_flash_norm * 1e-3, 1e-300)
        t_vector = target_response / target_norm

        def solve(weight_bounds: str, fixed_scale: float | None) -> tuple[np.ndarray, float]:
            if fixed_scale is None:
                # Variables x = [w_f, s]; residual A w_f − s t + A w_a (A/unit in the first k columns).
                design = self._design / unit
                np.negative(t_vector, out=design[:, k])
                hessian = design.T.dot(design)
                hessian += _ridge(k + 1)
                linear = design.T.dot(ambient_response / -unit)  # −(a/u) and a/(−u): the same bits
                if weight_bounds != "free":
                    linear -= self._power_tie_break  # least total power first
                x = self._complementary_rows[weight_bounds].with_hessian(hessian).minimise(linear).x
                return x[:k], float(x[k])
            constraints, limits = _box(k, weight_bounds)
            a_matrix = matrix / unit
            hessian = a_matrix.T @ a_matrix
            hessian += _ridge(k)
            linear = a_matrix.T @ (fixed_scale * t_vector - ambient_response / unit)
            x = minimise_quadratic(hessian, linear, constraints, limits, where="complementary flash").x
            return x, fixed_scale

        if bounds == "free":
            _, scale_unit = solve("nonnegative", None)
            weights, scale_unit = solve("free", scale_unit)
        else:
            weights, scale_unit = solve(bounds, None)
        # Round-off below 10⁻¹⁰ becomes 0 and the result is clipped to the bounds. With a lower
        # bound of 0 both are one step: every weight below 10⁻¹⁰ (tiny or negative) becomes +0.
        # (np.minimum: np.clip's argument handling costs more than the clipping here.)
        if bounds == "physical":
            weights = np.minimum(weights, 1.0)
        if bounds == "free":
            weights[abs(weights) < 1e-10] = 0.0
        else:
            weights[weights < 1e-10] = 0.0
        scale = scale_unit * unit / target_norm
        relative_error = _error_to_unit(matrix.dot(ambient_weights + weights), t_vector) if scale > 0 else 1.0
        return _finish("complementary", ambient_weights, weights, float(scale), relative_error, bounds)


@lru_cache(maxsize=64)
def _ridge(n: int) -> np.ndarray:
    """``TIE_BREAK_CHANGE · I`` (n × n, cached, read-only): the ridge added to the flash Hessians."""
    ridge = TIE_BREAK_CHANGE * np.eye(n)
    ridge.flags.writeable = False
    return ridge


@lru_cache(maxsize=64)
def _with_scale(k: int, bounds: str) -> tuple[np.ndarray, np.ndarray]:
    """The bound rows on ``[w_f, s]``: the weights' bounds plus ``s ≥ 0`` (cached, read-only)."""
    constraints, limits = _box(k, bounds)
    full_constraints = np.zeros((constraints.shape[0] + 1, k + 1))
    full_constraints[:-1, :k] = constraints
    full_constraints[-1, k] = 1.0
    full_limits = np.concatenate([limits, [0.0]])
    full_constraints.flags.writeable = False
    full_limits.flags.writeable = False
    return full_constraints, full_limits


def solve_matching(
    ambient_weights: np.ndarray,
    led_spectra: Spectra,
    camera_responsivities: Spectra,
    bounds: FlashBounds = "physical",
) -> FlashSolution:
    """Matching flash, eq. 7: ``min ‖Cᵀ I (w_a − w_f)‖`` subject to the bounds, then ``max(w_f) = 1``.

    When ``w_a ≥ 0`` the answer is ``w_a / max(w_a)`` (the spectral tie-break makes it exact);
    otherwise the closest non-negative mix in camera space, preferring spectral closeness.

    Examples
    --------
    >>> from msflash.processing.spectra import WavelengthGrid
    >>> g = WavelengthGrid(400, 700, 100)
    >>> leds = Spectra(g, np.eye(4), ("a", "b", "c", "d"), unit="photons")
    >>> cam = Spectra(g, np.ones((4, 3)), ("R", "G", "B"), kind="responsivity", unit="photons")
    >>> np.round(solve_matching(np.array([0.5, 1.0, 0.25, 0.0]), leds, cam).flash_weights, 6).tolist()
    [0.5, 1.0, 0.25, 0.0]
    """
    return FlashModel(led_spectra, camera_responsivities).matching(ambient_weights, bounds)


def solve_complementary(
    ambient_weights: np.ndarray,
    led_spectra: Spectra,
    camera_responsivities: Spectra,
    target: Spectra,
    bounds: FlashBounds = "physical",
) -> FlashSolution:
    """Complementary flash, eq. 8–9: ``min ‖Cᵀ I (w_a + w_f) − s Cᵀ i_d‖`` over ``w_f`` and ``s ≥ 0``.

    Parameters
    ----------
    ambient_weights
        ``w_a`` from the ambient estimate.
    led_spectra, camera_responsivities
        ``I`` and ``C`` in photons on one grid.
    target
        The desired illuminant ``i_d`` (one spectrum, photons, same grid); D65 in the paper.
    bounds
        ``physical`` (0 ≤ w_f ≤ 1), ``nonnegative`` or ``free`` (see the module notes).

    Warns
    -----
    TargetUnreachableWarning
        When ambient + flash cannot be brought to the target's colour within the bounds.
    """
    return FlashModel(led_spectra, camera_responsivities).complementary(ambient_weights, target, bounds)


def _chromatic_error(response: np.ndarray, wanted: np.ndarray) -> float:
    """Scale-free camera-space error: ``‖r/‖r‖ − t/‖t‖‖`` (0 when the colours agree)."""
    wanted_norm = _norm(wanted)
    return _error_to_unit(response, wanted / wanted_norm) if wanted_norm != 0 else 1.0


def _error_to_unit(response: np.ndarray, unit_wanted: np.ndarray) -> float:
    """``‖r/‖r‖ − t̂‖`` for an already normalised ``t̂`` (1 when ``r = 0``)."""
    response_norm = _norm(response)
    return _norm(response / response_norm - unit_wanted) if response_norm != 0 else 1.0


def _check_count(ambient_weights: np.ndarray, matrix: np.ndarray, led_spectra: Spectra) -> None:
    if ambient_weights.ndim != 1 or ambient_weights.size != matrix.shape[1]:
        raise SpectralDataError(
            f"flash: {ambient_weights.size} ambient weights for {matrix.shape[1]} LEDs in "
            f"{led_spectra.source or 'the LED spectra'}; expected one weight per LED"
        )
    # One sum tells finite weights apart; the exact check runs only if it is not finite (overflow).
    if not math.isfinite(np.add.reduce(ambient_weights)) and not np.isfinite(ambient_weights).all():
        raise SpectralDataError("flash: the ambient weights are not finite; expected numbers")


def _finish(
    mode: str, ambient_weights: np.ndarray, weights: np.ndarray, scale: float | None, relative_error: float, bounds: str
) -> FlashSolution:
    reached = relative_error <= UNREACHABLE_RELATIVE_ERROR
    notes: list[str] = []
    if not reached:
        goal = "the ambient's colour" if mode == "matching" else "the target illuminant"
        message = (
            f"{mode} flash: the LEDs cannot reach {goal} within the {bounds} bounds "
            f"(camera-space chromatic error {relative_error:.3f}); the closest mix is returned"
        )
        notes.append(message)
        warnings.warn(message, TargetUnreachableWarning, stacklevel=3)
    return FlashSolution(
        mode=mode,
        ambient_weights=ambient_weights,
        flash_weights=weights,
        scale=scale,
        relative_error=relative_error,
        bounds=bounds,
        target_reached=reached,
        warnings=tuple(notes),
    )


FLASH_MODES = {"matching": solve_matching, "complementary": solve_complementary}
"""Flash solvers by mode name."""
