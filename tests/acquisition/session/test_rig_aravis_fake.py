"""The ``aravis-fake`` rig: AravisCamera on the GigE Vision fake at 127.0.0.1 + booth emulator on a pty.

Aravis streams and triggers; each frame's pixels are the simulated scene rendered under the LED
levels the booth held when that frame was triggered. These tests check the plumbing (a complete
format-v1 sequence, frame ids, the trigger wires, releasing the fake) and that the frames carry
the booth's light: ``run`` estimates the ambient within 1.3× what the LEDs allow, in every sync mode.
"""

from __future__ import annotations

import json
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import UsageError
from msflash.acquisition.plan import CapturePlan, CaptureStep
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.capture import preview_frames, run_capture
from msflash.acquisition.session.rig import open_aravis_fake_rig, open_rig
from msflash.acquisition.session.rigs.aravis_fake import ARAVIS_FAKE_PIXEL_FORMAT
from msflash.processing import datasets
from tests.acquisition.support.capture_doubles import Watch
from tests.acquisition.support.gvcp_port import gvcp_port_in_use

pytestmark = pytest.mark.aravis


def _assert_released(aravis: ModuleType) -> None:
    """The rig let go of the fake: holding the port lock (this process's own hold would be taken
    again at once), nobody listens on 3956.

    Another xdist worker may hold the lock for its own test meanwhile, hence the wait.
    """
    from msflash.acquisition.devices.aravis.gv_fake import gvcp_port_lock

    with gvcp_port_lock(timeout_s=120.0):
        assert not gvcp_port_in_use()


@pytest.mark.parametrize("sync", ["booth", "camera"])  # host-paced: the run test below
def test_capture_writes_a_complete_sequence(aravis: ModuleType, tmp_path, sync: str) -> None:
    out = tmp_path / "c"
    assert main(["capture", "--rig", "aravis-fake", "--sync", sync, "--out", str(out)]) == 0
    sequence = read_sequence(out / "sequence")
    assert sequence.complete
    assert [f.role for f in sequence.frames] == ["ambient"] + ["led"] * 7
    assert sequence.camera.pixel_format == "BayerRG16" and sequence.camera.cfa == "RGGB"
    assert "channels" not in sequence.camera.extra and "rendered" in sequence.camera.extra["pixels"]
    for attempt in _attempts(sequence.frames):  # a frame lost under load is taken again, in a new attempt
        ids = [f.extra["frame_id"] for f in attempt]
        assert all((b - a) % (1 << 16) == 1 for a, b in zip(ids, ids[1:]))
        if sync != "host":
            assert [f.extra["trigger"] for f in attempt] == list(range(1, len(attempt) + 1))
    for index, frame in enumerate(sequence.frames):
        assert frame.led_levels == pytest.approx([1.0 if i == index - 1 else 0.0 for i in range(7)])
    pixels = sequence.load_frame(0)
    assert pixels.shape == (186, 200) and pixels.dtype == np.uint16  # the default chart at 16-pixel patches
    _assert_released(aravis)


@pytest.mark.parametrize("sync", ["host", "booth", "camera"])
def test_each_frame_is_rendered_under_the_levels_of_its_trigger(aravis: ModuleType, tmp_path, sync: str) -> None:
    """The levels the renderer used are the booth's at each trigger (recorded by the capture as the
    frame's), and the light shows in the pixels: at one exposure every LED frame is brighter than
    the ambient one, by what that LED adds."""
    levels = [(0.0,) * 7, (1.0, 0, 0, 0, 0, 0, 0), (0, 0, 0, 0.5, 0, 0, 0), (0, 0, 0, 0, 0, 0, 1.0)]
    trigger = {"host": "software", "booth": "booth", "camera": "camera"}[sync]
    plan = CapturePlan(
        tuple(CaptureStep(i, "led" if any(lv) else "ambient", lv, 8_000.0) for i, lv in enumerate(levels)),
        trigger=trigger,
    )  # type: ignore[arg-type]
    with open_rig("aravis-fake") as rig:
        with rig.sequence_writer(tmp_path / "s") as writer:
            entries = run_capture(rig.camera, rig.booth, plan, writer)
        rendered = rig.camera.rendered_levels
        assert not rig.line_errors
    assert len(rendered) == len(levels)
    for used, wanted, entry in zip(rendered, levels, entries):
        assert used == pytest.approx(wanted, abs=1e-4) and entry.led_levels == pytest.approx(wanted, abs=1e-4)
    sequence = read_sequence(tmp_path / "s")
    means = [float(sequence.load_frame(i).mean()) for i in range(len(levels))]
    assert all(m > means[0] + 50 for m in means[1:]), means
    _assert_released(aravis)


