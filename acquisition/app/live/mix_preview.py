"""See the flash before it fires: the last sequence's image under any LED mix, at video rate (issue 33 item 2).

The image under a mix ``w`` is ``msflash synthesize``'s: :func:`processing.synthesis.synthesize` on the
sequence's raw frames (``m_a + Σ_k w_k m_f,k``, paper eq. 7), run here on the **preview's samples** of those
frames. Synthesis is per sample, so the preview's sample at a position is the full image's sample there, bit
for bit (:func:`preview_samples` picks them; a mosaic keeps its CFA phase). The frames are loaded once, by
:func:`acquisition.session.analysis.load_frame_stack` (the one route from a sequence to frames), and cut to
the preview's samples once; each mix then costs one weighted sum of ``k + 1`` small frames and a JPEG.

Display: the linear image is shown on one fixed scale per run (the brightest of the ambient and the run's
solved mixes at its 99.5th percentile is display white), so a stronger mix looks brighter, as it will be;
the ambient beside it is drawn on the same scale. Pixels saturated in some input frame are painted
:data:`~acquisition.app.live.preview.OVERLAY_RGB` when the overlay is on (their synthesis is unreliable).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msflash.acquisition.app.live.preview import Preview, PreviewRenderer
from msflash.acquisition.app.live.runs import read_json
from msflash.acquisition.errors import UsageError
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.analysis import FrameStack, load_frame_stack
from msflash.processing import frame_kernels
from msflash.processing.render import demosaic_superpixel
from msflash.processing.statistics import FrameStackSpec
from msflash.processing.synthesis import synthesize

WHITE_PERCENTILE = 99.5
"""The percentile of the brightest solved image shown as display white."""


def preview_samples(raw: np.ndarray, cfa: str | None, width: int) -> np.ndarray:
    """The samples of ``raw`` a ``width``-pixel preview needs, contiguous, of ``raw``'s type.

    A mosaic keeps whole 2×2 CFA cells (one cell in every ``step / 2`` of each row and column), so its superpixel
    debayer is the whole number of cells nearest ``width``; other frames keep every ``step``-th pixel, nearest
    ``width`` too. The same cut of ``synthesize``'s full image gives the preview's image sample for sample
    (synthesis is per sample).
    """
    frame = np.asarray(raw)
    if frame.ndim == 2 and cfa is not None:
        step = max(1, round(frame.shape[1] / 2 / width)) * 2
        if step > 2:
            rows, columns = frame.shape[0] // step * step, frame.shape[1] // step * step
            cells = frame[:rows, :columns].reshape(rows // step, step, columns // step, step)[:, :2, :, :2]
            return np.ascontiguousarray(cells.reshape(rows // step * 2, columns // step * 2))
        return np.ascontiguousarray(frame)
    step = max(1, round(frame.shape[1] / width))
    return np.ascontiguousarray(frame[::step, ::step])


def _flicker_offsets(run: Path, names: tuple[str, ...]) -> np.ndarray | None:
    """The flicker shares the run's estimate corrected its LED images by (``estimate.json``), or None."""
    estimate = read_json(run / "estimate.json")
    flicker = estimate.get("flicker") if isinstance(estimate, dict) else None
    offsets = flicker.get("applied_gain_offsets") if isinstance(flicker, dict) and flicker.get("corrected") else None
    if not isinstance(offsets, list) or len(offsets) != len(names):
        return None
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in offsets):
        return None  # a text where a number belongs ("1_0" would read as 10): not the run's figures
    values = np.array(offsets, dtype=float)
    return values if np.all(np.isfinite(values)) else None


@dataclass(frozen=True)
class MixImage:
    """One synthesised preview: the linear samples, their saturation and the rendered JPEG."""

    levels: tuple[float, ...]
    linear: np.ndarray
    """``synthesize``'s image on the preview's samples (value per µs·gain, black removed)."""
    saturated: np.ndarray
    preview: Preview


