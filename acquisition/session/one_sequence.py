"""What ``msflash estimate`` and ``msflash flash`` compute for one recorded sequence (docs/architecture.md §5.2).

The one route from a sequence folder to the command's JSON object: read, calibrate, estimate (global,
local or with the light prior, eq. 4–6), refuse a dark ambient, solve the flash (eq. 7–9) and write
its computational image. The command line prints what these return, for one sequence
(:mod:`acquisition.app.cli_process`) or for many (:mod:`acquisition.session.many`), so both give
the same numbers. Notes meant for stderr go to a ``report`` callable as they arise.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.errors import UsageError
from msflash.acquisition.sequence.exr_metadata import exr_image
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.image_files import read_image_header, write_image
from msflash.acquisition.sequence.locate import locate_sequence
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import analysis, local_route, sequence_spectra
from msflash.processing.ambient import LED_SIGNAL_Z, AmbientEstimate
from msflash.processing.errors import TargetUnreachableWarning
from msflash.processing.flash import FlashBounds, FlashSolution
from msflash.processing.local import LocalEstimate
from msflash.processing.names import unknown_name
from msflash.processing.spectra import Spectra
from msflash.processing.synthesis import to_raw_values
from msflash.processing.tile_statistics import DEFAULT_TILES

Report = Callable[[str], None]
"""Where a note for stderr goes (``progress`` for one sequence; a list's ``append`` on a dask worker)."""


@dataclass(frozen=True)
class EstimateSettings:
    """The options of ``msflash estimate`` that shape the result (docs/architecture.md §7)."""

    solver: str = "tikhonov"
    alpha: float | str = "auto"
    bin_factor: int = analysis.DEFAULT_BIN_FACTOR
    method: str = "auto"
    tiles: int = DEFAULT_TILES
    model: str = "led"
    calibration: str | None = None
    reference_patch: tuple[int, int, int, int] | None = None
    """``--reference-patch``: a spectrally flat region (x, y, width, height) for ``--model prior|family|auto``."""
    reference_chart: str | None = None
    """``--reference-chart``: a JSON file of patches of known reflectance, for ``--model prior|family|auto``."""


@dataclass(frozen=True)
class FlashSettings:
    """The options of ``msflash flash``: the estimate's, the flash's (eq. 7–9) and the image to write."""

    estimate: EstimateSettings
    mode: str
    target: str = "D65"
    bounds: FlashBounds = "physical"
    out: str | None = None


@dataclass(frozen=True)
class EstimateResult:
    """One sequence's estimate: the ``--json`` object and what the text output reads.

    Exactly one of ``estimate`` (global LED model), ``local`` (``--method local|auto``) and
    ``choice`` (``--model prior|auto``: the chosen model and why) is set.
    """

    sequence: Sequence
    payload: dict[str, Any]
    estimate: AmbientEstimate | None = None
    local: LocalEstimate | None = None
    choice: tuple[str, str] | None = None


@dataclass(frozen=True)
class SequenceEstimate:
    """``msflash estimate SEQ --json`` as an object: the Python API's estimate (:func:`msflash.estimate_ambient`).

    Its fields are the JSON object's, in the same unit and to the last digit: the spectrum and band are in
    the sequence's spectral unit (``spectral_unit``, usually energy) on its grid — not processing's photons.
    """

    spectrum: Spectra
    """The estimated ambient spectrum (the JSON's ``spectrum``), one column, the sequence's unit and grid."""
    spectrum_std: np.ndarray
    """±1σ per wavelength, in the same unit (the JSON's ``spectrum_std``; :attr:`band_meaning` says what it covers)."""
    ambient_weights: np.ndarray
    """``w_a``, one weight per LED (the JSON's ``ambient_weights``)."""
    warnings: tuple[str, ...]
    """Reliability warnings, as the command prints them."""
    band_meaning: str
    """What the band covers, in words (the JSON's ``band``)."""
    payload: dict[str, Any]
    """The whole ``--json`` object (model choice, tiles, solver, α, residuals …)."""
    result: EstimateResult
    """The route's own objects (the processing estimate in photons, a local estimate, the model choice)."""

    @classmethod
    def of(cls, result: EstimateResult) -> SequenceEstimate:
        """The estimate of ``result``'s payload."""
        sequence, payload = result.sequence, result.payload
        spectrum = Spectra(
            sequence.grid,
            np.asarray(payload["spectrum"], dtype=float)[:, None],
            ("ambient",),
            kind="spd",
            unit=sequence.spectral_unit,
            source=f"ambient estimate of {sequence.directory}",
        )
        return cls(
            spectrum=spectrum,
            spectrum_std=np.asarray(payload["spectrum_std"], dtype=float),
            ambient_weights=np.asarray(payload["ambient_weights"], dtype=float),
            warnings=tuple(payload.get("warnings", ())),
            band_meaning=str(payload.get("band", "")),
            payload=payload,
            result=result,
        )


@dataclass(frozen=True)
class FlashResult:
    """One sequence's flash: the ``--json`` object, the solution and, on the local route, the local estimate."""

    sequence: Sequence
    payload: dict[str, Any]
    solution: FlashSolution
    local: LocalEstimate | None = None


def read_calibrated(path: str, calibration: str | None, report: Report) -> Sequence:
    """The sequence, with a calibration applied (``calibration`` or the sequence's reference); notes reported."""
    sequence, notes = sequence_spectra.apply_calibration(read_sequence(locate_sequence(path)), calibration)
    for note in notes:
        report(note)
    return sequence


FLASH_GOAL = {"matching": "match", "complementary": "complement"}
"""What each flash mode does to the ambient (for the dark-ambient refusal)."""


def refuse_dark_ambient(sequence: Sequence, estimate: AmbientEstimate, what: str) -> None:
    """A UsageError naming the ambient frame when it holds no light: there is no ambient to ``what``.

    The estimate is then noise (or zero): estimate would plot it normalised to full height, matching
    would rescale it to a full-drive mix, and complementary (scale-free, least power) returns a
    flash of ~1e-6 drive that "reaches" the target on the noise.
    """
    if not estimate.ambient_is_dark:
        return
    index = sequence.indices("ambient")[0]
    raise UsageError(
        f"{sequence.path}: frames[{index}].file '{sequence.frames[index].file}': the ambient image holds no light "
        f"(z-score {estimate.ambient_z:.2g} < {LED_SIGNAL_Z:g}: no signal above the black level "
        f"{sequence.camera.black_level:g}); expected an ambient illuminant to {what} — was the light off, the lens "
        "capped or the exposure far too short?"
    )


def estimate_one(path: str, settings: EstimateSettings, report: Report) -> EstimateResult:
    """``msflash estimate`` of the sequence at ``path``: eq. 4–6 by the route ``settings`` choose.

    Raises
    ------
    UsageError
        The ambient frame holds no light; the reader's and calibration's own errors pass through.
    """
    return estimate_read(read_calibrated(path, settings.calibration, report), settings, report)


def estimate_read(sequence: Sequence, settings: EstimateSettings, report: Report) -> EstimateResult:
    """:func:`estimate_one` of a sequence already read (and calibrated): what ``msflash estimate`` prints for it,
    and what :func:`msflash.estimate_ambient` returns (:class:`SequenceEstimate`). ``settings.calibration`` is
    not applied here. The route is :data:`ESTIMATE_METHODS`'s entry for :func:`method_of` the settings."""
    check_settings(settings)
    if sequence.partial:
        _check_every_led_captured(sequence)
        report(f"{sequence.path}: the sequence is incomplete (complete: false); estimating from the frames present")
    reference = settings.reference_chart if settings.reference_chart is not None else settings.reference_patch
    if settings.reference_patch is not None and settings.reference_chart is not None:
        raise UsageError(
            "--reference-patch and --reference-chart: expected one of them (a chart may hold the grey card)"
        )
    if reference is not None and settings.model == "led":
        option = "--reference-chart" if settings.reference_chart is not None else "--reference-patch"
        raise UsageError(f"{option}: expected --model prior, family or auto (the LEDs' span needs no reference)")
    return ESTIMATE_METHODS[validate_method(method_of(settings))](sequence, settings, report)


def _check_every_led_captured(sequence: Sequence) -> None:
    """Refuse an interrupted sequence that holds no ambient frame or no frame lighting some LED, naming what is
    missing (the solve's own refusal would speak of the levels' rank, not of the frames the capture never took).

    Raises
    ------
    UsageError
        Naming the sequence and the frames it lacks.
    """
    lit = np.zeros(len(sequence.leds), dtype=bool)
    for index in sequence.indices("led"):
        lit |= np.asarray(sequence.frames[index].led_levels) > 0
    names = [led.name for led, on in zip(sequence.leds, lit, strict=True) if not on]
    missing = [] if sequence.indices("ambient") else ["the ambient (LEDs off)"]
    if names:
        missing.append(("LED " if len(names) == 1 else "LEDs ") + ", ".join(names))
    if missing:
        raise UsageError(
            f"{sequence.path}: the sequence is incomplete (complete: false) and holds no frame of "
            f"{' nor of '.join(missing)} (the capture stopped before them); expected an ambient frame and a frame "
            "lighting each LED: capture the sequence again"
        )


@dataclass(frozen=True)
class SettingRule:
    """One estimate setting's rule: the values it takes and, in words, what is expected. The command line's type
    (:mod:`acquisition.app.options`, argparse naming the option) and the Python API's :func:`check_settings` (naming
    the parameter and its option) both apply it, so they refuse alike and say so alike."""

    option: str
    expected: str
    accepts: Callable[[object], bool]

    def refusal(self, shown: str) -> str:
        """The message for a refused value, ``shown`` as the caller gave it (``'0'`` typed, ``0`` passed)."""
        return f"{shown}: expected {self.expected}"


def _whole_number(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool) and bool(value >= 1)


def _alpha(value: object) -> bool:
    if value == "auto":
        return True
    return isinstance(value, int | float) and not isinstance(value, bool) and 0 <= value < float("inf")


SETTING_RULES = {
    "alpha": SettingRule("--alpha", "a finite number ≥ 0 or 'auto'", _alpha),
    "bin_factor": SettingRule("--bin", "a whole number ≥ 1", _whole_number),
    "tiles": SettingRule("--tiles", "a whole number ≥ 1", _whole_number),
}
""":class:`EstimateSettings` field → its rule (the names among the settings are checked against their tables:
``model`` :data:`AMBIENT_MODELS`, ``solver`` :data:`processing.ambient.AMBIENT_METHODS`)."""


def check_settings(settings: EstimateSettings) -> None:
    """Refuse settings the command line's own types would have refused (the Python API passes them as given): the
    same rules (:data:`SETTING_RULES`, the tables of names).

    Raises
    ------
    UsageError
        Naming the parameter, its option and what it expects.
    """
    from msflash.processing.ambient import AMBIENT_METHODS

    if settings.model not in AMBIENT_MODELS:  # named as itself, not as the method it would have been looked up as
        raise UsageError(unknown_name("model (--model)", str(settings.model), AMBIENT_MODELS))
    if settings.solver not in AMBIENT_METHODS:
        raise UsageError(unknown_name("solver (--solver)", str(settings.solver), sorted(AMBIENT_METHODS)))
    for name, rule in SETTING_RULES.items():
        value = getattr(settings, name)
        if not rule.accepts(value):
            raise UsageError(f"{name} ({rule.option}) {rule.refusal(repr(value))}")


def _light_models(sequence: Sequence, settings: EstimateSettings, report: Report) -> EstimateResult:
    """``prior``, ``family``, ``models``: the LED span beside the light prior and the physics families (§5.3)."""
    from msflash.acquisition.session.prior_route import led_side, with_model_choice
    from msflash.acquisition.session.reference_crops import ReferenceCrops

    reference = settings.reference_chart if settings.reference_chart is not None else settings.reference_patch
    # The frames streamed from disk one at a time; a reference keeps its rectangles' crops of each as it passes (a
    # chart file read and a rectangle outside the frame refused first, before any frame is decoded).
    crops = None if reference is None else ReferenceCrops.of(sequence, reference)
    led, payload, varies, stream = led_side(
        sequence, None, settings.method, settings.solver, settings.alpha, settings.tiles, settings.bin_factor, crops
    )
    refuse_dark_ambient(sequence, led, "estimate")
    payload, chosen, reason = with_model_choice(
        sequence, None, payload, settings.model, varies, crops, led.flicker, stream
    )
    return _reported(EstimateResult(sequence, payload, choice=(chosen, reason)), led, report)


def _tiled(sequence: Sequence, settings: EstimateSettings, report: Report) -> EstimateResult:
    """``auto`` and ``local``: the whole frame's estimate and the tiles', in one stream of the frames (issue 9)."""
    local = local_route.estimate_sequence_local(
        sequence, settings.method, settings.solver, settings.alpha, settings.tiles, bin_factor=settings.bin_factor
    )
    refuse_dark_ambient(sequence, local.global_estimate, "estimate")
    payload = local_route.local_estimate_payload(sequence, local)
    return _reported(EstimateResult(sequence, payload, local=local), local.global_estimate, report)


def _global(sequence: Sequence, settings: EstimateSettings, report: Report) -> EstimateResult:
    """``global``: the paper's one ambient for the whole frame (eq. 4–6)."""
    estimate = analysis.estimate_sequence(sequence, settings.solver, settings.alpha, bin_factor=settings.bin_factor)
    refuse_dark_ambient(sequence, estimate, "estimate")
    payload = analysis.estimate_payload(sequence, estimate)
    return _reported(EstimateResult(sequence, payload, estimate=estimate), estimate, report)


def _reported(result: EstimateResult, led: AmbientEstimate, report: Report) -> EstimateResult:
    """``result``, once the LED estimate's flicker note (docs/flicker.md) and the payload's warnings are reported."""
    flicker = led.flicker.summary() if led.flicker is not None else None
    if flicker is not None:
        report(flicker)
    for warning in result.payload["warnings"]:
        report(f"warning: {warning}")
    return result


ESTIMATE_METHODS: dict[str, Callable[[Sequence, EstimateSettings, Report], EstimateResult]] = {
    "global": _global,
    "local": _tiled,
    "auto": _tiled,
    "prior": _light_models,
    "family": _light_models,
    "models": _light_models,
}
"""The one method table of an estimate (colour-science's method table and dispatcher): ``global`` (one ambient,
eq. 4–6), ``local`` (tiles), ``auto`` (global or local as the tiles' held-out error says; the default), the
light models ``prior`` and ``family`` (beyond the LEDs' span, §5.3) and ``models`` (``--model auto``: the LED
span unless a light model predicts held-out folds 10 % better). Every route streams the frames into the one
accumulator (:mod:`acquisition.session.estimate_stream`) for the LED span's estimate."""

LIGHT_MODELS = {"prior": "prior", "family": "family", "models": "auto"}
"""Method table names of the light models → their ``--model`` name."""

AMBIENT_MODELS = ("led", *LIGHT_MODELS.values())
"""The ``--model`` names: the LEDs' span (eq. 4–6) and the light models."""


def method_of(settings: EstimateSettings) -> str:
    """The :data:`ESTIMATE_METHODS` name of ``--method``/``--model`` settings.

    >>> method_of(EstimateSettings()), method_of(EstimateSettings(method="global")), method_of(EstimateSettings(model="auto"))
    ('auto', 'global', 'models')
    """
    if settings.model == "led":
        return settings.method
    return next((name for name, model in LIGHT_MODELS.items() if model == settings.model), settings.model)


def with_method(settings: EstimateSettings, method: str) -> EstimateSettings:
    """``settings`` set to estimate by ``method``, a :data:`ESTIMATE_METHODS` name (the inverse of :func:`method_of`).

    >>> with_method(EstimateSettings(), "models").model, with_method(EstimateSettings(), "local").method
    ('auto', 'local')
    """
    method = validate_method(method)
    if method in LIGHT_MODELS:
        return replace(settings, model=LIGHT_MODELS[method])
    return replace(settings, method=method, model="led")


def validate_method(method: str) -> str:
    """``method`` if :data:`ESTIMATE_METHODS` has it, else a UsageError naming the methods (and the closest)."""
    if method not in ESTIMATE_METHODS:
        raise UsageError(unknown_name("estimate method", method, ESTIMATE_METHODS))
    return method


def flash_one(path: str, settings: FlashSettings, report: Report) -> FlashResult:
    """``msflash flash`` of the sequence at ``path``: the estimate, the flash mix (eq. 7–9) and, with
    ``settings.out``, its computational image written there.

    Raises
    ------
    UsageError
        An output type that cannot hold the frames, a dark ambient, an unwritable output.
    """
    kind = None if settings.out is None else check_output_type(Path(settings.out))
    estimating = settings.estimate
    sequence = read_calibrated(path, estimating.calibration, report)
    if settings.out is not None:
        check_raw_output(kind, Path(settings.out), sequence)
    if estimating.method != "global" or settings.out is not None:
        return _flash_local(sequence, settings, report)
    estimate = analysis.estimate_sequence(
        sequence, estimating.solver, estimating.alpha, bin_factor=estimating.bin_factor
    )
    refuse_dark_ambient(sequence, estimate, FLASH_GOAL[settings.mode])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TargetUnreachableWarning)
        solution = analysis.solve_sequence_flash(
            sequence, settings.mode, estimate.ambient_weights, settings.target, settings.bounds
        )
    for warning in caught:
        report(f"warning: {warning.message}")
    payload = analysis.flash_payload(sequence, solution, settings.target)
    payload["estimate_warnings"] = list(estimate.warnings)
    return FlashResult(sequence, payload, solution)


