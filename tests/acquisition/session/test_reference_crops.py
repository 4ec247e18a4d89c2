"""A reference patch or chart read from the one stream of the frames (issue 31, ``acquisition/session/reference_crops.py``).

``estimate --model prior|family|auto --reference-patch|--reference-chart`` loaded the whole frame stack only to crop
it; the rectangles are now copied from each frame as the LED estimate's stream takes it. The reference's numbers are
the stack's crops' to the bit (computed here the old way, from a loaded stack), the frames are decoded once and never
held together (tracemalloc), and the rectangle checks still give their one line, exit 2 — a rectangle outside the
frame before any frame is decoded.
"""

from __future__ import annotations

import json
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.app.cli_common import dumps_json
from msflash.acquisition.errors import UsageError
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import analysis
from msflash.acquisition.session.analysis import FrameStack, load_frame_stack
from msflash.acquisition.session.prior_route import (
    estimate_sequence_family,
    family_payload,
    light_model_stream,
    sequence_channel_statistics,
)
from msflash.acquisition.session.reference_crops import ReferenceCrops, patch_region
from msflash.acquisition.session.sequence_spectra import camera_responsivities_photons, led_spectra_photons
from msflash.processing.channel_statistics import accumulate_channel_statistics
from msflash.processing.flicker import FlickerCheck, corrected_channel_statistics
from msflash.processing.reference_patch import ReferencePatch
from tests.acquisition.session.test_estimate_stream import N_LED_FRAMES, SHAPE, write_sequence
from tests.helpers import rewrite_sequence
from tests.processing.unseen_sequences import Case, render_case


