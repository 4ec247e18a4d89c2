"""A synthesis from weights given alone reads each frame once (issue 31: no second pass).

``msflash synthesize SEQ --weights …`` and :func:`msflash.synthesize_flash` check the frames for flicker and sum
them: each ambient and LED frame, decoded once, feeds both the estimate's statistics and the synthesis sum
(:func:`acquisition.session.analysis.synthesize_checked`). Before, the check streamed the sequence and the sum read
it again: two reads of every used frame. The image is the two-pass image bit for bit where nothing is corrected
and to one float32 rounding step where flicker is.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import msflash
from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.acquisition.session import analysis
from msflash.acquisition.session.estimate_stream import stream_sequence
from msflash.acquisition.session.rig import open_sim_rig

WEIGHTS = np.array([0.4, 0.7, 0.2, 0.5, 0.3, 0.6, 0.1])
"""Flash weights for the sim rig's seven LEDs."""


def count_reads(monkeypatch: pytest.MonkeyPatch) -> Counter[int]:
    """Every frame decoded from now on, by index (the sequence's one frame reader, wrapped; it still reads)."""
    reads: Counter[int] = Counter()
    real = Sequence.load_frame

    def counted(self: Sequence, index: int, **options: bool) -> np.ndarray:
        reads[index] += 1
        return real(self, index, **options)

    monkeypatch.setattr(Sequence, "load_frame", counted)
    return reads


def recorded_run(path: Path, *flicker: str) -> Path:
    """A sim run (raw RGGB, camera responsivities recorded) with the lamp steady or flickering; its sequence."""
    assert main(["run", "--out", str(path), "--exposure", "2000", "--seed", "2", *flicker]) == 0
    return path / "sequence"


def two_passes(sequence: Sequence, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, analysis.StackLayout, object]:
    """What ``synthesize`` did before: the flicker check's pass, then the sum's."""
    check = None
    if sequence.camera_responsivities() is not None:
        statistics = stream_sequence(sequence, analysis.DEFAULT_BIN_FACTOR).statistics()
        check = analysis.flicker_check(sequence, statistics)
    image, saturated, layout = analysis.synthesize_sequence(sequence, weights, flicker=check)
    return image, saturated, layout, check


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("runs")
    return {
        "steady": recorded_run(root / "steady"),
        "flickering": recorded_run(root / "flickering", "--flicker", "100:0.3"),
    }


