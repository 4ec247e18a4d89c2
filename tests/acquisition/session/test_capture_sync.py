"""The three sync modes of run_capture on the sim rig (SimulatedCamera + booth emulator on a real pty).

Host paced, booth master (the emulator pulses the camera's trigger line) and camera master (the
camera's exposure advances the booth's pattern table) must give the same frames for the same
seed, each paired with its step by trigger count; lost frames raise DroppedFrameError naming the
step and keep what was written.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import DroppedFrameError, FrameLostError, FrameTimeoutError
from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.acquisition.session.capture import preview_frames, run_capture
from msflash.acquisition.session.rig import Rig, open_sim_rig

MODES = ("software", "booth", "camera")


def _writer(rig: Rig, path: Path) -> SequenceWriter:
    wavelengths, camera, leds = rig.sequence_header()
    return SequenceWriter(path, wavelengths_nm=wavelengths, spectral_unit="energy", camera=camera, leds=leds)


def _plan(trigger: str, n_leds: int = 4, **timing: float) -> CapturePlan:
    return CapturePlan.ambient_then_each_led(n_leds, 10_000.0, trigger=trigger, **timing)


@pytest.fixture
def sim_rig():
    with open_sim_rig(n_leds=4, seed=3) as rig:
        yield rig


@pytest.fixture(scope="module")
def host_frames(tmp_path_factory: pytest.TempPathFactory) -> list[np.ndarray]:
    path = tmp_path_factory.mktemp("host") / "sequence"
    with open_sim_rig(n_leds=4, seed=3) as rig, _writer(rig, path) as writer:
        run_capture(rig.camera, rig.booth, _plan("software"), writer)
        writer.finish()
    sequence = read_sequence(path)
    return [sequence.load_frame(i) for i in range(len(sequence.frames))]


@pytest.mark.parametrize("trigger", ["booth", "camera"])
def test_table_paced_modes_give_the_host_paced_frames(sim_rig: Rig, tmp_path: Path, host_frames, trigger: str) -> None:
    plan = _plan(trigger)
    with _writer(sim_rig, tmp_path / "sequence") as writer:
        written = run_capture(sim_rig.camera, sim_rig.booth, plan, writer)
        writer.finish()
    assert len(written) == len(plan.steps)
    # The camera exposed each step under exactly the levels the booth's table held for it.
    assert sim_rig.camera.rendered_levels == tuple(step.led_levels for step in plan.steps)
    sequence = read_sequence(tmp_path / "sequence")
    assert sequence.complete
    assert [f.extra["trigger"] for f in sequence.frames] == [1, 2, 3, 4, 5]
    assert [tuple(f.led_levels) for f in sequence.frames] == [s.led_levels for s in plan.steps]
    for index, expected in enumerate(host_frames):
        np.testing.assert_array_equal(sequence.load_frame(index), expected)
    assert sim_rig.booth.trigger_count() == len(plan.steps)
    assert sim_rig.emulator is not None and sim_rig.emulator.levels == (0.0,) * 4
    assert not sim_rig.line_errors


def test_modes_follow_each_other_on_one_rig(sim_rig: Rig, tmp_path: Path) -> None:
    """A sequence then a one-frame flash, switching modes, as msflash run does.

    The flash's exposure is two periods of the booth's 244 Hz PWM: host paced, the booth dims by
    PWM and only whole periods give level × full (the planner picks such exposures,
    docs/flash-energy.md); booth and camera master it pulses each LED for level × exposure."""
    with _writer(sim_rig, tmp_path / "sequence") as writer:
        for trigger in MODES:
            run_capture(sim_rig.camera, sim_rig.booth, _plan(trigger), writer)
            run_capture(
                sim_rig.camera,
                sim_rig.booth,
                CapturePlan.single([0.25, 0.5, 0.0, 1.0], 8192.0, trigger=trigger),
                writer,
            )
        writer.finish()
    flash = (0.25, 0.5, 0.0, 1.0)  # within one 16-bit wire step
    assert np.allclose(sim_rig.camera.rendered_levels[5::6], [flash] * 3, atol=1 / 65535)
    assert len(sim_rig.camera.rendered_levels) == 18


@pytest.mark.parametrize("trigger", MODES)
def test_a_lost_frame_names_its_step_and_keeps_the_frames_written(sim_rig: Rig, tmp_path: Path, trigger: str) -> None:
    camera = sim_rig.camera
    real_next = camera.next_frame
    calls = {"n": 0}

    def losing_next(timeout_s: float):
        calls["n"] += 1
        if calls["n"] == 3:  # the frame of step 2 never reaches the host
            real_next(timeout_s)
            if trigger != "booth":
                camera.trigger()  # host and camera master trigger the next step themselves
        return real_next(timeout_s)

    camera.next_frame = losing_next
    with pytest.raises(FrameLostError) as caught, _writer(sim_rig, tmp_path / "sequence") as writer:
        run_capture(camera, sim_rig.booth, _plan(trigger), writer, retakes=0)
    assert str(caught.value).startswith("step 2 (led:2)")
    assert "2 frame(s) already saved" in str(caught.value)
    sequence = read_sequence(tmp_path / "sequence")
    assert not sequence.complete and len(sequence.frames) == 2
    assert sim_rig.emulator.levels == (0.0,) * 4


def _losing_step(sim_rig: Rig, trigger: str, plan: CapturePlan, lost: int, times: int, how: str) -> dict[str, int]:
    """Make the sim camera lose the frame of step ``lost`` the first ``times`` times that step is
    exposed; returns the count of frames lost.

    ``how``: ``incomplete`` — the camera reports it (:class:`FrameLostError`, as Aravis does for a
    frame missing packets); ``skipped`` — it never arrives and the next one comes in its place,
    its id skipped (found by the capture's own continuity check, from the second frame of a table
    or of a host-paced run on)."""
    camera = sim_rig.camera
    real_next = camera.next_frame
    count = {"lost": 0}

    def losing_next(timeout_s: float):
        frame = real_next(timeout_s)
        # The sim camera numbers its renders from 1 (booth master renders on the booth's pulses,
        # so the latest render may already be the next step's).
        if camera.rendered_levels[frame.frame_id - 1] == plan.steps[lost].led_levels and count["lost"] < times:
            count["lost"] += 1
            if how == "incomplete":
                raise FrameLostError(f"camera: frame {frame.frame_id} arrived incomplete")
            if how == "vanished":
                raise FrameTimeoutError(f"camera: no frame within {timeout_s:.3g} s")
            if trigger != "booth":
                camera.trigger()  # host and camera master trigger the next step themselves
            return real_next(timeout_s)
        return frame

    camera.next_frame = losing_next
    return count


def _nearest(frame: np.ndarray, references: list[np.ndarray]) -> int:
    return int(np.argmin([np.abs(frame.astype(float) - r).mean() for r in references]))


@pytest.mark.parametrize("how", ["incomplete", "skipped"])
@pytest.mark.parametrize("trigger", MODES)
def test_a_lost_frame_is_taken_again_with_the_steps_after_it(
    sim_rig: Rig, tmp_path: Path, host_frames, trigger: str, how: str
) -> None:
    """The lost step and the ones after it are captured anew in the same sync mode: the sequence is
    complete, each frame shows its own step's light, and the retaken frames say so."""
    plan = _plan(trigger)
    count = _losing_step(sim_rig, trigger, plan, lost=2, times=1, how=how)
    with _writer(sim_rig, tmp_path / "sequence") as writer:
        written = run_capture(sim_rig.camera, sim_rig.booth, plan, writer)
        writer.finish()
    assert count["lost"] == 1 and len(written) == len(plan.steps)
    sequence = read_sequence(tmp_path / "sequence")
    assert sequence.complete
    assert [f.extra.get("retake", 0) for f in sequence.frames] == [0, 0, 1, 1, 1]
    assert [tuple(f.led_levels) for f in sequence.frames] == [s.led_levels for s in plan.steps]
    if trigger != "software":  # each table's triggers count from 1
        assert [f.extra["trigger"] for f in sequence.frames] == [1, 2, 1, 2, 3]
    # Each frame is its own step's (other noise draws than the host-paced reference, same light).
    assert [_nearest(sequence.load_frame(i), host_frames) for i in range(5)] == [0, 1, 2, 3, 4]
    assert sim_rig.emulator is not None and sim_rig.emulator.levels == (0.0,) * 4
    assert not sim_rig.line_errors