def _flash_local(sequence: Sequence, settings: FlashSettings, report: Report) -> FlashResult:
    estimating = settings.estimate
    # The estimate streams the frames from disk one at a time, and so does a global image's synthesis; a local
    # image (per-tile weights blended) is synthesised from the frames together.
    local = local_route.estimate_sequence_local(
        sequence,
        estimating.method,
        estimating.solver,
        estimating.alpha,
        estimating.tiles,
        bin_factor=estimating.bin_factor,
    )
    refuse_dark_ambient(sequence, local.global_estimate, FLASH_GOAL[settings.mode])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TargetUnreachableWarning)
        solution, tile_weights, _ = local_route.solve_sequence_flash_local(
            sequence, settings.mode, local, settings.target, settings.bounds
        )
    for message in dict.fromkeys(str(warning.message) for warning in caught):
        report(f"warning: {message}")
    payload = local_route.local_flash_payload(sequence, solution, local, tile_weights, settings.target)
    if settings.out is not None:
        output = Path(settings.out)
        if local.model == "local":
            image, saturated, stack = local_route.synthesize_sequence_local(sequence, tile_weights, local)
            ambient_index = stack.ambient_index
        else:
            image, saturated, layout = analysis.synthesize_sequence(
                sequence, solution.flash_weights, flicker=local.global_estimate.flicker
            )
            ambient_index = layout.ambient_index
        metadata = {
            "msflash:flash_weights": solution.flash_weights.tolist(),
            "msflash:method": local.model,
            "msflash:mode": solution.mode,
        }
        if local.model == "local":
            metadata["msflash:tile_flash_weights"] = json.dumps(np.round(tile_weights, 6).tolist())
        write_flash_image(output, image, ambient_index, sequence, metadata, report)
        payload["out"] = str(output)
        payload["saturated_fraction"] = float(saturated.mean())
    return FlashResult(sequence, payload, solution, local)


