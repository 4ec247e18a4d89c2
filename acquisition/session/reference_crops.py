"""A reference patch or chart read from the one stream of the frames (issue 31): only its crops are kept.

``--reference-patch X,Y,W,H`` (a spectrally flat card) and ``--reference-chart FILE`` (patches of known reflectance)
name rectangles of the scene for ``estimate --model prior|family|auto`` (docs/light-families.md). Their pixels are
taken from each ambient and LED frame *as it passes through the LED estimate's stream*
(:class:`~acquisition.session.estimate_stream.EstimateStream`, which hands each frame it uses to its
:class:`ReferenceCrops`): a copy of each rectangle is kept and the frame is let go, so the frames are decoded once
and never held together (they were: ``load_frame_stack``, the whole stack in memory, only to be cropped). Once every
frame is in, :meth:`ReferenceCrops.patch` takes each rectangle's channel statistics from its crops exactly as the
stack's crops gave them (:func:`processing.channel_statistics.accumulate_channel_statistics` at 2 × 2 blocks, two
folds, then :func:`processing.flicker.corrected_channel_statistics`): the same numbers to the bit.

A rectangle outside the frame, under 8 × 8 pixels or (after being cut to whole 2 × 2 cells of a mosaic) too small is
refused in one line before any frame is decoded when the frame files' headers say their size
(:meth:`ReferenceCrops.of`), else at the first frame; a saturated patch once the frames are in.
"""

from __future__ import annotations

from collections.abc import Sequence as Seq
from dataclasses import dataclass

import numpy as np

from msflash.acquisition.errors import RecordingError, UsageError
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.image_files import read_image_header
from msflash.acquisition.sequence.writer import as_recorded
from msflash.acquisition.session.sequence_spectra import camera_responsivities_photons, led_spectra_photons
from msflash.processing.channel_statistics import accumulate_channel_statistics
from msflash.processing.errors import SpectralDataError
from msflash.processing.flicker import FlickerCheck, corrected_channel_statistics
from msflash.processing.json_input import parse_json_document
from msflash.processing.reference_patch import ReferencePatch
from msflash.processing.statistics import FrameStackSpec
from msflash.processing.user_files import JSON_MAX_BYTES, read_user_text, shown_path

ReferenceRect = tuple[int, int, int, int]
"""``(x, y, width, height)`` in pixels of the full frame: ``--reference-patch``."""
Reference = ReferenceRect | str
"""A grey card's rectangle (``--reference-patch``) or a chart file's path (``--reference-chart``)."""

MAX_REFLECTANCE = 1.5
"""The largest reflectance factor a reference chart may give (fluorescent whites exceed 1; percentages do not fit)."""

MIN_SIDE = 8
"""The smallest side, in pixels, of a reference rectangle (after it is cut to whole 2 × 2 cells of a mosaic)."""

PATCH_BIN_FACTOR = 2
"""Block size of a reference's channel statistics (a patch is small: 2 × 2 blocks keep its half-difference probe)."""

PATCH_FOLDS = 2
"""Folds of a reference's channel statistics (only their totals are read)."""


@dataclass(frozen=True)
class ReferenceRegion:
    """One rectangle of known reflectance: a ``--reference-patch`` card or one patch of a ``--reference-chart``."""

    rect: ReferenceRect
    """``(x, y, width, height)`` as the user gave it (pixels of the full frame)."""
    reflectance: np.ndarray | None
    """Reflectance factors on the sequence's grid; None: spectrally flat (a grey card)."""
    what: str
    """How the user named it, for messages (``--reference-patch 1,2,30,30``, ``--reference-chart F: patches[3]``)."""

    def cells(self, cfa: str | None) -> ReferenceRect:
        """The rectangle cut to whole 2 × 2 cells of the mosaic (``cfa`` set; as given otherwise).

        Examples
        --------
        >>> region = ReferenceRegion((3, 4, 17, 16), None, "--reference-patch 3,4,17,16")
        >>> region.cells("RGGB"), region.cells(None)
        ((4, 4, 14, 16), (3, 4, 17, 16))
        """
        x, y, width, height = self.rect
        if cfa is None:
            return self.rect
        return x + x % 2, y + y % 2, width - width % 2 - 2 * (x % 2), height - height % 2 - 2 * (y % 2)

    def check_inside(self, cfa: str | None, frame_height: int, frame_width: int) -> ReferenceRect:
        """:meth:`cells`, checked to lie inside a ``frame_width`` × ``frame_height`` frame.

        Raises
        ------
        UsageError
            A rectangle outside the frame or smaller than :data:`MIN_SIDE` × :data:`MIN_SIDE` pixels (named as
            :attr:`what`, with the frame's size).
        """
        x, y, width, height = self.cells(cfa)
        if (
            x < 0
            or y < 0
            or width < MIN_SIDE
            or height < MIN_SIDE
            or x + width > frame_width
            or y + height > frame_height
        ):
            raise UsageError(
                f"{self.what}: expected x,y,width,height of at least {MIN_SIDE} × {MIN_SIDE} pixels inside the "
                f"{frame_width} × {frame_height} frame"
            )
        return x, y, width, height


