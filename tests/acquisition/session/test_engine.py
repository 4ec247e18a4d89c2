"""The capture engine's runner on the sim rig (SimulatedCamera + booth emulator on a real pty): frame events
to handlers in order, one ``sequence_finished``, cancellation between frames, the typed rig table, and a run's
``RunResult`` with both flashes solved once."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.errors import CaptureCancelled, UsageError
from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.both_flashes import solve_both
from msflash.acquisition.session.capture import preview_frames, run_capture
from msflash.acquisition.session.engine import Cancellation, CaptureResult, FrameEvent
from msflash.acquisition.session.exposure import ExposurePolicy
from msflash.acquisition.session.rig import (
    RIG_BUILDERS,
    HwRigOptions,
    SimRigOptions,
    SimWorldOptions,
    open_rig,
    open_sim_rig,
    rig_kind,
)
from msflash.acquisition.session.run import RunOptions, plan_exposure, run_one_stream, sequence_writer
from tests.acquisition.support.capture_doubles import Watch


@pytest.fixture
def sim_rig():
    with open_sim_rig(n_leds=4, seed=11) as rig:
        yield rig


class CancelAfter:
    """A frame handler asking the capture to stop once ``frames`` frames were handed to it."""

    def __init__(self, cancel: Cancellation, frames: int) -> None:
        self.cancel, self.frames, self.seen = cancel, frames, 0

    def frame_ready(self, event: FrameEvent) -> None:
        self.seen += 1
        if self.seen == self.frames:
            self.cancel.cancel("asked to stop")

    def sequence_finished(self, result: CaptureResult) -> None:
        raise AssertionError("a cancelled capture does not finish")


@pytest.mark.parametrize("trigger", ["software", "booth", "camera"])
def test_handlers_get_each_frame_written_in_order_then_the_end_once(sim_rig, tmp_path: Path, trigger: str) -> None:
    plan = CapturePlan.ambient_then_each_led(4, 5_000.0, trigger=trigger)
    first, second = Watch(), Watch()
    with sim_rig.sequence_writer(tmp_path / "s") as writer:
        entries = run_capture(sim_rig.camera, sim_rig.booth, plan, writer, (first, second))
        writer.finish()
    for watch in (first, second):
        # the writer (the runner's recorder) comes first: every handler sees the frame's entry on disk
        assert [event.entry for event in watch.events] == entries
        assert [event.step.index for event in watch.events] == list(range(len(plan.steps)))
        assert all(event.retake == 0 for event in watch.events)
        assert len(watch.finished) == 1 and watch.finished[0].entries == tuple(entries)
        assert watch.finished[0].frames == tuple(event.frame for event in watch.events)
    sequence = read_sequence(tmp_path / "s")
    assert sequence.complete and [f.file for f in sequence.frames] == [e.file for e in entries]


@pytest.mark.parametrize("trigger", ["software", "booth", "camera"])
def test_a_cancelled_capture_stops_between_frames_with_the_leds_off_and_its_frames_kept(
    sim_rig, tmp_path: Path, trigger: str
) -> None:
    plan = CapturePlan.ambient_then_each_led(4, 5_000.0, trigger=trigger)
    cancel = Cancellation()
    stopper = CancelAfter(cancel, 2)
    with (
        pytest.raises(CaptureCancelled, match=r"before step 2 \(led:2\): asked to stop"),
        AsyncSequenceWriter(sim_rig.sequence_writer(tmp_path / "s")) as writer,
    ):
        run_capture(sim_rig.camera, sim_rig.booth, plan, writer, (stopper,), cancel=cancel)
    assert stopper.seen == 2
    sequence = read_sequence(tmp_path / "s")
    assert not sequence.complete
    assert [frame.role for frame in sequence.frames] == ["ambient", "led"]
    assert all(sequence.load_frame(i).size for i in range(2))  # drained: whole frames on disk
    assert sim_rig.emulator.levels == (0.0,) * 4  # the booth holds no LED on (and no table runs)
    assert sim_rig.booth.status().state != "RUNNING"  # OFF aborted a running table
    assert not sim_rig.line_errors


def test_a_capture_cancelled_before_it_starts_touches_neither_camera_nor_booth(sim_rig) -> None:
    cancel = Cancellation()
    cancel.cancel("stopping")
    cancel.cancel("another reason")  # the first reason is kept
    plan = CapturePlan.single((0.0, 1.0, 0.0, 0.0), 5_000.0, role="led")
    with pytest.raises(CaptureCancelled, match=r"before step 0 \(led:2\): stopping$"):
        preview_frames(sim_rig.camera, sim_rig.booth, plan, cancel=cancel)
    assert sim_rig.camera.rendered_levels == ()


def test_metering_previews_are_cancelled_too(sim_rig) -> None:
    """``plan_exposure`` (auto: metered previews) takes the cancellation to its previews."""
    cancel = Cancellation()
    cancel.cancel("stopping")
    with pytest.raises(CaptureCancelled, match="stopping"):
        plan_exposure(sim_rig, "auto", ExposurePolicy(), cancel=cancel)
    assert sim_rig.camera.rendered_levels == ()


def test_a_run_returns_its_result_with_both_flashes_the_chosen_one_as_decided(sim_rig, tmp_path: Path) -> None:
    exposure = plan_exposure(sim_rig, 5_000.0, ExposurePolicy())
    options = RunOptions(mode="matching")
    watch = Watch()
    with sequence_writer(sim_rig, tmp_path, exposure) as inner, AsyncSequenceWriter(inner) as writer:
        result = run_one_stream(sim_rig, writer, exposure, options, (watch,))
        writer.finish()
    assert list(result.solutions) == ["matching", "complementary"]
    assert result.decision_ms >= 0 and result.flash_exposure_us == 5_000.0
    assert [event.step.role for event in watch.events] == ["ambient"] + ["led"] * 4 + ["flash"]
    sequence = read_sequence(tmp_path / "sequence")
    np.testing.assert_allclose(
        sequence.frames[-1].led_levels, np.clip(result.solutions["matching"].flash_weights, 0, 1)
    )
    # The decided flash is kept as decided; the other is solved once, from the reported estimate.
    asked: list[str] = []

    class Counting:
        def solve(self, mode: str, weights: np.ndarray):  # noqa: ANN201 - a FlashSolution
            asked.append(mode)
            return result.solutions[mode]

    both = solve_both(
        Counting(), result.estimate.ambient_weights, "matching", solved={"matching": result.solutions["matching"]}
    )
    assert asked == ["complementary"] and both.solutions["matching"] is result.solutions["matching"]
    assert list(both.solutions) == ["matching", "complementary"]


def test_the_rig_table_names_every_kind_and_refuses_other_kinds_options() -> None:
    assert set(RIG_BUILDERS) == {"sim", "aravis-fake", "replay", "hw"}
    assert rig_kind("replay:some/dir") == "replay" and rig_kind("sim") == "sim"
    for bad in ("replay:", "replay", "webcam"):
        with pytest.raises(
            UsageError,
            match=rf"--rig '{bad}': unknown; (did you mean .*\? )?expected one of sim, aravis-fake, replay:DIR, hw",
        ):
            open_rig(bad)
    with pytest.raises(TypeError, match="HwRigOptions given; expected SimRigOptions"):
        open_rig("sim", HwRigOptions())


def test_the_sim_rig_opens_from_its_typed_options() -> None:
    world = SimWorldOptions(ambient="daylight", n_leds=3, seed=5)
    with open_rig("sim", SimRigOptions(world, cfa="RGGB")) as rig:
        assert rig.led_spectra.count == 3 and rig.camera.info.cfa == "RGGB"
        assert rig.true_ambient is not None
