"""Async writer (order, drain on exception, back-pressure) and the one-stream flash in each sync mode."""

from __future__ import annotations

import gc
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.errors import FrameLostError, RecordingError
from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.acquisition.session.capture import run_capture_with_flash
from msflash.acquisition.session.flash_session import FlashSession
from msflash.acquisition.session.rig import open_sim_rig
from tests.acquisition.support.capture_doubles import FixedFlash
from tests.helpers import sequence_statistics


def _writer(rig, path: Path) -> SequenceWriter:
    wavelengths, camera, leds = rig.sequence_header()
    return SequenceWriter(path, wavelengths_nm=wavelengths, spectral_unit="energy", camera=camera, leds=leds)


@pytest.fixture
def sim_rig():
    """The sim rig as it comes: a 12-bit raw RGGB camera."""
    with open_sim_rig(n_leds=4, seed=3) as rig:
        yield rig


@pytest.fixture
def rgb_sim_rig():
    """The sim rig with RGB frames (``--cfa none``): a mono camera's sequences are recorded as RGB."""
    with open_sim_rig(n_leds=4, seed=3, cfa=None) as rig:
        yield rig


def _shape(rig) -> tuple[int, ...]:
    """The frames of the rig's camera: (H, W) for its raw mosaic (the sim rig's default), (H, W, 3) for RGB."""
    info = rig.camera.info
    return (info.height, info.width) if info.cfa is not None else (info.height, info.width, 3)


def _pixels(rig, value: int) -> np.ndarray:
    """A frame of the rig's camera, every sample ``value`` above its black level."""
    return np.full(_shape(rig), rig.camera.info.black_level + value, dtype=np.uint16)


def _value(rig, frame: np.ndarray) -> int:
    """The first sample of a frame of :func:`_pixels`, less the black level."""
    return int(frame.flat[0] - rig.camera.info.black_level)


def test_async_writer_keeps_order_and_drains_on_exception(sim_rig, tmp_path: Path) -> None:
    levels = (0.0,) * 4
    with (
        pytest.raises(KeyboardInterrupt),
        _writer(sim_rig, tmp_path / "s") as inner,
        AsyncSequenceWriter(inner, max_queued=2) as writer,
    ):
        for value in range(5):
            entry = writer.add_frame(_pixels(sim_rig, 100 + value), "ambient", levels, 1000.0 + value)
            assert entry.file == f"frames/{value:03d}-ambient.tiff"
        raise KeyboardInterrupt
    sequence = read_sequence(tmp_path / "s")
    assert not sequence.complete
    assert [f.exposure_us for f in sequence.frames] == [1000.0 + v for v in range(5)]
    assert [_value(sim_rig, sequence.load_frame(i)) for i in range(5)] == [100 + v for v in range(5)]


def test_async_writer_applies_back_pressure_instead_of_dropping(sim_rig, tmp_path: Path) -> None:
    inner = _writer(sim_rig, tmp_path / "s")
    gate = threading.Event()
    real_add = inner.add_frame

    def slow_add(*args, **kwargs):
        gate.wait()
        return real_add(*args, **kwargs)

    inner.add_frame = slow_add  # type: ignore[method-assign]
    writer = AsyncSequenceWriter(inner, max_queued=1)
    blocked = threading.Event()
    done = threading.Event()

    def produce() -> None:
        for value in range(3):
            if value == 2:
                blocked.set()
            writer.add_frame(_pixels(sim_rig, value), "ambient", (0.0,) * 4, 1000.0)
        done.set()

    thread = threading.Thread(target=produce)
    thread.start()
    assert blocked.wait(10)
    assert not done.wait(0.2)  # one frame being written, one queued: the third waits for room
    gate.set()
    thread.join(10)
    assert done.is_set()
    writer.finish()
    assert len(read_sequence(tmp_path / "s").frames) == 3