def patch_region(rect: ReferenceRect) -> ReferenceRegion:
    """``--reference-patch X,Y,W,H``: a spectrally flat card (a grey or white card)."""
    x, y, width, height = (int(v) for v in rect)
    return ReferenceRegion((x, y, width, height), None, f"--reference-patch {','.join(map(str, rect))}")


def _chart_patch(patch: object, where: str) -> tuple[ReferenceRect, np.ndarray, np.ndarray]:
    """One patch of a reference chart: its rectangle, wavelengths (increasing) and reflectance factors."""
    if not isinstance(patch, dict) or not {"rect", "wavelengths_nm", "reflectance"} <= set(patch):
        raise UsageError(f"{where}: is {str(patch)[:60]}; expected an object with rect, wavelengths_nm and reflectance")
    rect, nm, values = patch["rect"], patch["wavelengths_nm"], patch["reflectance"]

    def numbers(value: object) -> bool:
        return isinstance(value, list) and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)

    if not numbers(rect) or len(rect) != 4 or not all(float(v).is_integer() and abs(v) < 2**31 for v in rect):
        raise UsageError(f"{where}.rect: is {str(rect)[:60]}; expected 4 whole numbers x, y, width, height (pixels)")
    if not numbers(nm) or not numbers(values) or len(nm) != len(values) or len(nm) < 2:
        raise UsageError(
            f"{where}: wavelengths_nm and reflectance are not two lists of numbers of one length (at least 2); "
            "expected one reflectance per wavelength"
        )
    wavelengths, reflectance = np.asarray(nm, float), np.asarray(values, float)
    if not np.all(np.diff(wavelengths) > 0):
        raise UsageError(f"{where}.wavelengths_nm: not increasing; expected wavelengths in increasing order")
    if reflectance.min() < 0 or reflectance.max() > MAX_REFLECTANCE:
        raise UsageError(
            f"{where}.reflectance: holds values from {reflectance.min():g} to {reflectance.max():g}; expected "
            f"reflectance factors 0–{MAX_REFLECTANCE:g} (not percent)"
        )
    return (int(rect[0]), int(rect[1]), int(rect[2]), int(rect[3])), wavelengths, reflectance


def chart_regions(sequence: Sequence, path: str) -> tuple[ReferenceRegion, ...]:
    """``--reference-chart FILE``: the patches of known reflectance (a colour chart in the scene) it lists.

    The file is JSON: ``{"patches": [{"rect": [x, y, width, height], "wavelengths_nm": [...], "reflectance":
    [...]}, ...]}`` (pixels of the full frame, whole numbers; wavelengths increasing; reflectance factors
    0–:data:`MAX_REFLECTANCE`, interpolated onto the sequence's grid, the edge values held beyond the data).
    It is read as every user's file is (:mod:`processing.user_files`, :mod:`processing.json_input`).

    Raises
    ------
    UsageError
        An unreadable file, a missing or malformed field (named).
    """
    shown = f"--reference-chart {shown_path(path)}"
    text = read_user_text(path, "a reference chart (UTF-8 JSON)", JSON_MAX_BYTES, UsageError)
    document = parse_json_document(text, shown, UsageError)
    patches = document.get("patches") if isinstance(document, dict) else None
    if not isinstance(patches, list) or not patches:
        raise UsageError(f"{shown}: 'patches' missing or empty; expected a list of patches")
    grid = np.asarray(sequence.wavelengths_nm, float)
    regions = []
    for index, patch in enumerate(patches):
        where = f"{shown}: patches[{index}]"
        rect, nm, values = _chart_patch(patch, where)
        regions.append(ReferenceRegion(rect, np.interp(grid, nm, values), where))
    return tuple(regions)


def declared_frame_size(sequence: Sequence) -> tuple[int, int] | None:
    """``(height, width)`` of the frames the estimate uses, from the first one's header (nothing decoded); None when
    the header cannot be read (the frame's own read then says why, in sequence order)."""
    index = next((i for i, entry in enumerate(sequence.frames) if entry.role in ("ambient", "led")), None)
    if index is None:
        return None
    try:
        header = read_image_header(sequence.frame_path(index))
    except RecordingError:
        return None
    return header.height, header.width