def _attempts(frames) -> list[list]:
    """The frames of a sequence grouped by capture attempt (``retake`` 0, 1, 2…, in order)."""
    groups: dict[int, list] = {}
    for frame in frames:
        groups.setdefault(frame.extra.get("retake", 0), []).append(frame)
    assert list(groups) == sorted(groups)
    return list(groups.values())


@pytest.mark.parametrize("sync", ["host", "booth", "camera"])
def test_a_lossy_link_costs_retakes_not_the_sequence(aravis: ModuleType, tmp_path, sync: str) -> None:
    """The fake drops 2 % of its stream packets, so about two frames in three arrive incomplete:
    each lost frame is taken again, with the steps after it, until the sequence is complete, and
    every frame written was rendered under its own step's levels (150 such sequences, 2,630
    retakes, none failed or mispaired: docs/reliability.md)."""
    trigger = {"host": "software", "booth": "booth", "camera": "camera"}[sync]
    plan = CapturePlan.ambient_then_each_led(7, 8_000.0, trigger=trigger)  # type: ignore[arg-type]
    paired = []
    trace = []  # step, frame id, trigger, retake of each frame written: said when a pairing fails
    with open_aravis_fake_rig(lost_packet_ratio=0.02) as rig:

        def check(step, frame, entry) -> None:
            paired.append((rig.camera.rendered_levels[-1], step.led_levels))
            trace.append(f"{step.label}:{frame.frame_id}:{entry.extra.get('trigger')}:{entry.extra.get('retake', 0)}")

        with rig.sequence_writer(tmp_path / "s") as writer:
            run_capture(rig.camera, rig.booth, plan, writer, (Watch(check),), retakes=100)
            writer.finish()
        assert not rig.line_errors
    sequence = read_sequence(tmp_path / "s")
    assert sequence.complete and len(sequence.frames) == 8
    assert [tuple(f.led_levels) for f in sequence.frames] == [s.led_levels for s in plan.steps]
    for used, wanted in paired:
        assert used == pytest.approx(wanted, abs=1e-4), " ".join(trace)
    attempts = _attempts(sequence.frames)
    # P(eight frames in a row whole) = (0.98^~55 packets)^8 ≈ 1e-4: the link costs retakes.
    assert len(attempts) > 1
    for attempt in attempts:  # within an attempt, consecutive ids; a table's triggers count from 1
        ids = [f.extra["frame_id"] for f in attempt]
        assert all((b - a) % (1 << 16) == 1 for a, b in zip(ids, ids[1:]))
        if sync == "booth":
            assert [f.extra["trigger"] for f in attempt] == list(range(1, len(attempt) + 1))
    _assert_released(aravis)


def test_exposure_previews_on_a_lossy_link_are_taken_again(aravis: ModuleType) -> None:
    """The metering previews (host paced, written nowhere) retake their lost frames too."""
    plan = CapturePlan.ambient_then_each_led(7, 8_000.0)
    with open_aravis_fake_rig(lost_packet_ratio=0.02) as rig:
        frames = preview_frames(rig.camera, rig.booth, plan, retakes=100)
        rendered = rig.camera.rendered_levels
        assert not rig.line_errors
    # The wired camera renders only the frames it delivers: one per preview step, in order.
    assert len(frames) == len(rendered) == 8
    for used, step in zip(rendered, plan.steps, strict=True):
        assert used == pytest.approx(step.led_levels, abs=1e-4)
    _assert_released(aravis)


def test_run_estimates_the_rendered_ambient(aravis: ModuleType, tmp_path, capfd) -> None:
    """Aravis streaming and software triggering end to end: a good estimate, flash re-captured, exit 0."""
    out = tmp_path / "r"
    assert main(["run", "--rig", "aravis-fake", "--out", str(out)]) == 0
    err = capfd.readouterr().err
    assert "Unsupported pixel format" not in err  # the fake's per-frame complaint is muted (fake_log)
    _assert_good_run(out, err)
    _assert_released(aravis)