def test_synthesize_reads_each_used_frame_once(
    runs: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The CLI and the API decode the ambient and every LED frame once (two passes read each twice)."""
    sequence_path = runs["flickering"]
    used = {i for i, e in enumerate(read_sequence(sequence_path).frames) if e.role in ("ambient", "led")}
    reads = count_reads(monkeypatch)
    two_passes(read_sequence(sequence_path), WEIGHTS)
    assert set(reads) == used and set(reads.values()) == {2}  # the counter counts: the old route's two reads
    reads.clear()
    argv = ["synthesize", str(sequence_path), "--weights=" + ",".join(map(str, WEIGHTS))]
    assert main([*argv, "--out", str(tmp_path / "flash.exr")]) == 0
    assert "msflash: flicker: the LED frames saw" in capsys.readouterr().err  # the check still runs and says so
    assert set(reads) == used and set(reads.values()) == {1}, reads
    reads.clear()
    msflash.synthesize_flash(read_sequence(sequence_path), WEIGHTS)
    assert set(reads) == used and set(reads.values()) == {1}, reads


def test_the_one_read_image_is_the_two_pass_image(runs: dict[str, Path]) -> None:
    """Steady lamp: the same image bit for bit (nothing corrected). Flickering lamp: the same check, the image
    to one float32 rounding step (the ambient's share taken out after the pass); the saturated pixels and the
    frames used the same in both."""
    for name, corrected in (("steady", False), ("flickering", True)):
        sequence = read_sequence(runs[name])
        image, saturated, layout, check = analysis.synthesize_checked(sequence, WEIGHTS)
        before, saturated_before, layout_before, check_before = two_passes(sequence, WEIGHTS)
        assert check is not None and check_before is not None
        assert check.corrected == check_before.corrected == corrected
        assert check.to_dict() == check_before.to_dict()
        np.testing.assert_array_equal(saturated, saturated_before)
        assert (layout.ambient_index, layout.led_indices) == (layout_before.ambient_index, layout_before.led_indices)
        assert image.dtype == before.dtype == np.float32
        if not corrected:
            np.testing.assert_array_equal(image, before)
            continue
        # The flash part the correction changes is large (percent of the image), the difference one rounding step.
        assert np.abs(before - analysis.synthesize_sequence(sequence, WEIGHTS)[0]).max() > 1e-3 * np.abs(before).max()
        np.testing.assert_allclose(image, before, rtol=2.5e-7, atol=1e-12 * float(np.abs(before).max()))


def test_led_frames_recorded_before_the_ambient_are_summed_after_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A sequence whose LED frames come before its ambient frame (another writer's order): each frame still read
    once, the image the two-pass one bit for bit (the sum still adds the ambient first)."""
    with open_sim_rig(n_leds=3, seed=3, cfa=None) as rig:
        wavelengths, camera, leds = rig.sequence_header()
        black = int(rig.camera.info.black_level)
    rng = np.random.default_rng(5)
    shape = (48, 64, 3)
    scene = rng.uniform(0.2, 1.0, size=shape)
    path = tmp_path / "led-first"
    with SequenceWriter(path, wavelengths_nm=wavelengths, spectral_unit="energy", camera=camera, leds=leds) as writer:
        for j in range(3):
            frame = black + 900 * scene + 300 * scene[:, :, (j,)] + rng.normal(0, 3, shape)
            writer.add_frame(frame.astype(np.uint16), "led", tuple(float(i == j) for i in range(3)), 2000.0)
        writer.add_frame((black + 900 * scene).astype(np.uint16), "ambient", (0.0,) * 3, 1000.0)
        writer.finish()
    sequence = read_sequence(path)
    weights = np.array([0.5, 0.25, 0.75])
    before, saturated_before, _, check_before = two_passes(sequence, weights)
    reads = count_reads(monkeypatch)
    image, saturated, layout, check = analysis.synthesize_checked(sequence, weights)
    assert dict(reads) == {0: 1, 1: 1, 2: 1, 3: 1}
    assert layout.ambient_index == 3 and layout.led_indices == (0, 1, 2)
    assert (check is None) == (check_before is None)
    if check is not None and check_before is not None:
        assert check.to_dict() == check_before.to_dict()
    if check is None or not check.corrected:
        np.testing.assert_array_equal(image, before)
    else:
        np.testing.assert_allclose(image, before, rtol=2.5e-7, atol=1e-12 * float(np.abs(before).max()))
    np.testing.assert_array_equal(saturated, saturated_before)


def test_the_one_read_keeps_a_few_frames_whatever_the_frame_count(tmp_path: Path) -> None:
    """tracemalloc on a 33-frame RGB sequence: the float64 sum (4 frames' worth), the ambient frame kept for the
    check, one frame being read, the float32 image (2) and the statistics' block rows — not the stack."""
    import tracemalloc

    from tests.acquisition.session.test_estimate_stream import N_LED_FRAMES, SHAPE, write_sequence

    sequence = read_sequence(write_sequence(tmp_path / "s"))
    weights = np.array([0.3, 0.6, 0.2, 0.9])
    frame_bytes = int(np.prod(SHAPE)) * 2
    analysis.synthesize_checked(sequence, weights)  # warm: lazy imports, caches
    statistics = analysis.stream_sequence(sequence, analysis.DEFAULT_BIN_FACTOR).nbytes
    tracemalloc.start()
    try:
        image, _, _, check = analysis.synthesize_checked(sequence, weights)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert check is not None and image.shape == SHAPE
    # Measured 9 frames' worth at 1280 × 1024 × 15 frames (the two passes 6): the sum, the kept ambient frame and the
    # block rows live together during the pass.
    assert peak < 10 * frame_bytes + statistics < (N_LED_FRAMES + 1) * frame_bytes / 2, peak / frame_bytes
