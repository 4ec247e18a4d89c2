"""The estimate → flash decision of one capture, prepared before the sequence starts.

Between the last LED frame and the flash trigger only the per-frame work may run. Everything
that depends on the rig and the plan alone — LED spectra and camera responsivities in photons,
the :class:`~processing.flash.FlashModel` (``A = Cᵀ I``, the tie-break matrices, the factored
matching problem), the :class:`~processing.ambient.AmbientModel` (roughness operator and
non-negativity rows), the target's camera response ``Cᵀ i_d`` (a colour-science lookup and unit
conversion), the frame stack's black/white levels and block size — is computed once by
:meth:`FlashSession.prepare`. Each frame's block sums, saturated blocks and products with the
frames before it are taken by :meth:`FlashSession.add` as the frame arrives (between frames).
:meth:`FlashSession.decide` then costs the statistics from those moments, one ambient solve and
one small quadratic programme; the estimate's reliability signals wait until they are read.
Prepared with exposure limits, the session also takes each frame's rates for the flash exposure
(:class:`~acquisition.session.metering.FlashExposure`) as it arrives, and :meth:`FlashSession.flash_exposure`
only sums them.

The statistics are those of the one accumulator every route feeds
(:class:`~acquisition.session.estimate_stream.EstimateStream`): :meth:`FlashSession.estimate` is the
estimate the run reports, and :func:`acquisition.session.analysis.estimate_sequence` on the sequence
written gives it to the last digit (the same frames in the same order into the same rows);
``tests/acquisition/session/test_estimate_stream.py`` checks it.
"""

from __future__ import annotations

from collections.abc import Callable
from collections.abc import Sequence as Seq

import numpy as np

from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.session import analysis, sequence_spectra
from msflash.acquisition.session.engine import CaptureResult, FrameEvent
from msflash.acquisition.session.estimate_stream import EstimateStream
from msflash.acquisition.session.exposure import ExposurePolicy
from msflash.acquisition.session.metering import FlashExposure, metering_view
from msflash.processing.ambient import AmbientEstimate, AmbientModel
from msflash.processing.flash import FlashBounds, FlashModel, FlashSolution
from msflash.processing.spectra import Spectra
from msflash.processing.statistics import SequenceStatistics

DEFAULT_EXPOSURE_POLICY = ExposurePolicy()
"""The policy a session predicts the flash exposure with unless given one (frozen: one instance serves all)."""


class FlashDecision:
    """What the flash step needs, and how it was reached.

    The ambient estimate's reliability signals (band, conditioning, warnings) are not needed to
    drive the flash, so :meth:`FlashSession.decide` leaves them out of the latency-critical path:
    :attr:`estimate` computes them on first access (after the flash is triggered).
    """

    def __init__(self, solution: FlashSolution, levels: np.ndarray, estimate: Callable[[], AmbientEstimate]) -> None:
        self.solution = solution
        self.levels = levels
        """The flash weights clipped to [0, 1]: the LED levels to drive."""
        self._estimate = estimate
        self._estimated: AmbientEstimate | None = None

    @property
    def estimate(self) -> AmbientEstimate:
        """The reported ambient estimate (:meth:`FlashSession.estimate`'s, from the same flicker check and
        weights), computed once on first access."""
        if self._estimated is None:
            self._estimated = self._estimate()
        return self._estimated