class MixPreview:
    """The frames of one sequence, cut once to the preview's samples, ready to be synthesised under any mix.

    Parameters
    ----------
    stack
        The sequence's frames (:func:`~acquisition.session.analysis.load_frame_stack`).
    solved
        Solved mixes by name (``matching``, ``complementary``), drive levels in [0, 1].
    renderer
        The live view's renderer (the camera → sRGB matrix); its width is the preview's.
    ambient_offsets
        The run's estimate's flicker shares (``estimate.json``'s ``flicker.applied_gain_offsets``), or None.
    """

    def __init__(
        self,
        stack: FrameStack,
        cfa: str | None,
        led_names: tuple[str, ...],
        solved: dict[str, tuple[float, ...]],
        renderer: PreviewRenderer,
        run: str = "",
        ambient_exposure: tuple[float, float] = (0.0, 1.0),
        ambient_offsets: np.ndarray | None = None,
    ) -> None:
        self.run = run
        self.ambient_offsets = ambient_offsets
        """A flickering lamp's share in each LED image, taken out as the run's own synthesis does, or None."""
        self.ambient_exposure = ambient_exposure
        """The ambient frame's exposure (µs) and gain: a mix is fired at them."""
        self.cfa = cfa if stack.ambient.ndim == 2 else None
        self.led_names = led_names
        self.spec: FrameStackSpec = stack.spec
        self.renderer = renderer
        # The preview sums these frames again for every mix: the compiled pass pays off whatever their size.
        frame_kernels.wanted(frame_kernels.COMPILE_BYTES)
        self.ambient = preview_samples(stack.ambient, self.cfa, renderer.width)
        self.led_frames = tuple(preview_samples(frame, self.cfa, renderer.width) for frame in stack.led_frames)
        self.solved = dict(solved)
        brightest = 0.0
        saturated: np.ndarray = np.zeros(self.ambient.shape[:2], dtype=bool)
        for levels in [(0.0,) * len(led_names), *self.solved.values()]:
            linear, saturated = self.synthesize(levels)
            brightest = max(brightest, float(np.percentile(self.rgb(linear), WHITE_PERCENTILE)))
        self.white = brightest if brightest > 0 else 1.0
        """The linear value shown as display white."""
        # Saturated in some input frame: the same samples whatever the mix (synthesize's mask), drawn per pixel.
        self.paint: np.ndarray = saturated
        if self.cfa is not None:  # one flag per superpixel: any of its cell's samples
            rows, columns = saturated.shape[0] // 2, saturated.shape[1] // 2
            cells = saturated[: rows * 2, : columns * 2].reshape(rows, 2, columns, 2)
            self.paint = np.asarray(cells.any(axis=(1, 3)))

    @classmethod
    def from_run(cls, run: Path, renderer: PreviewRenderer) -> MixPreview:
        """The preview of the run in folder ``run`` (its ``sequence/``; ``flash-matching.json`` and
        ``flash-complementary.json`` give the solved mixes when the run reported).

        Raises
        ------
        UsageError
            The folder holds no readable sequence with an ambient and the LED frames.
        """
        try:
            sequence = read_sequence(run / "sequence")
            stack = load_frame_stack(sequence)
        except Exception as err:  # noqa: BLE001 - any unreadable sequence: one line for the page
            raise UsageError(f"run '{run.name}': no sequence to synthesise from ({err})") from err
        names = tuple(led.name for led in sequence.leds)
        solved: dict[str, tuple[float, ...]] = {}
        for mode in ("matching", "complementary"):
            flash = read_json(run / f"flash-{mode}.json")
            weights = flash.get("flash_weights") if isinstance(flash, dict) else None
            if isinstance(weights, list) and len(weights) == len(names):
                try:
                    solved[mode] = tuple(float(np.clip(float(w), 0.0, 1.0)) for w in weights)
                except (TypeError, ValueError):
                    continue
        ambient = sequence.frames[stack.ambient_index]
        exposure = (float(ambient.exposure_us), float(ambient.gain))
        return cls(
            stack, sequence.camera.cfa, names, solved, renderer, run.name, exposure, _flicker_offsets(run, names)
        )

    def levels(self, given: object) -> tuple[float, ...]:
        """``given`` checked as one drive level in [0, 1] per LED (a one-line :class:`UsageError` otherwise)."""
        count = len(self.led_names)
        if not isinstance(given, list) or len(given) != count:
            raise UsageError(f"levels: expected a list of {count} numbers in [0, 1], one per LED")
        levels = []
        for name, value in zip(self.led_names, given):
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= float(value) <= 1.0:
                raise UsageError(f"level of {name} {str(value)[:40]}: expected a number in [0, 1]")
            levels.append(float(value))
        return tuple(levels)

    def synthesize(self, levels: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
        """``synthesize`` on the preview's samples: the linear image and its saturation mask."""
        weights = np.asarray(levels, dtype=float)
        return synthesize(
            self.ambient, self.led_frames, self.spec, weights, workers=1, ambient_offsets=self.ambient_offsets
        )

    def rgb(self, linear: np.ndarray) -> np.ndarray:
        """Camera RGB of a linear image of the preview's samples (a mosaic's superpixels)."""
        if linear.ndim == 2 and self.cfa is not None:
            return demosaic_superpixel(linear, self.cfa, np.float32)
        return linear if linear.ndim == 3 else np.repeat(linear[:, :, None], 3, axis=2)

    def image(self, levels: tuple[float, ...], overlay: bool = True) -> MixImage:
        """The image under ``levels`` (drive levels, one per LED), rendered for the page."""
        linear, saturated = self.synthesize(levels)
        paint = self.paint if overlay else None
        preview = self.renderer.render_rgb(
            self.rgb(linear), paint, float(np.mean(self.paint)), scale=1.0 / self.white, histogram=False
        )
        return MixImage(levels, linear, saturated, preview)
