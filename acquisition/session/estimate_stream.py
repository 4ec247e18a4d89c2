"""The one accumulator of a sequence's estimate, fed one frame at a time (docs/architecture.md §5).

Whatever feeds the frames — a capture's runner (:meth:`EstimateStream.frame_ready`, a frame handler of
:mod:`acquisition.session.engine`), a sequence read from disk (:func:`stream_sequence`, one frame decoded
at a time), a replay — they reach the estimate the same way: each frame's block sums and saturated blocks
go into :class:`processing.block_rows.BlockRows` as it arrives, and the frame is then let go; the
moments are one product of those rows once every frame is in. The statistics they give *are* the reported
estimate: a live run reports the statistics it decided its flash from, and ``msflash estimate SEQ``
on the sequence it wrote feeds the same frames in the same order to the same accumulator, so both give
the same numbers to the last digit (``tests/acquisition/session/test_estimate_stream.py``).

Peak memory is one frame plus the statistics (the block rows: ``(n + 2)`` rows of ``H·W·C / b²``
float64 for ``b × b`` blocks, a sixteenth of a 16-bit RGB frame per frame at ``b = 8``), whatever
the frame count (but for ``bin_factor`` 1, the all-pixel reference, whose exact moments need every
frame's pixels together: the frames are kept). The local estimate's tiles (:class:`processing.tile_statistics.TileBlocks`) are accumulated
beside them when asked for.

A mono camera's frames are taken as their one plane (the sequence records them as three identical
channels, ``camera.extra["channels"]``), their statistics replicated to the three channels
(:meth:`processing.statistics.SequenceStatistics.replicated`): a third of the work, live and from disk
alike.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from collections.abc import Sequence as Seq
from dataclasses import dataclass

import numpy as np

from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.writer import mono_as_rgb
from msflash.acquisition.session.engine import CaptureResult, FrameEvent
from msflash.acquisition.session.reference_crops import ReferenceCrops
from msflash.processing import frame_kernels
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.ambient import AmbientEstimate, AmbientModel
from msflash.processing.block_rows import BlockRows
from msflash.processing.block_sums import plane_shape
from msflash.processing.channel_statistics import DEFAULT_FOLDS, ChannelStatistics, channel_statistics_of_block_rows
from msflash.processing.errors import SpectralDataError
from msflash.processing.flicker import corrected_tiles
from msflash.processing.local import LocalEstimate, estimate_local
from msflash.processing.statistics import FrameStackSpec, SequenceStatistics
from msflash.processing.tile_statistics import TileBlocks

USED_ROLES = ("ambient", "led")
"""The roles the estimate reads: the first ``ambient`` frame and every ``led`` frame."""


@dataclass(frozen=True)
class StackLayout:
    """Which frames of a sequence the estimate uses and how to linearise them."""

    spec: FrameStackSpec
    """Black/white levels, exposure·gain scales and LED levels."""
    ambient_index: int
    """Index of the (first) ambient frame in the sequence."""
    led_indices: tuple[int, ...]
    """Indices of the LED frames in the sequence."""


def stack_layout(
    sequence: Sequence,
    roles: Seq[str],
    led_levels: Seq[Seq[float]],
    exposure_gain: Seq[float],
) -> StackLayout:
    """The frames the estimate uses (the first ambient, every LED frame) and their linearisation.

    Raises
    ------
    RecordingError
        If there is no ambient frame, no LED frame, an ambient frame with LEDs lit, or LED frames that
        do not light every LED independently.
    """
    ambient_indices = [i for i, role in enumerate(roles) if role == "ambient"]
    led_indices = tuple(i for i, role in enumerate(roles) if role == "led")
    if not ambient_indices:
        raise RecordingError(f"{sequence.path}: frames has no 'ambient' frame; expected one")
    if not led_indices:
        raise RecordingError(f"{sequence.path}: frames has no 'led' frame; expected one per LED")
    ambient_index = ambient_indices[0]
    if any(level > 0 for level in led_levels[ambient_index]):
        raise RecordingError(
            f"{sequence.path}: frames[{ambient_index}] has role 'ambient' but LED levels "
            f"{list(led_levels[ambient_index])}; expected all zero"
        )
    try:
        spec = FrameStackSpec(
            black_level=sequence.camera.black_level,
            white_level=sequence.camera.white_level,
            ambient_scale=1.0 / exposure_gain[ambient_index],
            led_scales=tuple(1.0 / exposure_gain[i] for i in led_indices),
            led_levels=np.array([led_levels[i] for i in led_indices], dtype=float),
        )
    except SpectralDataError as err:
        raise RecordingError(f"{sequence.path}: frames: {err}") from err
    return StackLayout(spec, ambient_index, led_indices)


def is_mono(sequence: Sequence) -> bool:
    """Whether the sequence records a mono camera's frames as three identical channels (format v1, §6)."""
    return sequence.camera.cfa is None and "channels" in sequence.camera.extra