@pytest.mark.parametrize("sync", ["booth", "camera"])
def test_run_estimates_the_rendered_ambient_in_each_sync_mode(aravis: ModuleType, tmp_path, capsys, sync: str) -> None:
    out = tmp_path / sync
    assert main(["run", "--rig", "aravis-fake", "--sync", sync, "--out", str(out)]) == 0
    _assert_good_run(out, capsys.readouterr().err)
    sequence = read_sequence(out / "sequence")
    for attempt in _attempts(sequence.frames):
        assert [f.extra["trigger"] for f in attempt] == list(range(1, len(attempt) + 1))
    _assert_released(aravis)


def _assert_good_run(out, err: str) -> None:
    summary = json.loads((out / "run.json").read_text())
    estimate, bound = summary["spectrum_rmse_vs_truth"], summary["spectrum_rmse_led_bound"]
    # Measured 0.170–0.181 against a bound of 0.192 (seeds 0–3; docs/architecture.md §4).
    assert estimate <= 1.3 * bound, (estimate, bound)
    assert (
        f"spectrum RMSE against the true ambient {estimate:.4f}; the best non-negative LED fit of it {bound:.4f}" in err
    )
    sequence = read_sequence(out / "sequence")
    assert sequence.complete
    assert [f.role for f in sequence.frames] == ["ambient"] + ["led"] * 7 + ["flash"]
    assert sequence.camera.pixel_format == ARAVIS_FAKE_PIXEL_FORMAT == "BayerRG16" and sequence.camera.cfa == "RGGB"
    flash = sequence.load_frame(8)
    assert flash.dtype == np.uint16 and flash.ndim == 2
    assert any(level > 0 for level in sequence.frames[8].led_levels)
    assert sequence.extra["msflash"]["true_ambient"]["name"] == "tungsten"
    truth = datasets.camera_responsivities("NikonD100").resample(sequence.led_spectra().grid)
    recorded = sequence.camera_responsivities()
    assert recorded is not None
    assert np.allclose(recorded.to_unit("energy").values, truth.to_unit("energy").values, rtol=1e-6, atol=1e-9)
    assert "responsivity_note" not in sequence.camera.extra


