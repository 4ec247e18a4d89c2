"""Exposure planning on the sim rig: ambient metering, LED exposures below saturation, SNR.

The sim scene has a specular strip (3.8 % of the pixels, 10× the diffuse signal); with the
bright-end criterion's (the default) 0.1 % saturation budget the strip sets the exposure, as a
highlight would in a photo; the information criterion lets it saturate and exposes the rest longer.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import exposure as ex
from msflash.acquisition.session import led_snr, metering
from msflash.acquisition.session.capture import preview_frames
from msflash.acquisition.session.rig import Rig, open_sim_rig

N_LEDS = 4
POLICY = ex.ExposurePolicy()
INFORMATION = ex.ExposurePolicy(criterion="information")


@pytest.fixture
def rig() -> Iterator[Rig]:
    with open_sim_rig(n_leds=N_LEDS, seed=5) as opened:
        yield opened


def _scale_ambient(rig: Rig, factor: float) -> None:
    camera = rig.camera
    camera.ambient = camera.ambient.replace(values=camera.ambient.values * factor)


def _capture(rig: Rig):
    def capture(levels, exposure_us: float) -> np.ndarray:
        return preview_frames(rig.camera, rig.booth, CapturePlan.single(levels, exposure_us, role="led"))[0].pixels

    return capture


def _plan(
    rig: Rig,
    limits: tuple[float, float] = ex.DEFAULT_EXPOSURE_RANGE_US,
    noise: bool = True,
    policy: ex.ExposurePolicy = POLICY,
) -> ex.ExposurePlan:
    info = rig.camera.info
    return ex.plan_exposures(
        _capture(rig),
        N_LEDS,
        info.black_level,
        info.white_level,
        limits,
        ex.camera_noise_model(rig.camera) if noise else None,
        policy,
        start_us=10_000.0,
        cfa=info.cfa is not None,  # the sim rig's raw mosaic, as run.plan_exposure passes it
    )


def _check_frames(rig: Rig, plan: ex.ExposurePlan) -> tuple[metering.Levels, list[float]]:
    """Capture the planned frames; none saturates beyond the budget; return the ambient's levels and the SNR."""
    info = rig.camera.info
    capture = _capture(rig)
    ambient = capture((0.0,) * N_LEDS, plan.ambient_exposure_us)
    levels = metering.meter(ambient, info.black_level, info.white_level, POLICY)
    assert levels.saturated_fraction <= POLICY.max_saturated_fraction
    leds = []
    for led, exposure in enumerate(plan.led_exposures_us):
        frame = capture(tuple(1.0 if i == led else 0.0 for i in range(N_LEDS)), exposure)
        metered = metering.meter(frame, info.black_level, info.white_level, POLICY)
        assert metered.saturated_fraction <= POLICY.max_saturated_fraction, (led, metered)
        assert metered.bright_end <= POLICY.headroom_fraction * 1.05
        leds.append(frame)
    snr, method = led_snr.measure_led_snr(
        ambient,
        plan.ambient_exposure_us,
        leds,
        plan.led_exposures_us,
        info.black_level,
        info.white_level,
        ex.camera_noise_model(rig.camera),
    )
    assert method == "photon+read noise"
    return levels, snr


def test_normal_ambient_lands_on_target(rig: Rig) -> None:
    plan = _plan(rig)
    levels, snr = _check_frames(rig, plan)
    assert levels.bright_end == pytest.approx(POLICY.target_fraction, rel=POLICY.tolerance)
    assert all(math.isfinite(v) and v > 0 for v in plan.predicted_snr)
    # planned (from a 4× shorter preview) and measured SNR agree
    np.testing.assert_allclose(snr, plan.predicted_snr, rtol=0.35)
    # ambient + LED gets no more than the headroom over the ambient's target: LED exposures ≤ 1.3× ambient
    assert max(plan.led_exposures_us) <= plan.ambient_exposure_us * POLICY.headroom_fraction / (
        POLICY.target_fraction * (1 - POLICY.tolerance)
    )
    assert plan.to_dict()["led_exposures_us"] == list(plan.led_exposures_us)


@pytest.mark.parametrize("factor", [30.0, 0.01])
def test_too_bright_and_too_dark_ambients(rig: Rig, factor: float) -> None:
    reference = _plan(rig).ambient_exposure_us
    _scale_ambient(rig, factor)
    plan = _plan(rig)
    levels, _ = _check_frames(rig, plan)
    # the sensor is linear: exposure scales inversely with the light
    assert plan.ambient_exposure_us == pytest.approx(reference / factor, rel=0.2)
    assert levels.bright_end == pytest.approx(POLICY.target_fraction, rel=POLICY.tolerance)
    assert not any("did not settle" in w for w in plan.warnings)