class EstimateStream:
    """A sequence's estimate statistics, accumulated one frame at a time (see the module notes).

    Parameters
    ----------
    header
        The sequence (read from disk, or the header a writer holds before the first frame): its camera
        (CFA, black and white levels), LEDs and responsivities.
    n_led_frames
        How many ``led`` frames will come (a plan's, or a sequence's count): the rows are laid out for
        them before the first frame.
    bin_factor
        The block size asked for (:func:`acquisition.session.analysis.block_factor` fits it to the frame).
    tiles
        Also accumulate the tiles of the local estimate (``tiles`` per side), or None.
    live
        Frames arrive while a camera streams: never a compiled kernel's first load or compile then
        (:func:`processing.frame_kernels.paused`); the numbers do not depend on it (docs/architecture.md §5.2).
    full_probe
        Keep every block row's half difference (the light models' channel statistics, :meth:`channel_statistics`).
    references
        A reference patch's or chart's crops (:class:`~acquisition.session.reference_crops.ReferenceCrops`), fed each
        ambient and LED frame this stream uses, as it passes (``--reference-patch|--reference-chart``); or None.
    """

    def __init__(
        self,
        header: Sequence,
        n_led_frames: int,
        bin_factor: int = 8,
        tiles: int | None = None,
        live: bool = False,
        full_probe: bool = False,
        references: ReferenceCrops | None = None,
    ) -> None:
        self.header = header
        self.references = references
        """The reference rectangles' crops, fed each frame used (None: no reference)."""
        self.full_probe = full_probe
        """Keep every block row's half difference (:class:`BlockRows`, ``full_probe``): the light models take their
        channel statistics from :attr:`block_rows` then, on frames of any size."""
        self.n_led_frames = n_led_frames
        self.bin_factor = bin_factor
        self.tiles = tiles
        self.live = live
        self.mono = is_mono(header)
        self.roles: list[str] = []
        self.levels: list[tuple[float, ...]] = []
        self.exposure_gain: list[float] = []
        self.frame_shape: tuple[int, ...] | None = None
        """The shape of the frames as the sequence records them (a mono frame's three channels included)."""
        self.factor: int | None = None
        self._rows: BlockRows | None = None
        self._model_rows: BlockRows | None = None  # full_probe only: the light models' (module notes)
        self._planes: dict[int, np.ndarray] = {}  # bin factor 1 only: the frames, kept
        self._tiles: TileBlocks | None = None
        self._n_led_rows = 0
        self._have_ambient = False
        # The moments' route, decided before this stream loads anything (a live one never does): a capture's stream and
        # ``msflash estimate`` of its sequence in the same kind of process take the same (frame_kernels.statistics_compiled).
        self._compiled_statistics = frame_kernels.statistics_compiled()

    @classmethod
    def for_sequence(
        cls,
        sequence: Sequence,
        bin_factor: int = 8,
        tiles: int | None = None,
        live: bool = False,
        full_probe: bool = False,
        references: ReferenceCrops | None = None,
    ) -> EstimateStream:
        """A stream laid out for a sequence's own frames (its ``led`` entries)."""
        n_led = sum(1 for entry in sequence.frames if entry.role == "led")
        return cls(sequence, n_led, bin_factor, tiles, live, full_probe, references)

    # -- feeding -----------------------------------------------------------------------------------
    def add(self, pixels: np.ndarray, role: str, levels: Seq[float], exposure_gain: float) -> None:
        """Take the next frame of the sequence (every frame, in sequence order: flash and dark frames are
        only counted); an ambient or LED frame is block-summed now and may be let go after.

        Raises
        ------
        RecordingError
            If a frame's size differs from the first one's, more LED frames come than were laid out,
            or a frame holds non-finite values.
        """
        index = len(self.roles)
        where = f"{self.header.path}: frames[{index}]"
        if role == "led" and self._n_led_rows >= self.n_led_frames:  # refused before it counts as taken
            raise RecordingError(
                f"{where} is LED frame {self._n_led_rows + 1} but {self.n_led_frames} were planned; expected one row "
                "per LED frame"
            )
        self.roles.append(role)
        self.levels.append(tuple(float(v) for v in levels))
        self.exposure_gain.append(float(exposure_gain))
        if role not in USED_ROLES or (role == "ambient" and self._have_ambient):
            return  # the estimate uses the first ambient frame only (and no flash or dark frame)
        if pixels.ndim == 3 and pixels.shape[2] == 1:
            pixels = pixels[:, :, 0]
        if pixels.ndim == 2 and self.header.camera.cfa is None and self.frame_shape is None:
            self.mono = True  # a mono camera's frame as it gives it (the file holds three identical channels)
        recorded_shape = pixels.shape + (3,) if self.mono and pixels.ndim == 2 else pixels.shape
        plane = pixels[:, :, 0] if self.mono and pixels.ndim == 3 else pixels
        camera = self.header.camera
        period = 2 if camera.cfa is not None else 1
        if self.frame_shape is None:
            self.frame_shape = recorded_shape
            self.factor = _block_factor(recorded_shape, camera.cfa, self.bin_factor)
            # As the batch pass did: a large sequence loads the compiled kernels (never while a camera streams).
            if not self.live:
                frame_kernels.wanted(plane.nbytes * (self.n_led_frames + 1))
        elif recorded_shape != self.frame_shape:
            raise RecordingError(
                f"{where} has shape {recorded_shape} but the first frame {self.frame_shape}; expected frames of one size"
            )
        assert self.factor is not None
        if role == "ambient":
            row = self.n_led_frames
            self._have_ambient = True
        else:
            row = self._n_led_rows
            self._n_led_rows += 1
        if self.references is not None:  # the reference rectangles' pixels, copied: the frame is still let go
            self.references.add(row, pixels)
        try:
            if self.factor == 1:
                # Every pixel, no blocks (``--bin-factor 1``, the all-pixel reference): the exact all-pixel
                # moments need each pixel of every frame together, so the frames are kept until the end.
                self._planes[row] = plane
            self._add_to_rows(row, plane, period)
            if self.tiles is not None:
                if self._tiles is None:
                    self._tiles = TileBlocks(
                        self.n_led_frames,
                        recorded_shape,
                        camera.black_level,
                        camera.white_level,
                        bin_factor=self.factor,
                        cfa_period=period,
                        weighting=SAMPLE_WEIGHTING,
                    )
                self._tiles.add_frame(row, mono_as_rgb(plane) if self.mono else plane)
        except SpectralDataError as err:
            raise RecordingError(f"{where}: {err}") from err

    def _add_to_rows(self, row: int, plane: np.ndarray, period: int) -> None:
        """The frame's block sums into the block rows, laid out at the first frame: the estimate's (none for bin factor
        1), and with ``full_probe`` the light models', at the default block size whatever the estimate's (the size
        they are tuned at: docs/decisions/one-estimation-route.md), made once when the two coincide."""
        if self._rows is None and self._model_rows is None and (self.factor != 1 or self.full_probe):
            assert self.frame_shape is not None and self.factor is not None
            default = _block_factor(self.frame_shape, self.header.camera.cfa)
            if self.factor != 1:
                self._rows = self._laid_out(plane, period, self.factor, self.full_probe and self.factor == default)
            if self.full_probe:
                same = self._rows is not None and self.factor == default
                self._model_rows = self._rows if same else self._laid_out(plane, period, default, True)
        with frame_kernels.paused() if self.live else contextlib.nullcontext():
            for rows in dict.fromkeys(r for r in (self._rows, self._model_rows) if r is not None):
                rows.add_frame(row, plane, period)

    def _laid_out(self, plane: np.ndarray, period: int, factor: int, full_probe: bool) -> BlockRows:
        """Empty block rows of ``factor`` for the frames of ``plane``'s size (``full_probe``: the light models' rows;
        the estimate's own moments are the strided probe's either way)."""
        camera = self.header.camera
        return BlockRows(
            self.n_led_frames,
            plane_shape(plane.shape, period),
            factor,
            camera.white_level,
            black_level=camera.black_level,
            weighting=SAMPLE_WEIGHTING,
            compiled=self._compiled_statistics,
            full_probe=full_probe,
        )

    def frame_ready(self, event: FrameEvent) -> None:
        """A capture's frame as it lands (a handler of :class:`~acquisition.session.engine.CaptureRunner`)."""
        frame = event.frame
        self.add(frame.pixels, event.step.role, event.step.led_levels, frame.exposure_us * frame.gain)

    def sequence_finished(self, result: CaptureResult) -> None:
        """Nothing to do: the statistics were taken frame by frame."""

    @property
    def nbytes(self) -> int:
        """Bytes the statistics hold (the block rows and their probe; the tiles' block sums when asked for)."""
        arrays: list[np.ndarray | None] = []
        if self._rows is not None:
            arrays += [self._rows.rows, self._rows.differences]
        arrays += list(self._planes.values())
        if self._tiles is not None:
            arrays += [self._tiles.data, self._tiles.differences]
        return sum(array.nbytes for array in arrays if array is not None)

    # -- results -----------------------------------------------------------------------------------
    def layout(self) -> StackLayout:
        """The frames used and their linearisation (:func:`stack_layout` of the frames taken)."""
        return stack_layout(self.header, self.roles, self.levels, self.exposure_gain)

    def _complete(self) -> bool:
        """Every laid-out LED frame and the ambient frame taken, and their block rows made (bin factor 1 keeps the
        frames instead): the one completeness rule of every result."""
        have_rows = self._rows is not None or self.factor == 1
        return have_rows and self._have_ambient and self._n_led_rows == self.n_led_frames

    def _complete_rows(self) -> BlockRows | None:
        """The block rows of the frames taken (None for bin factor 1), or a RecordingError naming what is missing."""
        if not self._complete():
            self.layout()  # no ambient frame: its own message
            raise RecordingError(
                f"{self.header.path}: {self._n_led_rows} of {self.n_led_frames} LED frames taken; "
                "expected every LED frame before the estimate"
            )
        return self._rows

    def channel_statistics(self) -> ChannelStatistics:
        """The channel-resolved statistics of the frames taken (``--model prior|family|auto``, docs/architecture.md
        §5.3), from the block rows made as the frames arrived: no second pass over the frames (issue 31; the frames'
        own pass, :func:`processing.channel_statistics.accumulate_channel_statistics`, gives the same numbers). The
        stream must keep every block row's probe (``full_probe``). Their block size is the default one whatever the
        estimate's (:meth:`_add_to_rows`); a mono camera's one plane gives the three alike channels its sequence
        records.

        Raises
        ------
        RecordingError
            A frame missing, a stream made without ``full_probe``, or fewer block rows than folds.
        """
        self._complete_rows()
        rows = self._model_rows
        if rows is None:
            raise RecordingError(
                f"{self.header.path}: the estimate stream kept no full probe; expected full_probe=True for the channel "
                "statistics"
            )
        statistics = channel_statistics_of_block_rows(rows, self.layout().spec, cfa=self.header.camera.cfa)
        if statistics is None:
            raise RecordingError(
                f"{self.header.path}: {rows.block_shape[0]} rows of {rows.factor}×{rows.factor} blocks; expected at "
                f"least {DEFAULT_FOLDS} for the light models' held-out folds (larger frames)"
            )
        return statistics

    def statistics(self) -> SequenceStatistics:
        """The sufficient statistics of eq. 4–6 of the frames taken (every LED frame must be in)."""
        rows = self._complete_rows()
        spec = self.layout().spec
        with frame_kernels.paused() if self.live else contextlib.nullcontext():
            if self.factor == 1:
                planes, n = self._planes, self.n_led_frames
                period = 2 if self.header.camera.cfa is not None else 1
                statistics = accumulate_statistics(
                    planes[n], [planes[j] for j in range(n)], spec, bin_factor=1, cfa_period=period
                )
            else:
                assert rows is not None
                statistics = rows.statistics(spec)
        return statistics.replicated(3) if self.mono else statistics

    def estimate(
        self, method: str = "tikhonov", alpha: float | str = "auto", model: AmbientModel | None = None
    ) -> AmbientEstimate:
        """The reported ambient estimate (eq. 4–6 with the LED model's band) of the frames taken."""
        from msflash.acquisition.session.analysis import estimate_from_statistics

        return estimate_from_statistics(self.header, self.statistics(), method, alpha, model)

    def local(
        self,
        method: str = "auto",
        solver: str = "tikhonov",
        alpha: float | str = "auto",
        global_estimate: AmbientEstimate | None = None,
    ) -> LocalEstimate:
        """The global-or-local estimate (``method`` auto|global|local) of the frames taken; the stream must
        have been made with ``tiles``. The global estimate is :meth:`estimate`'s (or ``global_estimate``)."""
        from msflash.acquisition.session.sequence_spectra import led_spectra_photons

        self._complete_rows()  # frames missing (an interrupted capture): say so, not that tiles are
        if self._tiles is None or self.tiles is None:
            raise RecordingError(f"{self.header.path}: the estimate stream was made without tiles; expected tiles=…")
        whole_frame = global_estimate if global_estimate is not None else self.estimate(solver, alpha)
        grid = _tile_grid(self._tiles.block_grid, self.tiles)
        try:
            tiled = self._tiles.statistics(self.layout().spec, grid)
        except SpectralDataError as err:
            raise RecordingError(f"{self.header.path}: {err}") from err
        # The whole frame's flicker read corrects the tiles too (processing.flicker: the same shares, exactly).
        tiled = corrected_tiles(tiled, whole_frame.flicker)
        return estimate_local(
            tiled, led_spectra_photons(self.header), method, solver, alpha, global_estimate=whole_frame
        )