OUTPUT_TYPES = {".exr": "exr", ".tif": "tiff", ".tiff": "tiff"}
"""``--out`` suffixes: linear float EXR, or 16-bit raw TIFF at the ambient frame's exposure and gain."""


def check_output_type(output: Path) -> str:
    """``exr`` or ``tiff`` for ``--out``; refused before any work is done."""
    kind = OUTPUT_TYPES.get(output.suffix.lower())
    if kind is None:
        raise UsageError(f"--out {output}: unsupported image type; expected .exr (linear float) or .tiff (16-bit raw)")
    return kind


def check_raw_output(kind: str | None, output: Path, sequence: Sequence) -> None:
    """Refuse an ``--out`` inside the sequence's own folder, and a raw ``.tiff`` (``kind`` from
    :func:`check_output_type`) for a sequence whose frames are float (EXR).

    Inside the sequence folder the image would replace a captured frame (``--out SEQ/frames/000-ambient.tiff``,
    a capture lost) or be an undeclared file there. Raw TIFF values are whole counts in the frames' own
    encoding, and float frames have none (normalised ones, white level 1, would all round to 0 or 1)."""
    folder = sequence.directory.resolve()
    if output.resolve().is_relative_to(folder):
        raise UsageError(
            f"--out {output}: inside the sequence folder {sequence.directory}, where it would replace or sit "
            "among the captured frames; expected a path outside it (e.g. beside it, in the run folder)"
        )
    ambient = sequence.indices("ambient")
    if kind != "tiff" or not ambient:
        return
    header = read_image_header(sequence.frame_path(ambient[0]))
    if np.issubdtype(header.dtype, np.floating):
        raise UsageError(
            f"--out {output}: the frames of {sequence.path} are float ({sequence.frames[ambient[0]].file}, white level "
            f"{sequence.camera.white_level:g}), so a 16-bit raw TIFF cannot hold them in their encoding; expected .exr "
            "(linear float)"
        )