def test_async_writer_reports_a_write_error(sim_rig, tmp_path: Path) -> None:
    from msflash.acquisition.errors import RecordingError

    with _writer(sim_rig, tmp_path / "s") as inner, pytest.raises(RecordingError, match="writing a frame failed"):
        writer = AsyncSequenceWriter(inner)
        writer.add_frame(np.zeros((2, 2), dtype=np.uint16), "ambient", (0.0,) * 4, 1000.0)
        writer.add_frame(np.zeros((4, 4), dtype=np.uint16), "ambient", (0.0,) * 4, 1000.0)  # size mismatch
        writer.finish()


@pytest.mark.parametrize("trigger", ["software", "booth", "camera"])
def test_flash_in_the_same_stream(sim_rig, tmp_path: Path, trigger: str) -> None:
    plan = CapturePlan.ambient_then_each_led(4, 10_000.0, trigger=trigger)
    flash = (0.25, 0.5, 0.0, 1.0)
    with _writer(sim_rig, tmp_path / "s") as inner, AsyncSequenceWriter(inner) as writer:
        session = FlashSession.prepare(writer.sequence)

        def check() -> None:
            assert not gc.isenabled()  # no collection pause between the last LED frame and the flash
            # The booth holds the flash step: nothing exposed with stale levels meanwhile.
            if trigger != "software":
                assert sim_rig.emulator.levels == (0.0,) * 4 or sim_rig.emulator.holding is None
            decision = session.decide("complementary")
            assert decision.levels.shape == (4,)

        decider = FixedFlash(flash, 8_192.0, check)
        entries = run_capture_with_flash(
            sim_rig.camera, sim_rig.booth, plan, writer, decider, handlers=(session, decider)
        )
        writer.finish()
    seen = decider.seen
    assert seen == [5] and gc.isenabled()
    assert [e.role for e in entries] == ["ambient"] + ["led"] * 4 + ["flash"]
    sequence = read_sequence(tmp_path / "s")
    assert sequence.complete and sequence.frames[-1].role == "flash"
    assert sequence.frames[-1].exposure_us == 8_192.0 or trigger == "booth"
    # The camera exposed the flash under exactly the levels decided (within one 16-bit step).
    np.testing.assert_allclose(sim_rig.camera.rendered_levels[-1], flash, atol=1 / 65535)
    np.testing.assert_allclose(sequence.frames[-1].led_levels, flash)
    assert not sim_rig.line_errors


@pytest.mark.parametrize("lost", ["led", "flash"])
@pytest.mark.parametrize("trigger", ["software", "booth", "camera"])
def test_a_frame_lost_in_the_flash_stream_is_taken_again(sim_rig, tmp_path: Path, trigger: str, lost: str) -> None:
    """The last LED frame or the flash frame arrives incomplete once: the retake captures it (and
    the flash) anew; a lost flash is decided again from the same frames, a lost LED frame once."""
    plan = CapturePlan.ambient_then_each_led(4, 10_000.0, trigger=trigger)
    flash = (0.25, 0.5, 0.0, 1.0)
    target = plan.steps[-1].led_levels if lost == "led" else flash
    camera = sim_rig.camera
    real_next = camera.next_frame
    losses: list[int] = []

    def losing_next(timeout_s: float):
        frame = real_next(timeout_s)
        # The sim camera numbers its renders from 1 (booth master renders on the booth's pulses).
        if not losses and np.allclose(camera.rendered_levels[frame.frame_id - 1], target, atol=1 / 65535):
            losses.append(frame.frame_id)
            raise FrameLostError(f"camera: frame {frame.frame_id} arrived incomplete")
        return frame

    camera.next_frame = losing_next
    decider = FixedFlash(flash, 8_192.0)
    with _writer(sim_rig, tmp_path / "s") as inner, AsyncSequenceWriter(inner) as writer:
        entries = run_capture_with_flash(camera, sim_rig.booth, plan, writer, decider, handlers=(decider,))
        writer.finish()
    seen = decider.seen
    assert len(losses) == 1
    assert seen == ([5] if lost == "led" else [5, 5])
    assert [e.role for e in entries] == ["ambient"] + ["led"] * 4 + ["flash"]
    sequence = read_sequence(tmp_path / "s")
    assert sequence.complete
    retaken = [0] * 4 + [1, 1] if lost == "led" else [0] * 5 + [1]
    assert [f.extra.get("retake", 0) for f in sequence.frames] == retaken
    np.testing.assert_allclose(sequence.frames[-1].led_levels, flash)
    np.testing.assert_allclose(camera.rendered_levels[-1], flash, atol=1 / 65535)
    assert sim_rig.emulator.levels == (0.0,) * 4
    assert not sim_rig.line_errors


