"""The simulated lamp's mains flicker (acquisition/devices/mains_flicker.py) and the sim camera rendering it."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.acquisition.devices.mains_flicker import FLICKER_WAVEFORMS, MainsFlicker, drawn_flicker, parse_flicker
from msflash.acquisition.devices.simulated_camera import SimulatedCamera


@pytest.mark.parametrize("waveform", FLICKER_WAVEFORMS)
def test_whole_periods_see_the_mean_and_instants_the_depth(waveform: str) -> None:
    lamp = MainsFlicker(100.0, 0.3, waveform, phase=0.17)
    starts = np.linspace(0.0, 0.05, 37)
    assert np.allclose(lamp.window_means(starts, 0.01), 1.0, atol=1e-6)  # one period
    assert np.allclose(lamp.window_means(starts, 0.03), 1.0, atol=1e-6)  # three
    instants = lamp.window_means(np.linspace(0.0, 0.01, 4001), 0.0)
    depth = (instants.max() - instants.min()) / (instants.max() + instants.min())
    assert depth == pytest.approx(0.3, abs=2e-3)
    short = lamp.window_means(starts, 0.002)
    assert short.max() - short.min() > 0.2  # 2 ms windows see the flicker


def test_the_drawn_lamp_is_near_nominal_and_reproducible() -> None:
    lamp = drawn_flicker(120.0, 0.5, "clipped", seed=3)
    assert lamp == drawn_flicker(120.0, 0.5, "clipped", seed=3)
    assert abs(lamp.frequency_hz - 120.0) <= 1.2 and 0.0 <= lamp.phase < 1.0
    assert lamp.to_dict()["depth"] == 0.5


@pytest.mark.parametrize(
    "text, named",
    [
        ("abc", "HZ:DEPTH"),
        ("100:x", "numbers"),
        ("100:0", "depth"),
        ("100:1.5", "depth"),
        ("0:0.3", "frequency"),
        ("100:0.3:square", "waveform"),
    ],
)
def test_bad_flicker_text_says_what_is_wrong(text: str, named: str) -> None:
    with pytest.raises(ValueError, match=named):
        parse_flicker(text)


def _ambient_means(camera: SimulatedCamera, frames: int) -> np.ndarray:
    black = camera.info.black_level
    dark = (0.0,) * camera.led_spectra.count
    return np.array([float(np.mean(camera.render(dark, 2000.0, 1.0))) - black for _ in range(frames)])


def test_the_sim_camera_renders_each_frame_with_its_own_share_of_a_flickering_lamp() -> None:
    camera = SimulatedCamera.default(seed=1)
    camera.ambient_modulation = MainsFlicker(100.0, 0.3, "sine", phase=0.4)
    means = _ambient_means(camera, 8)
    gains = np.array(camera.true_ambient_gains[-8:])
    # The frames' ambient differs as the lamp's mean over each window does (2 ms of a 10 ms period).
    assert gains.max() - gains.min() > 0.05
    assert np.allclose(means / means.mean(), gains / gains.mean(), atol=0.01)


def test_a_steady_lamp_gives_every_frame_the_same_ambient() -> None:
    camera = SimulatedCamera.default(seed=1)
    means = _ambient_means(camera, 5)
    assert camera.true_ambient_gains[-5:] == [1.0] * 5
    assert np.allclose(means / means.mean(), 1.0, atol=0.005)
