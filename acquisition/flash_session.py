"""The estimate → flash decision of one capture, prepared before the sequence starts.

Between the last LED frame and the flash trigger only the per-frame work may run. Everything
that depends on the rig and the plan alone — LED spectra and camera responsivities in photons,
the :class:`~processing.flash.FlashModel` (``A = Cᵀ I``, the tie-break matrices), the target's
camera response ``Cᵀ i_d`` (a colour-science lookup and unit conversion), the frame stack's
black/white levels and block size — is computed once by :meth:`FlashSession.prepare`.
:meth:`FlashSession.decide` then costs one statistics pass over the frames in memory, one
ambient solve and one small quadratic programme.

The results are those of :func:`acquisition.analysis.estimate_sequence` and
:func:`acquisition.analysis.solve_sequence_flash` on the same frames (same statistics code,
same solvers); ``tests/acquisition/test_flash_session.py`` checks it.
"""

from __future__ import annotations

from collections.abc import Sequence as Seq
from dataclasses import dataclass

import numpy as np

from acquisition import analysis
from acquisition.camera import RawFrame
from acquisition.errors import RecordingError
from acquisition.sequence_format import Sequence
from processing.ambient import AmbientEstimate, estimate_ambient
from processing.flash import FlashModel, FlashSolution
from processing.spectra import Spectra
from processing.statistics import FrameStackSpec, SequenceStatistics, accumulate_statistics, bin_frame


@dataclass
class FlashDecision:
    """What the flash step needs, and how it was reached."""

    estimate: AmbientEstimate
    solution: FlashSolution
    levels: np.ndarray
    """The flash weights clipped to [0, 1]: the LED levels to drive."""
    stack: analysis.FrameStack
    """The in-memory frame stack the estimate used (indices as in the sequence)."""