def test_camera_exposure_limit_gives_a_too_dark_warning(rig: Rig) -> None:
    _scale_ambient(rig, 0.01)
    plan = _plan(rig, limits=(10.0, 20_000.0))
    assert plan.ambient_exposure_us == 20_000.0
    assert all(10.0 <= e <= 20_000.0 for e in plan.led_exposures_us)
    assert any("ambient too dark" in w for w in plan.warnings)


def test_too_bright_at_the_shortest_exposure_warns(rig: Rig) -> None:
    _scale_ambient(rig, 1000.0)
    plan = _plan(rig, limits=(50.0, 1e6))
    assert plan.ambient_exposure_us == 50.0 and any("ambient too bright" in w for w in plan.warnings)


def test_difference_image_snr_without_a_noise_model(rig: Rig) -> None:
    with_model = _plan(rig)
    without = _plan(rig, noise=False)
    assert without.snr_method == "difference image"
    np.testing.assert_allclose(without.predicted_snr, with_model.predicted_snr, rtol=0.5)


def test_flash_exposure_keeps_the_flash_frame_below_saturation(rig: Rig) -> None:
    plan = _plan(rig)
    info = rig.camera.info
    capture = _capture(rig)
    ambient = capture((0.0,) * N_LEDS, plan.ambient_exposure_us)
    leds = [
        capture(tuple(1.0 if i == k else 0.0 for i in range(N_LEDS)), e) for k, e in enumerate(plan.led_exposures_us)
    ]
    weights = np.ones(N_LEDS)
    exposure = metering.flash_exposure(
        ambient,
        plan.ambient_exposure_us,
        leds,
        plan.led_exposures_us,
        weights,
        info.black_level,
        info.white_level,
        plan.exposure_range_us,
        POLICY,
    )
    flash = capture(tuple(weights), exposure)
    levels = metering.meter(flash, info.black_level, info.white_level, POLICY)
    assert levels.saturated_fraction <= POLICY.max_saturated_fraction
    assert levels.bright_end == pytest.approx(POLICY.target_fraction, rel=0.15)


