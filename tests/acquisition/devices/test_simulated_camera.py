"""SimulatedCamera: the Camera protocol over a rendered spectral world."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from msflash.acquisition.devices.camera import Camera
from msflash.acquisition.devices.simulated_camera import SimulatedCamera
from msflash.acquisition.errors import CameraError, FrameTimeoutError
from msflash.acquisition.plan import CapturePlan
from msflash.processing import datasets, lights
from msflash.processing.image_formation import expected_response, total_illumination
from msflash.processing.scenes import chart_scene
from msflash.processing.sensor import SensorModel, cfa_channel_map
from msflash.processing.spectra import DEFAULT_GRID, Spectra

N_LEDS = 7


def small_world(**options: object) -> SimulatedCamera:
    """A fast world without colour-science: flat ambient, Macbeth chart, paper LEDs, NikonD100."""
    scene = chart_scene(datasets.macbeth().resample(DEFAULT_GRID), patch_px=3, border_px=1, specular_strip_px=2)
    ambient = Spectra(DEFAULT_GRID, np.ones(DEFAULT_GRID.size), ("flat",), source="flat test ambient")
    leds = datasets.paper_leds().resample(DEFAULT_GRID)
    leds = leds.replace(values=leds.values / leds.values.max())
    camera = datasets.isetcam_camera("NikonD100").resample(DEFAULT_GRID)
    settings: dict = dict(scale=0.02, seed=3) | options
    return SimulatedCamera(scene, ambient, leds, camera, SensorModel(), **settings)


def capture(camera: SimulatedCamera, plan: CapturePlan) -> list:
    camera.prepare(plan)
    camera.start()
    frames = []
    for _ in plan.steps:
        camera.trigger()
        frames.append(camera.next_frame(timeout_s=10.0))
    camera.stop()
    return frames


class TestProtocol:
    def test_is_a_camera(self) -> None:
        camera = small_world()
        assert isinstance(camera, Camera)
        info = camera.info
        assert (info.height, info.width) == camera.scene.shape
        assert (info.pixel_format, info.black_level, info.white_level) == ("RGB16", 256.0, 65535.0)

    def test_one_frame_per_step_with_the_plan_settings(self) -> None:
        camera = small_world()
        exposures = [1000.0 + 100 * k for k in range(N_LEDS)]
        plan = CapturePlan.ambient_then_each_led(N_LEDS, 2000.0, gain=2.0, led_exposures_us=exposures)
        frames = capture(camera, plan)
        assert len(frames) == N_LEDS + 1
        assert [f.frame_id for f in frames] == list(range(1, N_LEDS + 2))
        assert all(b.timestamp_ns > a.timestamp_ns for a, b in zip(frames, frames[1:]))
        assert [f.exposure_us for f in frames] == [2000.0] + exposures
        assert all(f.gain == 2.0 for f in frames)
        assert frames[0].pixels.shape == camera.scene.shape + (3,) and frames[0].pixels.dtype == np.uint16
        assert not frames[0].pixels.flags.writeable
        assert camera.rendered_levels == tuple(step.led_levels for step in plan.steps)

    def test_frames_follow_eq_1_to_3(self) -> None:
        camera = small_world(noise=False)
        plan = CapturePlan.ambient_then_each_led(N_LEDS, 3000.0)
        frames = capture(camera, plan)
        ambient = frames[0].pixels.astype(float)
        diffuse = ~camera.scene.specular
        dark = camera.ambient.replace(values=np.zeros_like(camera.ambient.values))
        for k, frame in enumerate(frames[1:]):
            flash_only = frame.pixels.astype(float) - ambient
            expected = (
                expected_response(
                    camera.scene,
                    total_illumination(dark, camera.led_spectra, np.eye(N_LEDS)[k]),
                    camera.camera_responsivities,
                    3000.0,
                    1.0,
                    camera.scale,
                )
                / camera.sensor.electrons_per_dn
            )
            unclipped = diffuse[..., None] & (frame.pixels < camera.sensor.white_level)
            assert unclipped.sum() > 0.9 * diffuse.sum() * 3
            np.testing.assert_allclose(flash_only[unclipped], expected[unclipped], atol=1.0)  # rounding only

    def test_same_seed_same_frames(self) -> None:
        plan = CapturePlan.ambient_then_each_led(N_LEDS, 1000.0)
        first = capture(small_world(seed=11), plan)
        second = capture(small_world(seed=11), plan)
        other = capture(small_world(seed=12), plan)
        for a, b, c in zip(first, second, other):
            np.testing.assert_array_equal(a.pixels, b.pixels)
            assert not np.array_equal(a.pixels, c.pixels)


class TestInjectedLevels:
    def test_levels_are_read_at_trigger_time(self) -> None:
        held = {"levels": (0.0,) * N_LEDS}
        camera = small_world(led_levels_source=lambda: held["levels"], noise=False)
        plan = CapturePlan.ambient_then_each_led(N_LEDS, 1000.0)
        camera.prepare(plan)
        camera.start()
        sent = [(0.0,) * N_LEDS, (0.5,) + (0.0,) * 6, (0.0,) * 6 + (1.0,)]
        for levels in sent:
            held["levels"] = levels
            camera.trigger()
            held["levels"] = (1.0,) * N_LEDS  # changed after the exposure: must not matter
        frames = [camera.next_frame(10.0) for _ in sent]
        assert camera.rendered_levels == tuple(sent)  # the source's levels, not the plan's
        assert len(frames) == 3
        reference = small_world(noise=False)
        reference.prepare(CapturePlan.single(sent[1], 1000.0))
        reference.start()
        reference.trigger()
        np.testing.assert_array_equal(frames[1].pixels, reference.next_frame(1.0).pixels)

    @pytest.mark.parametrize("levels", [(0.5,) * 3, (2.0,) * N_LEDS, ("x",) * N_LEDS])
    def test_bad_levels_from_the_source(self, levels: tuple) -> None:
        camera = small_world(led_levels_source=lambda: levels)
        camera.prepare(CapturePlan.ambient_then_each_led(N_LEDS, 1000.0))
        camera.start()
        with pytest.raises(CameraError, match="LED levels"):
            camera.trigger()


class TestTriggeringAndErrors:
    def test_timeout_without_a_trigger_is_immediate(self) -> None:
        camera = small_world()
        camera.prepare(CapturePlan.ambient_then_each_led(N_LEDS, 1000.0))
        camera.start()
        # nothing was triggered: raises at once instead of waiting 100 s
        with pytest.raises(FrameTimeoutError, match=r"step 0 \(ambient\).*no trigger was issued"):
            camera.next_frame(timeout_s=100.0)
        camera.trigger()
        camera.next_frame(timeout_s=100.0)
        with pytest.raises(FrameTimeoutError, match=r"step 1 \(led:1\)"):
            camera.next_frame(timeout_s=100.0)

    def test_booth_triggered_plan_uses_the_trigger_line(self) -> None:
        camera = small_world()
        plan = CapturePlan(CapturePlan.ambient_then_each_led(N_LEDS, 1000.0).steps, trigger="booth")
        camera.prepare(plan)
        camera.start()
        camera.trigger()  # the protocol's software trigger is a no-op for a hardware-paced camera
        with pytest.raises(FrameTimeoutError, match="the trigger did not arrive"):
            camera.next_frame(timeout_s=0.01)
        line = threading.Thread(target=camera.trigger_line)
        line.start()
        frame = camera.next_frame(timeout_s=30.0)
        line.join()
        assert frame.frame_id == 1 and camera.rendered_levels == ((0.0,) * N_LEDS,)

    def test_misuse_is_named(self) -> None:
        camera = small_world()
        with pytest.raises(CameraError, match="before start"):
            camera.trigger()
        with pytest.raises(CameraError, match="start\\(\\) before prepare"):
            camera.start()
        with pytest.raises(CameraError, match="plan drives 3 LEDs but the world has 7"):
            camera.prepare(CapturePlan.ambient_then_each_led(3, 1000.0))
        camera.prepare(CapturePlan.single((0.0,) * N_LEDS, 1000.0, role="ambient"))
        camera.start()
        camera.trigger()
        with pytest.raises(CameraError, match="trigger 2 but the plan has 1 steps"):
            camera.trigger()
        camera.stop()
        camera.stop()
        camera.close()
        camera.close()
        with pytest.raises(CameraError, match="after close"):
            camera.prepare(CapturePlan.single((0.0,) * N_LEDS, 1000.0))


@pytest.fixture(scope="module")
def default_world() -> SimulatedCamera:
    return SimulatedCamera.default(seed=5)


class TestDefaultWorld:
    def test_default_world_is_sensible(self, default_world: SimulatedCamera) -> None:
        camera = default_world
        assert camera.led_spectra.names == datasets.paper_leds().names
        np.testing.assert_allclose(camera.true_ambient.values, lights.ambient_spectrum("tungsten").values)
        assert camera.suggested_exposure_us is not None
        # A colour machine-vision camera: a 12-bit raw RGGB mosaic above a black pedestal.
        assert camera.info.pixel_format == "BayerRG12" and camera.info.cfa == "RGGB"
        assert (camera.sensor.bit_depth, camera.sensor.black_level, camera.sensor.white_level) == (12, 240.0, 4095.0)
        frames = capture(camera, CapturePlan.ambient_then_each_led(N_LEDS, camera.suggested_exposure_us))
        assert frames[0].pixels.shape == camera.scene.shape and frames[0].pixels.dtype == np.uint16
        diffuse = ~camera.scene.specular
        white = camera.sensor.white_level
        channels = cfa_channel_map("RGGB", camera.scene.shape)

        def channel_mean(pixels: np.ndarray) -> float:
            """The mean over the diffuse scene of each of R, G and B, averaged (what the LEDs' power is set on)."""
            signal = pixels.astype(float) - camera.sensor.black_level
            return float(np.mean([signal[diffuse & (channels == c)].mean() for c in range(3)]))

        ambient = frames[0].pixels.astype(float) - camera.sensor.black_level
        assert ambient[diffuse].max() < 0.5 * white  # room for the flash
        highlight = camera.scene.specular
        assert np.all(frames[0].pixels[highlight & (channels == 1)] == white)  # the highlight saturates (green)
        ratios = []
        for frame in frames[1:]:
            assert not np.any(frame.pixels[diffuse] >= white)  # ambient + any one LED fits at this exposure
            ratios.append(channel_mean(frame.pixels) / channel_mean(frames[0].pixels) - 1)
        # As a flash: every LED-only image at least the ambient's (flash_power 1: the weakest LED
        # equal to it, the others in the paper's ratios, up to 3.7× with this camera).
        assert min(ratios) == pytest.approx(1.0, abs=0.05)
        assert max(ratios) < 4.0

    def test_default_world_with_a_mosaic(self) -> None:
        camera = SimulatedCamera.default(scene="macbeth", ambient="daylight", cfa="BGGR", seed=1, patch_px=4)
        assert camera.info.pixel_format == "BayerBG12" and camera.info.cfa == "BGGR"
        frames = capture(camera, CapturePlan.ambient_then_each_led(N_LEDS, 10_000.0))
        assert len(frames) == N_LEDS + 1 and frames[0].pixels.shape == camera.scene.shape


def test_render_is_the_renderer_triggers_use() -> None:
    """One renderer: ``render`` under a step's levels, exposure and gain gives the frame ``trigger`` gives
    (same seed, same order), noise included; the aravis-fake rig paints the fake's frames with it."""
    plan = CapturePlan.ambient_then_each_led(N_LEDS, 4_000.0, gain=2.0, led_exposures_us=[3_000.0] * N_LEDS)
    triggered = capture(small_world(), plan)
    world = small_world()
    rendered = [world.render(step.led_levels, step.exposure_us, step.gain) for step in plan.steps]
    for frame, pixels in zip(triggered, rendered):
        assert np.array_equal(frame.pixels, pixels)
    assert not np.array_equal(rendered[0], rendered[1])  # the LED's light is in the frame


@pytest.mark.parametrize(
    ("levels", "exposure_us", "gain", "message"),
    [
        ((0.5,) * (N_LEDS - 1), 1_000.0, 1.0, "expected 7 values in \\[0, 1\\]"),
        ((1.5,) + (0.0,) * (N_LEDS - 1), 1_000.0, 1.0, "expected 7 values in \\[0, 1\\]"),
        (("x",) * N_LEDS, 1_000.0, 1.0, "are not numbers"),
        ((0.0,) * N_LEDS, -1.0, 1.0, "expected exposure ≥ 0 and gain > 0"),
        ((0.0,) * N_LEDS, 1_000.0, 0.0, "expected exposure ≥ 0 and gain > 0"),
    ],
)
def test_render_refuses_bad_levels_exposure_or_gain(
    levels: tuple, exposure_us: float, gain: float, message: str
) -> None:
    with pytest.raises(CameraError, match=message):
        small_world().render(levels, exposure_us, gain)