def write_flash_image(
    output: Path,
    image: np.ndarray,
    ambient_index: int,
    sequence: Sequence,
    metadata: dict[str, Any],
    report: Report,
) -> None:
    """The computational image at ``output``: linear float EXR (RGB; a mosaic demosaicked,
    :func:`acquisition.sequence.exr_metadata.exr_image`), or raw TIFF at the ambient frame's exposure.

    Raises
    ------
    UsageError
        ``output`` cannot be written (naming what is in the way).
    """
    kind = check_output_type(output)
    try:
        if kind == "exr":
            rgb, exr = exr_image(sequence, image)  # a mosaic demosaicked: an EXR holds R, G, B
            write_image(output, rgb, {**metadata, **exr.attributes}, exr.chromaticities)
            return
        ambient = sequence.frames[ambient_index]
        white = sequence.camera.white_level
        raw = to_raw_values(image, ambient.exposure_us, ambient.gain, sequence.camera.black_level, white)
        write_image(output, raw, {**metadata, "msflash:exposure_us": ambient.exposure_us, "msflash:gain": ambient.gain})
    except OSError as err:
        blocking = next((parent for parent in output.parents if parent.exists()), None)
        reason = (
            f"{blocking} is not a directory"
            if blocking is not None and not blocking.is_dir()
            else err.strerror or str(err)
        )
        raise UsageError(f"--out {output}: cannot be written ({reason}); expected a writable file path") from None
    clipped = int(np.count_nonzero((raw >= white) | (raw <= 0)))
    if clipped:
        report(
            f"warning: {clipped} of the {raw.size} samples of {output} ({clipped / raw.size:.2%}) are clipped to the "
            f"raw range 0…{white:g} at the ambient frame's exposure; .exr keeps the linear values"
        )