@pytest.mark.parametrize("trigger", MODES)
def test_a_frame_lost_at_every_retake_fails_naming_its_step(sim_rig: Rig, tmp_path: Path, trigger: str) -> None:
    plan = _plan(trigger)
    count = _losing_step(sim_rig, trigger, plan, lost=3, times=100, how="incomplete")
    with pytest.raises(FrameLostError) as caught, _writer(sim_rig, tmp_path / "sequence") as writer:
        run_capture(sim_rig.camera, sim_rig.booth, plan, writer, retakes=2)
    assert count["lost"] == 3  # the first attempt and two retakes
    message = str(caught.value)
    assert message.startswith("camera: frame") and message.endswith("(after 2 retake(s) of lost frames)")
    sequence = read_sequence(tmp_path / "sequence")
    assert not sequence.complete and len(sequence.frames) == 3
    assert sim_rig.emulator.levels == (0.0,) * 4


def test_a_host_paced_frame_that_vanishes_after_others_came_is_taken_again(
    sim_rig: Rig, tmp_path: Path, host_frames
) -> None:
    plan = _plan("software")
    count = _losing_step(sim_rig, "software", plan, lost=2, times=1, how="vanished")
    with _writer(sim_rig, tmp_path / "sequence") as writer:
        run_capture(sim_rig.camera, sim_rig.booth, plan, writer)
        writer.finish()
    sequence = read_sequence(tmp_path / "sequence")
    assert count["lost"] == 1 and sequence.complete
    assert [f.extra.get("retake", 0) for f in sequence.frames] == [0, 0, 1, 1, 1]
    assert [_nearest(sequence.load_frame(i), host_frames) for i in range(5)] == [0, 1, 2, 3, 4]