def test_capture_reports_exposures_and_snr(tmp_path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "c"
    assert main(["capture", "--out", str(out), "--ambient", "daylight"]) == 0
    err = capsys.readouterr().err
    assert "exposure (auto): ambient" in err and "LED SNR (photon+read noise" in err
    sequence = read_sequence(out / "sequence")
    planned = sequence.extra["msflash"]["exposure"]
    assert planned["mode"] == "auto" and len(planned["predicted_led_snr"]) == 7
    assert [f.exposure_us for f in sequence.frames[1:]] == pytest.approx(planned["led_exposures_us"])
    assert planned["policy"]["criterion"] == "bright_end" and planned["lost_block_fraction"] is None
    for index in range(len(sequence.frames)):
        pixels = sequence.load_frame(index)
        saturated = np.mean((pixels >= sequence.camera.white_level).any(axis=-1))
        assert saturated <= POLICY.max_saturated_fraction


def test_fixed_exposure_and_bad_values(tmp_path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "f"
    assert main(["capture", "--out", str(out), "--exposure-us", "4000"]) == 0
    sequence = read_sequence(out / "sequence")
    assert {f.exposure_us for f in sequence.frames} == {4000.0}
    assert sequence.extra["msflash"]["exposure"]["mode"] == "fixed"
    capsys.readouterr()
    assert main(["capture", "--out", str(tmp_path / "g"), "--exposure", "-3"]) == 2
    assert "--exposure" in capsys.readouterr().err


def test_run_json_reports_exposure_and_snr(tmp_path) -> None:
    out = tmp_path / "r"
    assert main(["run", "--out", str(out), "--ambient", "fluorescent", "--scene", "macbeth"]) == 0
    summary = json.loads((out / "run.json").read_text())
    exposure = summary["exposure"]
    assert exposure["mode"] == "auto" and len(exposure["led_snr"]) == 7
    assert all(v > 0 for v in exposure["led_snr"]) and exposure["flash_exposure_us"] > 0
    assert summary["decision_ms"] >= 0
    flash = read_sequence(out / "sequence").frames[-1]
    assert flash.role == "flash" and flash.exposure_us == pytest.approx(exposure["flash_exposure_us"])


@pytest.mark.parametrize("dtype", [np.float64, np.uint16])
def test_linear_quantile_is_numpy_quantile_bit_for_bit(dtype) -> None:
    rng = np.random.default_rng(7)
    for _ in range(300):
        n = int(rng.integers(1, 5000))
        values = (rng.random(n) * 60_000).astype(dtype)
        if dtype is np.float64 and rng.random() < 0.5:
            values = np.round(values / 1000.0)  # ties
        for q in (0.0, 0.5, 0.999, 1.0, float(rng.random())):
            assert metering.linear_quantile(values, q) == float(np.quantile(values, q))
    kept = np.array([5.0, 1.0, 3.0])
    metering.linear_quantile(kept, 0.5)
    assert kept.tolist() == [5.0, 1.0, 3.0]  # partitions a copy unless told to overwrite
    assert math.isnan(metering.linear_quantile(np.array([1.0, math.nan, 2.0]), 0.5))
    with pytest.raises(ValueError, match="no values"):
        metering.linear_quantile(np.array([]), 0.5)


@pytest.mark.parametrize("channels", [0, 3])
def test_flash_exposure_from_frames_as_they_arrive(channels: int) -> None:
    """FlashExposure (frames added one by one) = the one-shot flash_exposure = the linear model written out."""
    rng = np.random.default_rng(channels)
    shape = (48, 64, channels) if channels else (48, 64)
    black, white, limits = 64.0, 4095.0, (10.0, 50_000.0)
    ambient = rng.integers(64, 1500, size=shape).astype(np.uint16)
    leds = [(ambient + rng.integers(0, 800, size=shape)).astype(np.uint16) for _ in range(5)]
    ambient_us, led_us = 2000.0, [1000.0, 1500.0, 2000.0, 2500.0, 3000.0]
    predictor = metering.FlashExposure(black, white, limits, POLICY)
    predictor.add_ambient(ambient, ambient_us)
    for frame, exposure in zip(leds, led_us):
        predictor.add_led(frame, exposure)
    step = 2 * POLICY.stride

    def sampled(frame: np.ndarray) -> np.ndarray:
        # RGB: every step-th pixel; a one-plane (mosaic) frame: every (step/2)-th 2×2 quad, its four sites as channels
        if frame.ndim == 3:
            return frame[::step, ::step]
        return np.stack([frame[i::2, j::2][:: step // 2, :: step // 2] for i in (0, 1) for j in (0, 1)], axis=2)

    rate = (sampled(ambient).astype(float) - black) / ambient_us
    for weights in ([0.3, 0.0, 1.0, 0.2, 0.7], [0.0] * 5, [1.0] * 5):
        one_shot = metering.flash_exposure(ambient, ambient_us, leds, led_us, weights, black, white, limits, POLICY)
        assert predictor.predict(weights) == one_shot
        total = rate + sum(
            w * ((sampled(f).astype(float) - black) / e - rate) for f, e, w in zip(leds, led_us, weights)
        )
        brightest = total.max(axis=2)
        bright_end = np.quantile(brightest, 1.0 - POLICY.max_saturated_fraction)
        expected = min(max(POLICY.target_fraction * (white - black) / bright_end, limits[0]), limits[1])
        assert one_shot == pytest.approx(expected, rel=1e-12)
    with pytest.raises(ValueError, match="strict|shorter|longer"):
        predictor.predict([1.0] * 4)  # one weight per LED frame


def test_flash_exposure_refuses_frames_out_of_order() -> None:
    predictor = metering.FlashExposure(0.0, 4095.0, (1.0, 1e5), POLICY)
    frame = np.ones((8, 8), dtype=np.uint16)
    with pytest.raises(ValueError, match="before the ambient"):
        predictor.add_led(frame, 100.0)
    with pytest.raises(ValueError, match="no ambient frame"):
        predictor.predict([])
    predictor.add_ambient(frame, 100.0)
    with pytest.raises(ValueError, match="second ambient"):
        predictor.add_ambient(frame, 100.0)


# -- the information criterion -----------------------------------------------------------------

BLACK, WHITE = 0.0, 4095.0
NOISE = led_snr.NoiseModel(electrons_per_dn=2.0, read_noise_e=3.0)


def _lost_blocks(frames, white: float, block: int = 4) -> float:
    """Fraction of ``block × block`` blocks with a pixel at white in any frame (the estimator's rule)."""
    union = None
    for frame in frames:
        saturated = frame >= white
        saturated = saturated.any(axis=-1) if saturated.ndim == 3 else saturated
        rows, cols = saturated.shape[0] // block, saturated.shape[1] // block
        blocks = saturated[: rows * block, : cols * block].reshape(rows, block, cols, block).any(axis=(1, 3))
        union = blocks if union is None else union | blocks
    return float(np.mean(union))


def _synthetic(ambient: np.ndarray, leds: list[np.ndarray]):
    """A noise-free linear sensor: ``capture(levels, t)`` = clip(black + t·(ambient + Σ level·LED-only))."""

    def capture(levels, exposure_us: float) -> np.ndarray:
        rate = ambient + sum(level * led for level, led in zip(levels, leds))
        return np.minimum(BLACK + rate * exposure_us, WHITE)

    return capture


def _scene(
    strips: list[tuple[int, int]], n_leds: int = 1, ambient_strips: bool = True
) -> tuple[np.ndarray, list[np.ndarray]]:
    """64×64×3 rates: a textured diffuse scene; LED k's rows ``strips[k]`` 10× brighter (the ambient's too:
    a specular strip; or not: each LED's own glare)."""
    rng = np.random.default_rng(3)
    diffuse = 0.5 + 0.5 * rng.random((64, 64, 1)) * np.array([1.0, 0.8, 0.6])
    ambient = diffuse.copy()
    leds = []
    for k in range(n_leds):
        led = 0.3 * diffuse
        rows = slice(*strips[k % len(strips)])
        led[rows] *= 10.0
        if ambient_strips:
            ambient[rows] = diffuse[rows] * 10.0
        leds.append(led)
    return ambient, leds


def _plan_synthetic(ambient, leds, criterion: str, **policy) -> ex.ExposurePlan:
    chosen = ex.ExposurePolicy(criterion=criterion, **policy)
    return ex.plan_exposures(
        _synthetic(ambient, leds), len(leds), BLACK, WHITE, (1.0, 1e6), NOISE, chosen, start_us=100.0
    )


def _frames(plan: ex.ExposurePlan, ambient, leds) -> list[np.ndarray]:
    capture = _synthetic(ambient, leds)
    n = len(leds)
    return [capture((0.0,) * n, plan.ambient_exposure_us)] + [
        capture(tuple(1.0 if i == k else 0.0 for i in range(n)), t) for k, t in enumerate(plan.led_exposures_us)
    ]


def test_information_lets_a_bright_strip_saturate_and_exposes_the_rest_longer() -> None:
    ambient, leds = _scene([(8, 12)])  # 4 of 64 rows (6 %) 10× brighter
    bright = _plan_synthetic(ambient, leds, "bright_end")
    informed = _plan_synthetic(ambient, leds, "information")
    # the strip sets the bright end; the information criterion gives it up (only it) for ~10× the exposure
    assert _lost_blocks(_frames(bright, ambient, leds), WHITE) == 0.0
    lost = _lost_blocks(_frames(informed, ambient, leds), WHITE)
    assert lost == pytest.approx(1 / 16) and informed.lost_block_fraction == pytest.approx(lost)
    for before, after in zip(bright.led_exposures_us, informed.led_exposures_us):
        assert after > 5 * before
    assert informed.ambient_exposure_us > 5 * bright.ambient_exposure_us
    assert all(a > 2 * b for a, b in zip(informed.predicted_snr, bright.predicted_snr))
    # outside the strip nothing saturates: the headroom holds
    for frame in _frames(informed, ambient, leds):
        assert frame[16:].max() <= INFORMATION.headroom_fraction * WHITE * 1.000001


def test_information_on_a_uniform_scene_is_the_bright_end() -> None:
    ambient = np.full((64, 64, 3), 1.0)
    leds = [np.full((64, 64, 3), 0.4), np.full((64, 64, 3), 0.1)]
    bright = _plan_synthetic(ambient, leds, "bright_end")
    informed = _plan_synthetic(ambient, leds, "information")
    # nothing to trade: each LED frame's bright end at the headroom, as the bright-end rule puts it
    np.testing.assert_allclose(informed.led_exposures_us, bright.led_exposures_us, rtol=1e-9)
    assert informed.lost_block_fraction == 0.0
    # the ambient frame goes to the headroom too (its noise enters every LED-only difference)
    assert informed.ambient_exposure_us * 1.0 == pytest.approx(INFORMATION.headroom_fraction * WHITE, rel=1e-9)
    assert _lost_blocks(_frames(informed, ambient, leds), WHITE) == 0.0


@pytest.mark.parametrize("bound", [0.0, 0.1, 0.2])
def test_information_keeps_the_union_of_lost_blocks_within_the_bound(bound: float) -> None:
    # two specular strips (6 % of the blocks each, 12 % together), in every frame
    ambient, leds = _scene([(8, 12), (40, 44)], n_leds=2)
    plan = _plan_synthetic(ambient, leds, "information", max_lost_fraction=bound)
    lost = _lost_blocks(_frames(plan, ambient, leds), WHITE)
    # the plan counts a block lost when it passes the headroom (a margin below white)
    past_headroom = _lost_blocks(_frames(plan, ambient, leds), INFORMATION.headroom_fraction * WHITE * 1.000001)
    assert lost <= past_headroom == pytest.approx(plan.lost_block_fraction) and past_headroom <= bound
    # at 0 nothing is lost; at 20 % both strips go, and every frame is exposed for the diffuse scene
    if bound == 0.0:
        assert lost == 0.0
    if bound == 0.2:
        bright = _plan_synthetic(ambient, leds, "bright_end")
        assert lost == pytest.approx(2 / 16)
        assert all(a > 5 * b for a, b in zip(plan.led_exposures_us, bright.led_exposures_us))


def test_information_keeps_a_strip_whose_led_only_signal_outweighs_the_gain() -> None:
    # glare of the LED alone (not the ambient): its LED-only signal is 10× the diffuse one, so each of its
    # pixels carries ~60× a diffuse pixel's information; exposing 3× longer would not pay for losing it
    ambient, leds = _scene([(8, 12)], ambient_strips=False)
    plan = _plan_synthetic(ambient, leds, "information")
    assert _lost_blocks(_frames(plan, ambient, leds), WHITE) == 0.0


def test_information_plan_on_the_sim_rig_predicts_its_losses_and_gains_snr(rig: Rig) -> None:
    bright = _plan(rig)
    informed = _plan(rig, policy=INFORMATION)
    info = rig.camera.info
    capture = _capture(rig)
    frames = [capture((0.0,) * N_LEDS, informed.ambient_exposure_us)] + [
        capture(tuple(1.0 if i == k else 0.0 for i in range(N_LEDS)), t)
        for k, t in enumerate(informed.led_exposures_us)
    ]
    block = 8 if info.cfa is not None else 4  # the estimator's 4 × 4 blocks of a CFA plane: 8 × 8 pixels of a mosaic
    lost = _lost_blocks(frames, info.white_level, block)
    past_headroom = _lost_blocks(
        frames, info.black_level + INFORMATION.headroom_fraction * (info.white_level - info.black_level), block
    )
    assert 0 < lost <= past_headroom <= INFORMATION.max_lost_fraction
    assert past_headroom == pytest.approx(informed.lost_block_fraction, abs=0.02)
    snr, _ = led_snr.measure_led_snr(
        frames[0],
        informed.ambient_exposure_us,
        frames[1:],
        informed.led_exposures_us,
        info.black_level,
        info.white_level,
        ex.camera_noise_model(rig.camera),
    )
    _, before = _check_frames(rig, bright)
    gains = np.array(snr) / np.array(before)
    assert gains.min() > 1.2 and np.median(gains) > 2.0, gains


def test_policy_refuses_an_unknown_criterion() -> None:
    with pytest.raises(ValueError, match="criterion 'brightest'; expected one of bright_end, information"):
        ex.ExposurePolicy(criterion="brightest")
    with pytest.raises(ValueError, match="max_lost_fraction"):
        ex.ExposurePolicy(max_lost_fraction=1.5)


def test_capture_with_the_information_criterion_from_the_command_line(tmp_path, capsys: pytest.CaptureFixture) -> None:
    """``--exposure-criterion information --max-lost 10`` reaches the plan: longer LED exposures, ≤ 10 % blocks lost."""
    bright, informed = tmp_path / "b", tmp_path / "i"
    assert main(["capture", "--out", str(bright), "--ambient", "tungsten"]) == 0
    assert (
        main(
            [
                "capture",
                "--out",
                str(informed),
                "--ambient",
                "tungsten",
                "--exposure-criterion",
                "information",
                "--max-lost",
                "10",
            ]
        )
        == 0
    )
    plans = [read_sequence(out / "sequence").extra["msflash"]["exposure"] for out in (bright, informed)]
    assert plans[1]["policy"]["criterion"] == "information"
    assert plans[1]["policy"]["max_lost_fraction"] == pytest.approx(0.10)
    assert 0 <= plans[1]["lost_block_fraction"] <= 0.10
    assert sum(plans[1]["led_exposures_us"]) > sum(plans[0]["led_exposures_us"])
    capsys.readouterr()
    assert (
        main(["capture", "--out", str(tmp_path / "x"), "--exposure-criterion", "information", "--max-lost", "150"]) == 2
    )
    assert "--max-lost: '150'" in capsys.readouterr().err


def test_a_mosaic_is_metered_on_every_colour_site() -> None:
    """An even stride on a raw mosaic would read one CFA site: a frame bright only on the blue sites
    must meter bright (and saturate) all the same."""
    frame = np.full((64, 64), 100, dtype=np.uint16)
    frame[1::2, 1::2] = 4095  # every blue site of an RGGB mosaic saturated, red sites dark
    levels = metering.meter(frame, 64.0, 4095.0, POLICY)
    assert levels.saturated_fraction == 1.0  # every 2×2 quad holds a saturated site
    assert levels.bright_end == pytest.approx(1.0)


@pytest.mark.parametrize("criterion", ["bright_end", "information"])
def test_a_mono_camera_meters_as_its_frames_recorded_in_rgb(criterion: str) -> None:
    """A mono camera's (H, W) frames, read through metering_view, give the plan, the LED SNR and the
    flash exposure of the same frames as three identical channels (how the sequence records them),
    not those of 2×2 neighbour quads."""
    rng = np.random.default_rng(8)
    ambient = 0.4 + rng.random((48, 64))
    leds = [0.2 * rng.random((48, 64)) + 0.05 * k for k in range(3)]
    ambient[5:9, 10:30] *= 12.0  # a highlight to meter
    mono, rgb = _synthetic(ambient, leds), _synthetic(ambient[..., None], [led[..., None] for led in leds])
    chosen = ex.ExposurePolicy(criterion=criterion)

    def as_mono(levels, exposure_us):
        return metering.metering_view(mono(levels, exposure_us), mosaic=False)

    def as_rgb(levels, exposure_us):
        return np.repeat(rgb(levels, exposure_us), 3, axis=2)

    planned = ex.plan_exposures(as_mono, 3, BLACK, WHITE, (1.0, 1e6), NOISE, chosen, start_us=100.0)
    reference = ex.plan_exposures(as_rgb, 3, BLACK, WHITE, (1.0, 1e6), NOISE, chosen, start_us=100.0)
    assert planned.ambient_exposure_us == reference.ambient_exposure_us
    assert planned.led_exposures_us == reference.led_exposures_us
    np.testing.assert_allclose(planned.predicted_snr, reference.predicted_snr, rtol=1e-12)
    frames = [as_mono((0.0,) * 3, 500.0)] + [as_mono(tuple(float(i == k) for i in range(3)), 400.0) for k in range(3)]
    coloured = [np.repeat(f, 3, axis=2) for f in frames]
    for noise in (NOISE, None):
        ours = led_snr.measure_led_snr(frames[0], 500.0, frames[1:], [400.0] * 3, BLACK, WHITE, noise)
        assert ours == led_snr.measure_led_snr(coloured[0], 500.0, coloured[1:], [400.0] * 3, BLACK, WHITE, noise)
    weights = [0.5, 0.0, 1.0]
    assert metering.flash_exposure(
        frames[0], 500.0, frames[1:], [400.0] * 3, weights, BLACK, WHITE, (1.0, 1e6), POLICY
    ) == metering.flash_exposure(
        coloured[0], 500.0, coloured[1:], [400.0] * 3, weights, BLACK, WHITE, (1.0, 1e6), POLICY
    )
    quads = metering.flash_exposure(
        frames[0][:, :, 0],
        500.0,
        [f[:, :, 0] for f in frames[1:]],
        [400.0] * 3,
        weights,
        BLACK,
        WHITE,
        (1.0, 1e6),
        POLICY,
    )
    assert quads != metering.flash_exposure(
        frames[0], 500.0, frames[1:], [400.0] * 3, weights, BLACK, WHITE, (1.0, 1e6), POLICY
    )