SAMPLE_WEIGHTING = True
"""The estimate's statistics weigh each sample by its inverse noise variance (processing.block_rows, module
notes): unweighted, a bright highlight's noisy samples dominate eq. 5."""


def _block_factor(shape: tuple[int, ...], cfa: str | None, bin_factor: int | None = None) -> int:
    """:func:`acquisition.session.analysis.block_factor` (``None``: of the default block size)."""
    from msflash.acquisition.session.analysis import DEFAULT_BIN_FACTOR, block_factor

    return block_factor(shape, cfa, DEFAULT_BIN_FACTOR if bin_factor is None else bin_factor)


def _tile_grid(blocks: tuple[int, int], tiles: int) -> tuple[int, int]:
    """Tiles (rows, columns) that fit ``blocks``: at least 2 blocks per tile side."""
    return max(1, min(tiles, blocks[0] // 2)), max(1, min(tiles, blocks[1] // 2))


def stream_sequence(
    sequence: Sequence,
    bin_factor: int = 8,
    tiles: int | None = None,
    pixels: Callable[[int], np.ndarray] | None = None,
    full_probe: bool = False,
    references: ReferenceCrops | None = None,
) -> EstimateStream:
    """Feed a sequence's frames to a new :class:`EstimateStream`, one decoded frame at a time, in order.

    Only the ambient and LED frames are decoded (``pixels(index)``; by default read from disk by
    :meth:`~acquisition.sequence.format.Sequence.load_frame`, which checks each); the others are counted
    from their entries. ``references``: crops of a reference patch or chart taken from the same frames as they pass.
    """
    stream = EstimateStream.for_sequence(sequence, bin_factor, tiles, full_probe=full_probe, references=references)
    load = pixels or sequence.load_frame
    seen_ambient = False
    for index, entry in enumerate(sequence.frames):
        used = entry.role == "led" or (entry.role == "ambient" and not seen_ambient)
        seen_ambient = seen_ambient or entry.role == "ambient"
        frame = load(index) if used else _NO_PIXELS
        stream.add(frame, entry.role, entry.led_levels, entry.exposure_us * entry.gain)
        del frame
    return stream


_NO_PIXELS = np.zeros((0, 0), dtype=np.uint16)