class FlashSession:
    """A rig's estimate + flash problem, prepared once (see the module notes).

    Build it with :meth:`prepare` from the sequence header (``SequenceWriter.sequence`` before
    any frame), then call :meth:`decide` with the ambient + LED frames as captured.
    """

    def __init__(
        self,
        header: Sequence,
        leds: Spectra,
        model: FlashModel,
        target_response: np.ndarray | None,
        method: str,
        alpha: float | str,
        bin_factor: int,
        exposure_limits_us: tuple[float, float] | None = None,
        exposure_policy: ExposurePolicy = DEFAULT_EXPOSURE_POLICY,
    ) -> None:
        self.header = header
        self.leds = leds
        self.model = model
        self.ambient_model = AmbientModel(leds)
        self.target_response = target_response
        self.method = method
        self.alpha = alpha
        self.bin_factor = bin_factor
        self.exposure_limits_us = exposure_limits_us
        self.exposure_policy = exposure_policy
        self.begin()

    @classmethod
    def prepare(
        cls,
        header: Sequence,
        target: str = "D65",
        method: str = "tikhonov",
        alpha: float | str = "auto",
        bin_factor: int = analysis.DEFAULT_BIN_FACTOR,
        exposure_limits_us: tuple[float, float] | None = None,
        exposure_policy: ExposurePolicy = DEFAULT_EXPOSURE_POLICY,
    ) -> FlashSession:
        """Prepare from a sequence header (LEDs, camera, grid); ``target`` for the complementary flash.

        With ``exposure_limits_us`` (the camera's range) the flash exposure is predicted too
        (:meth:`flash_exposure`, aiming as ``exposure_policy`` says).

        Raises
        ------
        RecordingError
            If the header has no camera responsivities, or the target cannot be read.
        """
        leds = sequence_spectra.led_spectra_photons(header)
        camera = sequence_spectra.camera_responsivities_photons(header)
        model = FlashModel(leds, camera)
        response = model.target_response(sequence_spectra.target_illuminant(target, header)) if target else None
        return cls(header, leds, model, response, method, alpha, bin_factor, exposure_limits_us, exposure_policy)

    # -- per capture -------------------------------------------------------------------------
    def begin(self, n_led_frames: int | None = None) -> None:
        """Forget the frames of an earlier capture; ``n_led_frames`` LED frames will come (default one per LED)."""
        self.stream = EstimateStream(
            self.header, self.leds.count if n_led_frames is None else n_led_frames, self.bin_factor, live=True
        )
        camera = self.header.camera
        self._exposure = (
            None
            if self.exposure_limits_us is None
            else FlashExposure(camera.black_level, camera.white_level, self.exposure_limits_us, self.exposure_policy)
        )
        self._seen_ambient = False

    def add(self, frame: RawFrame, role: str, levels: Seq[float]) -> None:
        """Take one captured frame; ambient and LED frames are block-summed now (between frames).

        The block sums, the per-block saturation and the frame's products with the frames before
        it go into the session's :class:`~acquisition.session.estimate_stream.EstimateStream`, the
        accumulator a sequence read from disk is fed to as well; doing it as each frame arrives leaves
        :meth:`decide` only the small solves.
        """
        first_ambient = role == "ambient" and not self._seen_ambient
        self._seen_ambient = self._seen_ambient or role == "ambient"
        self.stream.add(frame.pixels, role, levels, frame.exposure_us * frame.gain)
        if self._exposure is not None and (role == "led" or first_ambient):
            metered = metering_view(frame.pixels, mosaic=self.header.camera.cfa is not None)
            if role == "ambient":
                self._exposure.add_ambient(metered, frame.exposure_us)
            else:
                self._exposure.add_led(metered, frame.exposure_us)

    # -- as a frame handler of the capture engine ---------------------------------------------
    def frame_ready(self, event: FrameEvent) -> None:
        """Take an ambient or LED frame of a run as it lands (:meth:`add`); the flash frame is not the estimate's."""
        if event.step.role != "flash":
            self.add(event.frame, event.step.role, event.step.led_levels)

    def sequence_finished(self, result: CaptureResult) -> None:
        """Nothing to do: the statistics were taken frame by frame."""

    def statistics(self) -> SequenceStatistics:
        """The statistics of the frames taken so far, from the block sums taken in :meth:`add`."""
        return self.stream.statistics()

    def estimate(self) -> AmbientEstimate:
        """The reported ambient estimate of the frames taken (what ``msflash estimate`` gives for them)."""
        return self.stream.estimate(self.method, self.alpha, self.ambient_model)

    def solve(self, mode: str, ambient_weights: np.ndarray, bounds: FlashBounds = "physical") -> FlashSolution:
        """The matching or complementary flash (as :func:`analysis.solve_sequence_flash`)."""
        if mode == "matching":
            return self.model.matching(ambient_weights, bounds=bounds)
        if mode == "complementary":
            if self.target_response is None:
                raise RecordingError("complementary flash: the session was prepared without a target")
            return self.model.complementary(ambient_weights, self.target_response, bounds=bounds)
        raise RecordingError(f"flash mode '{mode}' is unknown; expected matching or complementary")

    def flash_exposure(self, levels: Seq[float] | np.ndarray) -> float:
        """The flash frame's exposure (µs) for LED ``levels``, from the frames taken (see :class:`FlashExposure`).

        Raises
        ------
        RecordingError
            If the session was prepared without exposure limits.
        """
        if self._exposure is None:
            raise RecordingError(
                "flash exposure: the session was prepared without exposure_limits_us; "
                "expected FlashSession.prepare(…, exposure_limits_us=(shortest, longest))"
            )
        return self._exposure.predict(levels)

    def decide(self, mode: str = "complementary", sanitise: bool = False) -> FlashDecision:
        """Estimate the ambient from the frames taken and solve the ``mode`` flash.

        Only the weights are estimated here; the estimate's reliability signals are computed when
        :attr:`FlashDecision.estimate` is first read. ``sanitise`` replaces non-finite ambient
        weights by 0 before solving (a degenerate estimate still yields a flash to capture, e.g. on
        the test patterns of the aravis fake).
        """
        statistics = self.statistics()  # the stream is live: no compiling between the LED frames and the flash
        # A flickering ambient's gains out, as the reported estimate takes them (docs/flicker.md): the flash mix is
        # the estimate's.
        statistics, check = analysis.flicker_corrected(self.header, statistics)
        raw_weights, alpha_used = self.ambient_model.weights(statistics, self.method, self.alpha)
        weights = np.asarray(raw_weights, dtype=float)
        if sanitise:
            weights = np.where(np.isfinite(weights), weights, 0.0)  # as nan_to_num(…, 0, 0, 0), at a tenth of its cost
        solution = self.solve(mode, weights)
        flash_weights = np.asarray(solution.flash_weights, dtype=float)
        # NaN → 0, ±inf → the bounds: what clip(nan_to_num(w), 0, 1) gives.
        flash = np.minimum(np.maximum(np.where(np.isnan(flash_weights), 0.0, flash_weights), 0.0), 1.0)
        model, method, header = self.ambient_model, self.method, self.header
        return FlashDecision(
            solution,
            flash,
            lambda: analysis.reported(model.reliability(statistics, raw_weights, method, alpha_used), header, check),
        )