def test_world_options_apply_to_the_rendered_scene(aravis: ModuleType, tmp_path) -> None:
    out = tmp_path / "o"
    assert (
        main(
            [
                "capture",
                "--rig",
                "aravis-fake",
                "--ambient",
                "D65",
                "--scene",
                "macbeth",
                "--leds",
                "4",
                "--seed",
                "3",
                "--exposure",
                "5000",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    sequence = read_sequence(out / "sequence")
    assert sequence.extra["msflash"]["true_ambient"]["name"] == "D65"
    assert len(sequence.leds) == 4 and len(sequence.frames) == 5
    assert sequence.load_frame(0).shape == (78, 110)  # the Macbeth chart at 16-pixel patches, not the default chart
    _assert_released(aravis)


def test_the_test_pattern_form_keeps_mono_frames(aravis: ModuleType) -> None:
    """``rendered=False`` (the capture bench's transport figures): the fake's own Mono16 pattern, a nominal camera."""
    rig = open_aravis_fake_rig(rendered=False)
    try:
        plan = CapturePlan.single((0.0,) * 7, 1_000.0, role="ambient")
        rig.camera.prepare(plan)
        rig.camera.start()
        rig.camera.trigger()
        frame = rig.camera.next_frame(5.0)
        rig.camera.stop()
        assert rig.mono and rig.camera.info.pixel_format == "Mono16" and rig.camera.info.cfa is None
        assert frame.pixels.shape == (48, 64) and rig.true_ambient is None
        assert "nominal" in rig.camera_extra["responsivity_note"] and rig.camera.rendered_levels == ()
    finally:
        rig.close()
    _assert_released(aravis)


def test_a_roi_other_than_the_scene_is_refused(aravis: ModuleType) -> None:
    """Checked before the fake is served: the rendered mosaic fills the ROI."""
    with pytest.raises(UsageError, match=r"ROI 64x48 but the scene is 200x186; expected the scene's size"):
        open_aravis_fake_rig(width=64, height=48)


def test_rig_leds_off_and_fake_released_after_close(aravis: ModuleType) -> None:
    rig = open_rig("aravis-fake")
    try:
        rig.booth.set_levels([0.5] * 7)
        assert rig.emulator is not None and max(rig.emulator.levels) > 0
        header = rig.sequence_header()
        assert len(header[0]) == len(header[2][0].spd) == 31
    finally:
        rig.close()
    assert rig.emulator.levels == (0.0,) * 7
    _assert_released(aravis)


def test_an_exposure_below_the_fakes_range_is_bad_input(aravis: ModuleType, tmp_path, capsys) -> None:
    """The fake's ExposureTime starts at 10 µs: --exposure-us 2 is refused up front, naming the camera's
    own range (it passed the default range and failed later at the camera, exit 1)."""
    status = main(["capture", "--rig", "aravis-fake", "--exposure-us", "2", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2
    assert err[-1].startswith("msflash: error: --exposure 2: outside the camera's range 10–")


def _lamp_light(lamp: Any, since_first_ns: int, exposure_us: float) -> float:
    """The lamp's mean light over a frame's exposure, the frame starting ``since_first_ns`` after the first frame."""
    return float(lamp.window_means(np.array([since_first_ns * 1e-9]), exposure_us * 1e-6)[0])


def test_the_mains_is_fitted_from_the_fakes_timestamps(aravis: ModuleType, tmp_path, capfd) -> None:
    """A flickering lamp on the aravis-fake keeps the camera's clock (the GigE fake's timestamps, as a real camera's
    stamp its exposures on a clock that keeps real time with the mains): each LED frame's ambient gain read from its
    pixels is the lamp's at that frame's recorded timestamp, and a decisive mains fit is the lamp's. Before, the lamp
    ran on a simulated clock of its own and no fit was ever decisive.

    Whether the fit is decisive is not asked here (it was, and the test failed under load): the fake stamps real
    time, so the frames are as far apart as the host paced them. A pause of the process (a loaded machine; a lost
    frame's retake waits out the frame timeout, over 1 s) puts aliases ``f ± 1/gap`` of the lamp inside the searched
    ±1 % band, where no fit can tell them apart; a 1 s pause before the fifth trigger left it undecided; and even
    frames 10-30 ms apart leave it undecided in a few draws per thousand of their times. Decisiveness is pinned on
    fixed times in tests/harness/test_flicker.py."""
    from msflash.acquisition.devices.mains_flicker import MainsFlicker

    out = tmp_path / "flicker"
    argv = ["run", "--rig", "aravis-fake", "--flicker", "100:0.6", "--exposure", "2000", "--seed", "4"]
    assert main([*argv, "--out", str(out)]) == 0
    err = capfd.readouterr().err
    flicker = json.loads((out / "estimate.json").read_text())["flicker"]
    recorded = json.loads((out / "sequence" / "sequence.json").read_text())
    truth = recorded["msflash"]["true_flicker"]
    lamp = MainsFlicker(truth["frequency_hz"], truth["depth"], truth["waveform"], truth["phase_cycles"])
    frames = [frame for frame in recorded["frames"] if frame["role"] in ("ambient", "led")]
    assert [frame["role"] for frame in frames] == ["ambient"] + ["led"] * 7
    first = frames[0]["timestamp_ns"]
    light = np.array([_lamp_light(lamp, f["timestamp_ns"] - first, f["exposure_us"]) for f in frames])
    assert flicker["detected"]
    # A lamp on a clock of its own would miss by up to 0.7 here; the read's own bias is under 0.05 (LED 6's
    # curvature share), its noise about 0.005.
    assert flicker["frame_gains"] == pytest.approx(light[1:] / light[0], abs=0.08)
    if flicker["frequency_hz"] is not None:  # decisive: then the lamp's, and the run's line says so
        assert flicker["frequency_hz"] == pytest.approx(truth["frequency_hz"], abs=1.5)  # 8 frames over ~0.25 s
        assert flicker["depth"] == pytest.approx(truth["depth"], abs=0.08)
        assert f"; fitted {flicker['frequency_hz']:.1f} Hz, depth {flicker['depth']:.0%}" in err
    else:
        assert "; fitted " not in err
    _assert_released(aravis)