def _estimate(capsys: pytest.CaptureFixture[str], *args: str) -> dict:
    assert main(["estimate", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _refused(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    """The one error line of ``estimate ARGS`` (exit 2)."""
    capsys.readouterr()
    assert main(["estimate", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def _stack_patch(
    sequence: Sequence,
    stack: FrameStack,
    rect: tuple[int, int, int, int],
    reflectance: np.ndarray | None,
    flicker: FlickerCheck | None,
) -> ReferencePatch:
    """The reference as main computed it (``prior_route.reference_patch`` at 4bed5cc): the loaded stack's frames
    cropped, their channel statistics at 2 × 2 blocks and two folds, corrected for the flicker."""
    x, y, width, height = rect
    if sequence.camera.cfa is not None:
        x, y, width, height = x + x % 2, y + y % 2, width - width % 2 - 2 * (x % 2), height - height % 2 - 2 * (y % 2)

    def crop(frame: np.ndarray) -> np.ndarray:
        return frame[y : y + height, x : x + width]

    statistics = accumulate_channel_statistics(
        crop(stack.ambient),
        [crop(frame) for frame in stack.led_frames],
        stack.spec,
        cfa=sequence.camera.cfa,
        bin_factor=2,
        n_folds=2,
    )
    statistics = corrected_channel_statistics(statistics, flicker)
    return ReferencePatch.of(
        statistics, led_spectra_photons(sequence), camera_responsivities_photons(sequence), reflectance
    )


def _same_patch(ours: ReferencePatch, theirs: ReferencePatch) -> None:
    assert np.array_equal(ours.design, theirs.design) and np.array_equal(ours.target, theirs.target)
    assert ours.led_misfit == theirs.led_misfit


@pytest.mark.parametrize("kind", ["patch", "chart"])
def test_the_reference_is_the_stacks_crops_to_the_bit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str
) -> None:
    """The harness's scenes with a white card (RGB) and with a chart of 22 of its surfaces (a raw mosaic, specular):
    ``estimate --model family`` with the reference prints the family block main printed — the family model fitted
    with the reference computed the old way, from the loaded stack's crops — to the last digit."""
    from tests.harness.physics_cases import physics_cases_of
    from tests.harness.render import REFERENCE_CHART_FILE, REFERENCE_PATCH_FILE, render

    cases = physics_cases_of("tuning")
    case = cases[5] if kind == "patch" else next(c for c in cases if c.specular and c.cfa is not None)
    truth = render(case, tmp_path / "scene")
    sequence = read_sequence(truth.directory)
    if kind == "patch":
        rect = tuple(json.loads((truth.directory / REFERENCE_PATCH_FILE).read_text()))
        option = ["--reference-patch", ",".join(map(str, rect))]
        regions = [(rect, None)]
    else:
        chart = truth.directory / REFERENCE_CHART_FILE
        option = ["--reference-chart", str(chart)]
        grid = np.asarray(sequence.wavelengths_nm, float)
        regions = [
            (tuple(p["rect"]), np.interp(grid, p["wavelengths_nm"], p["reflectance"]))
            for p in json.loads(chart.read_text())["patches"]
        ]
    printed = _estimate(capsys, str(truth.directory), "--model", "family", *option)

    stack = load_frame_stack(sequence)
    flicker = analysis.estimate_sequence(sequence).flicker
    patches = [_stack_patch(sequence, stack, rect, reflectance, flicker) for rect, reflectance in regions]
    old = patches[0] if kind == "patch" else ReferencePatch.combined(patches)
    crops = ReferenceCrops.of(sequence, option[1] if kind == "chart" else rect)
    stream = light_model_stream(sequence, None, references=crops)
    _same_patch(crops.patch(stream.layout().spec, flicker), old)
    statistics = sequence_channel_statistics(sequence, stack, flicker=flicker)
    _, family = estimate_sequence_family(sequence, stack, None, old, flicker, statistics)
    assert printed["family"] == json.loads(dumps_json({"family": family_payload(sequence, family)}))["family"]
    assert printed["family"]["reference"]["equations"] == (4 if case.cfa else 3) * len(regions)


def _crop_counting(monkeypatch: pytest.MonkeyPatch) -> tuple[list[int], list[int]]:
    """Frames decoded (indices) and frame stacks built from now on."""
    decoded: list[int] = []
    stacks: list[int] = []
    real_load, real_stack = Sequence.load_frame, analysis.frame_stack

    def counted_load(self: Sequence, index: int, **kwargs: bool) -> np.ndarray:
        decoded.append(index)
        return real_load(self, index, **kwargs)

    def counted_stack(layout, pixels: Callable[[int], np.ndarray]) -> FrameStack:  # noqa: ANN001 — a StackLayout
        stacks.append(len(layout.led_indices) + 1)
        return real_stack(layout, pixels)

    monkeypatch.setattr(Sequence, "load_frame", counted_load)
    monkeypatch.setattr(analysis, "frame_stack", counted_stack)
    return decoded, stacks


@pytest.fixture(scope="module")
def raw_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An 80 × 88 GRBG mosaic of CIE A (tests.processing.unseen_sequences), written by the project's writer."""
    return render_case(Case("a", light="A", seed=5, cfa="GRBG"), tmp_path_factory.mktemp("raw") / "a").directory


def _chart(tmp_path: Path, rects: list[list[int]]) -> Path:
    path = tmp_path / "chart.json"
    patches = [{"rect": rect, "wavelengths_nm": [400, 700], "reflectance": [0.5, 0.5]} for rect in rects]
    path.write_text(json.dumps({"patches": patches}))
    return path


@pytest.mark.parametrize("kind", ["patch", "chart"])
def test_a_rectangle_outside_the_frame_is_refused_before_any_frame_is_decoded(
    raw_sequence: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, kind: str
) -> None:
    """The frame size is read from the first frame's header: a rectangle outside the 88 × 80 frame is refused
    before any frame is decoded (main decoded the whole stack, and estimated the LEDs' side, first)."""
    decoded, stacks = _crop_counting(monkeypatch)
    if kind == "patch":
        line = _refused(capsys, str(raw_sequence), "--model", "family", "--reference-patch", "70,10,20,20")
        assert line.endswith(
            "--reference-patch 70,10,20,20: expected x,y,width,height of at least 8 × 8 pixels inside the 88 × 80 frame"
        )
    else:
        chart = _chart(tmp_path, [[4, 4, 16, 16], [30, 70, 16, 16]])
        line = _refused(capsys, str(raw_sequence), "--model", "auto", "--reference-chart", str(chart))
        assert f"--reference-chart {chart}: patches[1]: expected x,y,width,height" in line and "88 × 80" in line
    assert decoded == [] and stacks == []


@pytest.mark.parametrize(
    ("rect", "why"),
    [("10,10,7,20", "narrower than 8"), ("10,10,20,6", "shorter than 8"), ("2,74,20,8", "past the bottom of the frame"),
     ("11,11,9,9", "9 × 9 cut to whole 2 × 2 cells of the mosaic: 6 × 6")],
)  # fmt: skip
def test_a_reference_rectangle_too_small_is_refused_in_one_line(
    raw_sequence: Path, capsys: pytest.CaptureFixture[str], rect: str, why: str
) -> None:
    line = _refused(capsys, str(raw_sequence), "--model", "prior", f"--reference-patch={rect}")
    assert f"--reference-patch {rect}: expected x,y,width,height of at least 8 × 8 pixels inside the 88 × 80" in line


def test_a_rectangle_is_checked_at_the_first_frame_when_no_header_said_the_size(raw_sequence: Path) -> None:
    """Crops made without the headers' size (:class:`ReferenceCrops` itself) check each rectangle at the first
    frame they are fed, and keep a copy, not a view of the frame."""
    sequence = read_sequence(raw_sequence)
    inside = ReferenceCrops(sequence, (patch_region((3, 5, 20, 17)),), combined=False)
    frame = np.arange(80 * 88, dtype=np.uint16).reshape(80, 88)
    inside.add(0, frame)
    assert inside.nbytes == 18 * 14 * 2  # (3, 5, 20, 17) cut to whole 2 × 2 cells: (4, 6, 18, 14)
    frame[:] = 0  # the crop is its own copy
    assert inside._crops[0][0].max() > 0
    outside = ReferenceCrops(sequence, (patch_region((80, 5, 20, 17)),), combined=False)
    with pytest.raises(UsageError, match=r"--reference-patch 80,5,20,17: .* inside the 88 × 80 frame"):
        outside.add(0, frame)


def _with_saturated_card(source: Path, target: Path, rect: tuple[int, int, int, int]) -> Path:
    """``source`` written again by the project's writer with ``rect`` at the white level in every LED frame."""
    x, y, width, height = rect
    white = read_sequence(source).camera.white_level

    def saturated(index: int, role: str, pixels: np.ndarray) -> np.ndarray:
        pixels = pixels.copy()
        if role == "led":
            pixels[y : y + height, x : x + width] = white
        return pixels

    return rewrite_sequence(source, target, saturated)


def test_a_saturated_reference_is_refused_in_one_line(
    raw_sequence: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    saturated = _with_saturated_card(raw_sequence, tmp_path / "saturated", (20, 20, 24, 24))
    line = _refused(capsys, str(saturated), "--model", "family", "--reference-patch", "22,22,20,20")
    assert "--reference-patch 22,22,20,20: every pixel of the patch is saturated in some frame" in line
    chart = _chart(tmp_path, [[50, 4, 16, 16], [20, 20, 24, 24]])
    line = _refused(capsys, str(saturated), "--model", "auto", "--reference-chart", str(chart))
    assert f"--reference-chart {chart}: patches[1]: every pixel of the patch is saturated" in line


def test_the_reference_keeps_no_frame_stack(tmp_path: Path) -> None:
    """tracemalloc: the light models' stream with a reference's crops, and the reference, peak at a few frames plus
    the statistics and the crops on a 33-frame sequence (the stack route held all 33 frames)."""
    sequence = read_sequence(write_sequence(tmp_path / "s"))
    frame_bytes = int(np.prod(SHAPE)) * 2
    chart = _chart(tmp_path, [[10, 10, 64, 48], [300, 200, 40, 40]])

    def reference() -> tuple[ReferencePatch, int]:
        crops = ReferenceCrops.of(sequence, str(chart))
        stream = light_model_stream(sequence, None, references=crops)
        return crops.patch(stream.layout().spec), stream.nbytes + crops.nbytes  # its rows are the light models' here

    first, held = reference()  # warm: lazy imports, caches
    tracemalloc.start()
    try:
        again, _ = reference()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    _same_patch(again, first)
    assert peak < 3 * frame_bytes + held < (N_LED_FRAMES + 1) * frame_bytes / 2, (peak / frame_bytes, held)