def test_flash_session_matches_the_sequence_path(sim_rig, tmp_path: Path) -> None:
    from msflash.acquisition.session import analysis
    from msflash.acquisition.session.capture import run_capture

    plan = CapturePlan.ambient_then_each_led(4, 10_000.0)
    with _writer(sim_rig, tmp_path / "s") as writer:
        session = FlashSession.prepare(writer.sequence)
        run_capture(
            sim_rig.camera,
            sim_rig.booth,
            plan,
            writer,
            handlers=(session,),
        )
        writer.finish()
    sequence = read_sequence(tmp_path / "s")
    reference = analysis.estimate_sequence(sequence)
    estimate = session.estimate()
    # One accumulator fed the same frames in the same order: the same numbers to the last digit.
    np.testing.assert_array_equal(estimate.ambient_weights, reference.ambient_weights)
    np.testing.assert_array_equal(estimate.spectrum_std, reference.spectrum_std)
    expected = analysis.solve_sequence_flash(sequence, "complementary", reference.ambient_weights)
    np.testing.assert_allclose(
        session.solve("complementary", estimate.ambient_weights).flash_weights,
        expected.flash_weights,
        rtol=1e-7,
        atol=1e-9,
    )


def test_async_writer_pause_holds_frames_then_writes_them_in_order(sim_rig, tmp_path: Path) -> None:
    writer = AsyncSequenceWriter(_writer(sim_rig, tmp_path / "s"), max_queued=2)
    writer.add_frame(_pixels(sim_rig, 100), "ambient", (0.0,) * 4, 1000.0)
    writer.flush()
    writer.pause()
    writer.add_frame(_pixels(sim_rig, 101), "ambient", (0.0,) * 4, 1001.0)
    assert writer._queue.qsize() == 0 and writer.queued == 1  # held back: the writer thread is not woken
    for value in range(2, 4):  # one more than the queue holds: a paused writer still makes room
        writer.add_frame(_pixels(sim_rig, 100 + value), "ambient", (0.0,) * 4, 1000.0 + value)
    writer.resume()
    sequence = writer.finish()
    assert [f.exposure_us for f in sequence.frames] == [1000.0 + v for v in range(4)]
    assert [_value(sim_rig, read_sequence(tmp_path / "s").load_frame(i)) for i in range(4)] == [100, 101, 102, 103]


def test_async_writer_paused_still_drains_on_exit(sim_rig, tmp_path: Path) -> None:
    with pytest.raises(KeyboardInterrupt), AsyncSequenceWriter(_writer(sim_rig, tmp_path / "s")) as writer:
        writer.pause()
        for value in range(3):
            writer.add_frame(_pixels(sim_rig, value), "ambient", (0.0,) * 4, 1000.0)
        raise KeyboardInterrupt
    assert len(read_sequence(tmp_path / "s").frames) == 3


def test_flash_stream_pauses_the_writer_only_around_the_decision(sim_rig, tmp_path: Path, monkeypatch) -> None:
    plan = CapturePlan.ambient_then_each_led(4, 2000.0, settle_s=0.001, deadtime_s=0.001, trigger="booth")
    states: list[bool] = []
    waits: list[bool] = []
    real_next = sim_rig.camera.next_frame

    def next_frame(timeout_s):
        waits.append(writer._running.is_set())
        return real_next(timeout_s)

    monkeypatch.setattr(sim_rig.camera, "next_frame", next_frame)
    with AsyncSequenceWriter(_writer(sim_rig, tmp_path / "s")) as writer:
        decider = FixedFlash((0.5,) * 4, 2000.0, lambda: states.append(writer._running.is_set()))
        entries = run_capture_with_flash(sim_rig.camera, sim_rig.booth, plan, writer, decider)
        assert writer._running.is_set()  # resumed once the flash frame is in
        writer.finish()
    assert states == [False]
    # Running while the ambient and the first LED frames arrive; paused from the wait for the
    # last LED frame through the flash trigger to the flash frame's arrival.
    assert waits == [True] * 4 + [False, False]
    assert [e.role for e in entries] == ["ambient"] + ["led"] * 4 + ["flash"]
    assert len(read_sequence(tmp_path / "s").frames) == 6