class FlashSession:
    """A rig's estimate + flash problem, prepared once (see the module notes).

    Build it with :meth:`prepare` from the sequence header (``SequenceWriter.sequence`` before
    any frame), then call :meth:`decide` with the ambient + LED frames as captured.
    """

    def __init__(self, header: Sequence, leds: Spectra, model: FlashModel, target_response: np.ndarray | None,
                 method: str, alpha: float | str, bin_factor: int) -> None:
        self.header = header
        self.leds = leds
        self.model = model
        self.target_response = target_response
        self.method = method
        self.alpha = alpha
        self.bin_factor = bin_factor
        self.begin()

    @classmethod
    def prepare(cls, header: Sequence, target: str = "D65", method: str = "tikhonov", alpha: float | str = "auto",
                bin_factor: int = analysis.DEFAULT_BIN_FACTOR) -> FlashSession:
        """Prepare from a sequence header (LEDs, camera, grid); ``target`` for the complementary flash.

        Raises
        ------
        RecordingError
            If the header has no camera responsivities, or the target cannot be read.
        """
        leds = analysis.led_spectra_photons(header)
        camera = analysis.camera_responsivities_photons(header)
        model = FlashModel(leds, camera)
        response = model.target_response(analysis.target_illuminant(target, header)) if target else None
        return cls(header, leds, model, response, method, alpha, bin_factor)

    # -- per capture -------------------------------------------------------------------------
    def begin(self) -> None:
        """Forget the frames of an earlier capture."""
        self._frames: list[RawFrame] = []
        self._roles: list[str] = []
        self._levels: list[tuple[float, ...]] = []
        self._binned: list[tuple[np.ndarray, np.ndarray] | None] = []
        self._factor: int | None = None

    def add(self, frame: RawFrame, role: str, levels: Seq[float]) -> None:
        """Take one captured frame; ambient and LED frames are block-summed now (between frames).

        The block sums and the per-block saturation are what the binned statistics pass of
        :func:`processing.statistics.accumulate_statistics` computes first; doing it as each frame
        arrives leaves only the small Gram product for :meth:`decide`.
        """
        if not hasattr(self, "_frames"):
            self.begin()
        pixels = _plane(frame.pixels)
        binned = None
        if role in ("ambient", "led"):
            period = 2 if self.header.camera.cfa is not None else 1
            if self._factor is None:
                factor = self.bin_factor
                while factor > 1 and min(pixels.shape[:2]) // (factor * period) < 8:  # as analysis.sequence_statistics
                    factor //= 2
                self._factor = max(factor, 1)
            if self._factor > 1:
                sums, maxima = bin_frame(pixels, self._factor, period)
                top = maxima if maxima.ndim == 2 else maxima.max(axis=2)
                binned = (sums, top >= self.header.camera.white_level)
        self._frames.append(frame)
        self._roles.append(role)
        self._levels.append(tuple(float(v) for v in levels))
        self._binned.append(binned)

    def stack(self) -> analysis.FrameStack:
        """The frame stack of the frames taken so far (first ``ambient`` and every ``led`` frame), in memory."""
        roles, frames = self._roles, self._frames
        ambient = [i for i, role in enumerate(roles) if role == "ambient"]
        leds = tuple(i for i, role in enumerate(roles) if role == "led")
        if not ambient or not leds:
            raise RecordingError(f"{self.header.path}: the captured frames have no ambient or no LED frame; "
                                 "expected ambient + one frame per LED")
        camera = self.header.camera

        def scale(index: int) -> float:
            return 1.0 / (frames[index].exposure_us * frames[index].gain)

        spec = FrameStackSpec(black_level=camera.black_level, white_level=camera.white_level,
                              ambient_scale=scale(ambient[0]), led_scales=tuple(scale(i) for i in leds),
                              led_levels=np.array([self._levels[i] for i in leds], dtype=float))
        return analysis.FrameStack(_plane(frames[ambient[0]].pixels), tuple(_plane(frames[i].pixels) for i in leds),
                                   spec, ambient[0], leds)

    def statistics(self, stack: analysis.FrameStack) -> SequenceStatistics:
        """The statistics of :func:`analysis.sequence_statistics` from the block sums taken in :meth:`add`.

        Block sums with the black level scaled by the block area, no white level and the
        saturated blocks masked are exactly what the binned pass feeds its moments (only the
        summation order differs).
        """
        factor = self._factor or 1
        if factor == 1:
            return analysis.sequence_statistics(stack, self.header.camera.cfa, self.bin_factor)
        indices = (stack.ambient_index, *stack.led_indices)
        binned = [self._binned[i] for i in indices]
        assert all(b is not None for b in binned)
        invalid = binned[0][1].copy()  # type: ignore[index]
        for _, saturated in binned[1:]:  # type: ignore[misc]
            invalid |= saturated
        spec = stack.spec
        block_spec = FrameStackSpec(black_level=spec.black_level * factor * factor, white_level=np.inf,
                                    ambient_scale=spec.ambient_scale, led_scales=spec.led_scales,
                                    led_levels=spec.led_levels)
        sums = [b[0] for b in binned]  # type: ignore[index]
        return accumulate_statistics(sums[0], sums[1:], block_spec, sample_mask=~invalid)

    def estimate(self, stack: analysis.FrameStack) -> AmbientEstimate:
        """The ambient estimate of :func:`analysis.estimate_sequence` for the frames taken."""
        return estimate_ambient(self.statistics(stack), self.leds, method=self.method, alpha=self.alpha)

    def solve(self, mode: str, ambient_weights: np.ndarray, bounds: str = "physical") -> FlashSolution:
        """The matching or complementary flash (as :func:`analysis.solve_sequence_flash`)."""
        if mode == "matching":
            return self.model.matching(ambient_weights, bounds=bounds)  # type: ignore[arg-type]
        if mode == "complementary":
            if self.target_response is None:
                raise RecordingError("complementary flash: the session was prepared without a target")
            return self.model.complementary(ambient_weights, self.target_response, bounds=bounds)  # type: ignore[arg-type]
        raise RecordingError(f"flash mode '{mode}' is unknown; expected matching or complementary")

    def decide(self, mode: str = "complementary", sanitise: bool = False) -> FlashDecision:
        """Estimate the ambient from the frames taken and solve the ``mode`` flash.

        ``sanitise`` replaces non-finite ambient weights by 0 before solving (a degenerate estimate
        still yields a flash to capture, e.g. on the test patterns of the aravis fake).
        """
        stack = self.stack()
        estimate = self.estimate(stack)
        weights = np.asarray(estimate.ambient_weights, dtype=float)
        if sanitise:
            weights = np.nan_to_num(weights, nan=0.0, posinf=0.0, neginf=0.0)
        solution = self.solve(mode, weights)
        flash = np.clip(np.nan_to_num(np.asarray(solution.flash_weights, dtype=float)), 0.0, 1.0)
        return FlashDecision(estimate, solution, flash, stack)


def _plane(pixels: np.ndarray) -> np.ndarray:
    return pixels[:, :, 0] if pixels.ndim == 3 and pixels.shape[2] == 1 else pixels


__all__ = ["FlashDecision", "FlashSession"]