@pytest.mark.parametrize("trigger", MODES)
def test_a_frame_that_never_comes_is_not_taken_again_where_it_may_be_the_trigger(
    sim_rig: Rig, tmp_path: Path, trigger: str
) -> None:
    """Host paced, no frame yet: the trigger or the wiring, which a retake would only wait out
    again. Booth and camera master, a frame the booth triggered but that never came: a missed
    trigger is found only here, and the frames since may be paired with the wrong steps."""
    plan = _plan(trigger)
    lost = 0 if trigger == "software" else 2
    count = _losing_step(sim_rig, trigger, plan, lost=lost, times=100, how="vanished")
    expected = FrameTimeoutError if trigger == "software" else DroppedFrameError
    with pytest.raises(expected) as caught, _writer(sim_rig, tmp_path / "sequence") as writer:
        run_capture(sim_rig.camera, sim_rig.booth, plan, writer)
    assert not isinstance(caught.value, FrameLostError)
    assert count["lost"] == 1 and "retake" not in str(caught.value)
    if lost:
        assert len(read_sequence(tmp_path / "sequence").frames) == lost
    else:  # nothing captured: the writer removes the sequence it began (no frame, nothing kept)
        assert not (tmp_path / "sequence" / "sequence.json").exists()


def test_a_lost_preview_frame_is_taken_again(sim_rig: Rig) -> None:
    """Exposure previews are captured as a sequence is: a lost frame must not fail the metering."""
    plan = _plan("software")
    count = _losing_step(sim_rig, "software", plan, lost=1, times=1, how="incomplete")
    frames = preview_frames(sim_rig.camera, sim_rig.booth, plan)
    assert count["lost"] == 1 and len(frames) == len(plan.steps)
    rendered = sim_rig.camera.rendered_levels
    assert [rendered[frame.frame_id - 1] for frame in frames] == [step.led_levels for step in plan.steps]
    assert sim_rig.emulator is not None and sim_rig.emulator.levels == (0.0,) * 4


def test_a_preview_frame_lost_at_every_retake_fails(sim_rig: Rig) -> None:
    plan = _plan("software")
    count = _losing_step(sim_rig, "software", plan, lost=0, times=100, how="incomplete")
    with pytest.raises(FrameLostError, match=r"\(after 2 retake\(s\) of lost frames\)$"):
        preview_frames(sim_rig.camera, sim_rig.booth, plan)
    assert count["lost"] == 3


def test_retakes_must_not_be_negative(sim_rig: Rig, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="retakes -1; expected 0 or more"), _writer(sim_rig, tmp_path / "s") as writer:
        run_capture(sim_rig.camera, sim_rig.booth, _plan("software"), writer, retakes=-1)


def test_booth_master_trigger_without_a_frame_is_a_dropped_frame(sim_rig: Rig, tmp_path: Path) -> None:
    """The camera missed the booth's 4th pulse: DroppedFrameError, not a hang.

    Frame ids count the camera's own frames, so a pulse the camera never saw is found only when
    the booth has counted more triggers than frames arrived (here at the last step); the frames
    after the missed pulse were already written with the step their trigger number implies.
    """
    emulator = sim_rig.emulator
    assert emulator is not None
    wired = emulator.on_trigger_out

    def missed_pulse(count: int) -> None:
        if count != 4:
            wired(count)

    emulator.on_trigger_out = missed_pulse
    plan = dataclasses.replace(_plan("booth"), timeout_margin_s=0.2)
    with pytest.raises(DroppedFrameError) as caught, _writer(sim_rig, tmp_path / "sequence") as writer:
        run_capture(sim_rig.camera, sim_rig.booth, plan, writer)
    assert str(caught.value).startswith("step 4 (led:4): the booth counted trigger 5 but no frame arrived")
    sequence = read_sequence(tmp_path / "sequence")
    assert not sequence.complete and len(sequence.frames) == 4


@pytest.mark.parametrize("sync", ["booth", "camera"])
def test_cli_capture_sync(tmp_path: Path, sync: str) -> None:
    out = tmp_path / sync
    log = tmp_path / f"{sync}.txt"
    assert main(["capture", "--sync", sync, "--out", str(out), "--log-serial", str(log)]) == 0
    sequence = read_sequence(out / "sequence")
    assert sequence.complete and len(sequence.frames) == 8
    transcript = log.read_text()
    assert f"ARM {sync.upper()} " in transcript and "DONE 8" in transcript


def test_a_booth_master_period_beyond_the_booth_is_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Exposures of ~10 s with the booth pacing: its step period would exceed what ARM takes (10 s); the
    capture says so and what would fit, before anything is sent — it was a ValueError traceback."""
    status = main(["capture", "--sync", "booth", "--exposure-us", "9999000", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 1
    assert err[-1].startswith(
        "msflash: error: booth master: step period 10 s (settle, trigger pulse, longest "
        "exposure 9.999 s, deadtime and readout) is longer than the booth's longest period 10 s"
    )
    assert "expected exposures up to 9.995 s" in err[-1]
    assert not list((tmp_path / "x" / "sequence" / "frames").glob("*"))