def _session_and_frames(
    sim_rig,
    tmp_path: Path,
    levels: list[tuple[float, ...]],
    saturate: float = 0.0,
    exposure_limits_us: tuple[float, float] | None = None,
):
    """A FlashSession fed synthetic frames (ambient + one frame per entry of ``levels``)."""
    from msflash.acquisition.devices.camera import RawFrame

    info = sim_rig.camera.info
    rng = np.random.default_rng(len(levels))
    white = int(info.white_level)
    black = int(info.black_level)
    ambient = rng.integers(black + 100, black + 1800, size=_shape(sim_rig))
    session = FlashSession.prepare(_writer(sim_rig, tmp_path / "s").sequence, exposure_limits_us=exposure_limits_us)
    session.begin(len(levels))  # the plan's LED frame count
    pixels = [ambient] + [ambient + rng.integers(100, 1800, size=ambient.shape) for _ in levels]
    session.fed = []  # type: ignore[attr-defined]  # what the test compares with
    for index, (values, level) in enumerate(zip(pixels, [(0.0,) * 4, *levels])):
        values = values.astype(np.uint16)
        values[rng.random(values.shape[:2]) < saturate] = white
        frame = RawFrame(values, index, 0, 1000.0 * (1 + index % 3), 1.0)
        session.add(frame, "ambient" if index == 0 else "led", level)
        session.fed.append(frame)  # type: ignore[attr-defined]
    return session


def _fed_stack(session):
    """The frames fed to a session, as a frame stack in memory (the batch statistics' input)."""
    from msflash.acquisition.session import analysis

    frames = session.fed
    roles = ["ambient" if i == 0 else "led" for i in range(len(frames))]
    gains = [f.exposure_us * f.gain for f in frames]
    layout = analysis.stack_layout(session.header, roles, session.stream.levels, gains)
    return analysis.frame_stack(layout, lambda index: frames[index].pixels)


@pytest.mark.parametrize(
    ("levels", "saturate"),
    [
        ([tuple(float(i == j) for i in range(4)) for j in range(4)], 0.0),
        ([tuple(float(i == j) for i in range(4)) for j in range(4)], 0.003),
        (
            [
                (1.0, 0.5, 0.0, 0.0),
                (0.0, 1.0, 0.5, 0.0),
                (0.0, 0.0, 1.0, 0.5),
                (0.5, 0.0, 0.0, 1.0),
                (1.0, 1.0, 1.0, 1.0),
            ],
            0.0,
        ),
    ],
    ids=["one-led-per-frame", "saturated-blocks", "multiplexed-more-frames"],
)
def test_flash_session_statistics_are_the_sequence_statistics(sim_rig, tmp_path: Path, levels, saturate) -> None:
    """Frame-by-frame moments (more LED frames than LEDs too) = the batch statistics of the same frames."""

    session = _session_and_frames(sim_rig, tmp_path, levels, saturate)
    stack = _fed_stack(session)
    ours = session.statistics()
    reference = sequence_statistics(stack, session.header.camera.cfa, session.bin_factor)
    assert ours.n_samples == reference.n_samples and (ours.n_samples < ours.n_total) == (saturate > 0)
    np.testing.assert_allclose(ours.gram, reference.gram, rtol=1e-9, atol=1e-9 * abs(reference.gram).max())
    np.testing.assert_allclose(ours.cross, reference.cross, rtol=1e-9, atol=1e-9 * abs(reference.cross).max())