class ReferenceCrops:
    """The reference rectangles' pixels, cropped from each frame the LED estimate's stream uses (module notes).

    Fed by :meth:`EstimateStream.add <acquisition.session.estimate_stream.EstimateStream.add>` with the frame's row
    (LED frame ``j`` is row ``j``, the ambient row ``n``, the LED frame count) and its pixels as the sequence
    records them; keeps a copy of each rectangle (the frame is not referenced after :meth:`add` returns).

    Parameters
    ----------
    header
        The sequence (its CFA, LEDs and camera responsivities).
    regions
        The rectangles, in order.
    combined
        Whether the regions are one chart's patches, whose equations are stacked (:meth:`ReferencePatch.combined`),
        rather than one ``--reference-patch`` card.
    """

    def __init__(self, header: Sequence, regions: Seq[ReferenceRegion], combined: bool) -> None:
        if not regions:
            raise UsageError(f"{header.path}: no reference rectangle; expected a patch or a chart's patches")
        self.header = header
        self.regions = tuple(regions)
        self.combined = combined
        self._cropped: tuple[ReferenceRect, ...] | None = None  # the rectangles checked against the frame size
        self._crops: dict[int, tuple[np.ndarray, ...]] = {}

    @classmethod
    def of(cls, sequence: Sequence, reference: Reference) -> ReferenceCrops:
        """The crops of ``--reference-patch`` (a rectangle) or ``--reference-chart`` (a path): the chart file read
        and every rectangle checked against the frame size its files' headers declare, before any frame is decoded.

        Raises
        ------
        UsageError
            A chart file unreadable or malformed, a rectangle outside the frame or too small (one line, named).
        """
        if isinstance(reference, str):
            crops = cls(sequence, chart_regions(sequence, reference), combined=True)
        else:
            crops = cls(sequence, (patch_region(reference),), combined=False)
        size = declared_frame_size(sequence)
        if size is not None:
            crops.check_frame(*size)
        return crops

    def check_frame(self, frame_height: int, frame_width: int) -> None:
        """Every rectangle checked inside a frame of this size (:meth:`ReferenceRegion.check_inside`; the first
        refused one named), and kept as cut to whole CFA cells."""
        cfa = self.header.camera.cfa
        self._cropped = tuple(region.check_inside(cfa, frame_height, frame_width) for region in self.regions)

    def add(self, row: int, pixels: np.ndarray) -> None:
        """Keep each rectangle of frame ``row``'s ``pixels`` ((H, W) mosaic or mono, (H, W, 3) RGB; a mono frame's
        crops as the sequence records it, three alike channels: :func:`~acquisition.sequence.writer.as_recorded`).

        Raises
        ------
        UsageError
            A rectangle outside this frame (at the first frame, when the headers did not say the size).
        """
        if self._cropped is None or not self._crops:
            self.check_frame(*pixels.shape[:2])
        assert self._cropped is not None
        cfa = self.header.camera.cfa
        self._crops[row] = tuple(
            as_recorded(np.array(pixels[y : y + height, x : x + width]), cfa) for x, y, width, height in self._cropped
        )

    @property
    def nbytes(self) -> int:
        """Bytes the crops hold."""
        return sum(crop.nbytes for crops in self._crops.values() for crop in crops)

    def patch(self, spec: FrameStackSpec, flicker: FlickerCheck | None = None) -> ReferencePatch:
        """The reference (:class:`~processing.reference_patch.ReferencePatch`) of the crops, every rectangle's channel
        statistics corrected for ``flicker``'s gains (the LED estimate's check); a chart's patches combined.

        ``spec``: the linearisation of the frames fed (the stream's :meth:`layout`), whose ``len(led_scales)`` LED
        frames and ambient frame must all have been cropped.

        Raises
        ------
        UsageError
            A rectangle whose pixels are saturated in some frame, or whose LED images hold no light.
        RecordingError
            A frame of ``spec`` that was not fed to :meth:`add`.
        """
        n = len(spec.led_scales)
        missing = [row for row in range(n + 1) if row not in self._crops]
        if missing:
            raise RecordingError(
                f"{self.header.path}: the reference crops hold {n + 1 - len(missing)} of the {n + 1} ambient and LED "
                "frames; expected the stream to feed every frame it uses"
            )
        cfa = self.header.camera.cfa
        leds, camera = led_spectra_photons(self.header), camera_responsivities_photons(self.header)  # for every patch
        patches = []
        for index, region in enumerate(self.regions):
            statistics = accumulate_channel_statistics(
                self._crops[n][index],
                [self._crops[j][index] for j in range(n)],
                spec,
                cfa=cfa,
                bin_factor=PATCH_BIN_FACTOR,
                n_folds=PATCH_FOLDS,
            )
            statistics = corrected_channel_statistics(statistics, flicker)
            if statistics.n_blocks == 0:
                raise UsageError(
                    f"{region.what}: every pixel of the patch is saturated in some frame; expected a surface below the "
                    "white level"
                )
            try:
                patch = ReferencePatch.of(statistics, leds, camera, region.reflectance)
            except SpectralDataError as error:
                raise UsageError(f"{region.what}: {error}") from None
            patches.append(patch)
        return ReferencePatch.combined(patches) if self.combined else patches[0]