def test_flash_decision_reads_the_full_estimate_only_when_asked(sim_rig, tmp_path: Path, monkeypatch) -> None:
    """decide() solves with the weights alone; the reliability signals are computed on first access."""
    import warnings

    from msflash.processing.ambient import AmbientModel

    session = _session_and_frames(sim_rig, tmp_path, [tuple(float(i == j) for i in range(4)) for j in range(4)])
    calls: list[int] = []
    real = AmbientModel.reliability

    def counted(self, *args, **kwargs):
        calls.append(1)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(AmbientModel, "reliability", counted)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        decision = session.decide("matching")
        assert calls == []
        full = session.estimate()
        assert decision.estimate is decision.estimate and len(calls) == 2
        expected_levels = np.clip(session.solve("matching", full.ambient_weights).flash_weights, 0, 1)
    np.testing.assert_array_equal(decision.estimate.ambient_weights, full.ambient_weights)
    np.testing.assert_array_equal(decision.estimate.spectrum_std, full.spectrum_std)
    np.testing.assert_array_equal(decision.levels, expected_levels)


def test_flash_session_predicts_the_flash_exposure_of_the_frames_taken(sim_rig, tmp_path: Path) -> None:
    """The rates taken frame by frame give flash_exposure's answer on the same frames (first ambient only)."""
    from msflash.acquisition.devices.camera import RawFrame
    from msflash.acquisition.errors import RecordingError
    from msflash.acquisition.session.metering import flash_exposure

    levels = [tuple(float(i == j) for i in range(4)) for j in range(4)]
    limits = (10.0, 1e6)
    session = _session_and_frames(sim_rig, tmp_path, levels, exposure_limits_us=limits)
    first = session.fed[0]
    session.add(RawFrame(first.pixels // 2, 99, 0, first.exposure_us, 1.0), "ambient", (0.0,) * 4)  # ignored
    frames = session.fed[:5]
    camera = session.header.camera
    for weights in ([0.2, 0.9, 0.0, 0.5], [1.0, 1.0, 1.0, 1.0]):
        expected = flash_exposure(
            frames[0].pixels,
            frames[0].exposure_us,
            [f.pixels for f in frames[1:]],
            [f.exposure_us for f in frames[1:]],
            weights,
            camera.black_level,
            camera.white_level,
            limits,
            session.exposure_policy,
        )
        assert session.flash_exposure(weights) == expected
    session.begin()
    with pytest.raises(ValueError, match="no ambient frame"):
        session.flash_exposure([0.0] * 4)
    plain = _session_and_frames(sim_rig, tmp_path / "plain", levels)
    with pytest.raises(RecordingError, match="exposure_limits_us"):
        plain.flash_exposure([0.0] * 4)


@pytest.mark.parametrize("trigger", ["booth", "camera"])
def test_flash_step_released_with_now_only_in_booth_master(sim_rig, tmp_path: Path, trigger: str) -> None:
    """The held flash step is released by one PSET, with NOW in booth master — also through a wrapper
    whose signature hides ``now`` (the capture bench times set_step with one)."""
    plan = CapturePlan.ambient_then_each_led(4, 5_000.0, trigger=trigger)
    calls: list[tuple[tuple, dict]] = []
    real = sim_rig.booth.set_step

    def timed(*args, **kwargs) -> None:
        calls.append((args, kwargs))
        real(*args, **kwargs)

    sim_rig.booth.set_step = timed
    with _writer(sim_rig, tmp_path / "s") as writer:
        run_capture_with_flash(sim_rig.camera, sim_rig.booth, plan, writer, FixedFlash((0.5,) * 4, 5_000.0))
    # the sim booth pulses (DIM=PULSE): the flash step's exposure travels with its levels
    assert calls == [((5, (0.5,) * 4), {"now": trigger == "booth", "exposure_us": 5_000.0})]
    assert not sim_rig.line_errors


@pytest.mark.parametrize(
    "levels",
    [
        [tuple(float(i == j) for i in range(4)) for j in range(4)],
        [(1.0, 0.5, 0.0, 0.0), (0.0, 1.0, 0.5, 0.0), (0.0, 0.0, 1.0, 0.5), (0.5, 0.0, 0.0, 1.0), (1.0, 1.0, 1.0, 1.0)],
    ],
    ids=["one-led-per-frame", "multiplexed-more-frames"],
)
def test_mono_frames_are_one_plane_in_the_session_and_three_channels_on_disk(
    rgb_sim_rig, tmp_path: Path, levels
) -> None:
    """A mono camera's (H, W) frames: the writer records three identical channels; the session
    block-sums the one plane and gives the statistics (and estimate) of the recorded sequence."""
    from msflash.acquisition.devices.camera import RawFrame
    from msflash.acquisition.session import analysis
    from msflash.acquisition.session.metering import flash_exposure

    info = rgb_sim_rig.camera.info
    rng = np.random.default_rng(7)
    white = int(info.white_level)
    black = int(info.black_level)
    ambient = rng.integers(black + 100, black + 1800, size=(info.height, info.width))
    pixels = [ambient] + [ambient + rng.integers(100, 1800, size=ambient.shape) for _ in levels]
    refused = rgb_sim_rig.sequence_writer(tmp_path / "s")  # not a mono rig: (H, W) without cfa is an error
    with pytest.raises(RecordingError, match="mono=True"):
        refused.add_frame(pixels[0].astype(np.uint16), "ambient", (0.0,) * 4, 1000.0)
    written = []
    wavelengths, camera, leds = rgb_sim_rig.sequence_header()
    with SequenceWriter(
        tmp_path / "mono", wavelengths_nm=wavelengths, spectral_unit="energy", camera=camera, leds=leds, mono=True
    ) as writer:
        session = FlashSession.prepare(writer.sequence, exposure_limits_us=(1.0, 1e6))
        session.begin(len(levels))  # the plan's LED frame count
        for index, (values, level) in enumerate(zip(pixels, [(0.0,) * 4, *levels])):
            values = values.astype(np.uint16)
            values[rng.random(values.shape) < 0.002] = white  # some saturated blocks
            written.append(values)
            frame = RawFrame(values, index, 0, 1000.0 * (1 + index % 3), 1.0)
            role = "ambient" if index == 0 else "led"
            writer.add_frame(frame.pixels, role, level, frame.exposure_us)
            session.add(frame, role, level)
    sequence = read_sequence(tmp_path / "mono")
    for index, values in enumerate(written):
        recorded = sequence.load_frame(index)
        assert recorded.shape == (info.height, info.width, 3)
        assert all(np.array_equal(recorded[:, :, channel], values) for channel in range(3))
    reference = sequence_statistics(analysis.load_frame_stack(sequence), None, session.bin_factor)
    ours = session.statistics()
    assert ours.n_samples == reference.n_samples < ours.n_total == reference.n_total
    np.testing.assert_allclose(ours.gram, reference.gram, rtol=1e-9, atol=1e-9 * abs(reference.gram).max())
    np.testing.assert_allclose(ours.cross, reference.cross, rtol=1e-9, atol=1e-9 * abs(reference.cross).max())
    np.testing.assert_allclose(ours.led_sums, reference.led_sums, rtol=1e-9)
    # A mono sequence from disk is taken as its one plane too: the same numbers to the last digit.
    np.testing.assert_array_equal(
        session.estimate().ambient_weights, analysis.estimate_sequence(sequence).ambient_weights
    )
    # msflash run's report reads the frames in memory as the sequence records them (RGB).
    in_memory = analysis.load_frame_stack(sequence, written)
    on_disk = analysis.load_frame_stack(sequence)
    assert in_memory.ambient.shape == on_disk.ambient.shape == (info.height, info.width, 3)
    assert np.array_equal(in_memory.ambient, on_disk.ambient)
    assert all(np.array_equal(a, b) for a, b in zip(in_memory.led_frames, on_disk.led_frames, strict=True))
    assert (in_memory.spec.ambient_scale, in_memory.spec.led_scales) == (
        on_disk.spec.ambient_scale,
        on_disk.spec.led_scales,
    )
    assert np.array_equal(in_memory.spec.led_levels, on_disk.spec.led_levels)
    # The frames do come from memory (the disk's would equal them: poison memory to tell them apart).
    poisoned = analysis.load_frame_stack(sequence, [np.zeros_like(v) for v in written])
    assert not np.any(poisoned.ambient) and not any(np.any(frame) for frame in poisoned.led_frames)
    # The flash exposure is metered pixel by pixel, as on the recorded RGB frames.
    recorded_frames = [sequence.load_frame(i) for i in range(len(written))]
    weights = [0.3] * len(levels)
    assert session.flash_exposure(weights) == flash_exposure(
        recorded_frames[0],
        sequence.frames[0].exposure_us,
        recorded_frames[1:],
        [f.exposure_us for f in sequence.frames[1:]],
        weights,
        info.black_level,
        info.white_level,
        (1.0, 1e6),
        session.exposure_policy,
    )


def test_collection_resumes_after_a_failed_flash_decision(sim_rig, tmp_path: Path) -> None:
    """The collector is paused only while the sequence streams: a decision that fails restores it
    (and a collector the caller had disabled stays disabled)."""
    plan = CapturePlan.ambient_then_each_led(4, 10_000.0, trigger="booth")

    def refuse() -> None:
        raise RuntimeError("no decision")

    decide = FixedFlash((0.0,) * 4, 1_000.0, refuse)

    for enabled in (True, False):
        (gc.enable if enabled else gc.disable)()
        try:
            with (
                AsyncSequenceWriter(_writer(sim_rig, tmp_path / f"s{enabled}")) as writer,
                pytest.raises(RuntimeError, match="no decision"),
            ):
                run_capture_with_flash(sim_rig.camera, sim_rig.booth, plan, writer, decide)
            assert gc.isenabled() == enabled
        finally:
            gc.enable()
    assert sim_rig.emulator.levels == (0.0,) * 4


def test_a_streaming_session_never_compiles_a_kernel(sim_rig, tmp_path: Path, monkeypatch) -> None:
    """Even in a process that has the kernels (forced here): adding frames and deciding take the numpy route for the
    frames' passes, and the kernels of the statistics' route the stream chose when it was made
    (frame_kernels.statistics_compiled: the moments, the ambient's noise line and weights) were compiled as the kernels loaded —
    nothing compiles while frames arrive (a first compile there stalls the stream and the booth's watchdog switches the
    LEDs off)."""
    from msflash.processing import frame_kernels
    from msflash.processing.errors import TargetUnreachableWarning

    monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, "numba")
    frame_kernels._compiled.cache_clear()
    kernels = frame_kernels._compiled()  # a process that has them: loaded and warmed
    if kernels is None:
        pytest.skip("numba is not installed")
    # the moments, the noise line's cells and fit, the weights' floor levels and inverse variances
    route = {"block_statistics", "detail_line", "haar_cells", "floor_levels", "inverse_variances"}
    compiled_before = {name: list(getattr(kernels, name).signatures) for name in ("block_pass", *sorted(route))}
    used: list[str] = []

    class Recorder:
        def __getattr__(self, name: str) -> object:
            used.append(name)
            return getattr(kernels, name)

    monkeypatch.setattr(frame_kernels, "_compiled", lambda: Recorder())  # every kernel taken is recorded
    levels = [tuple(float(i == j) for i in range(4)) for j in range(4)]
    session = _session_and_frames(sim_rig, tmp_path, levels)
    statistics = session.statistics()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TargetUnreachableWarning)  # synthetic frames: any flash will do
        decision = session.decide("complementary")
    assert np.all(np.isfinite(decision.levels)) and statistics.n_samples > 0
    assert set(used) == route  # the statistics' route only: the frames' block passes were numpy's
    assert {name: list(getattr(kernels, name).signatures) for name in compiled_before} == compiled_before
    used.clear()
    with frame_kernels.paused():
        assert not frame_kernels.enabled()
    assert used == []
