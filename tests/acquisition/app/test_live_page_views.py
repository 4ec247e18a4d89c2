"""The live page at 1024 px, 1920 px and 4K in headless Chromium (issue 33): zoom, the pixel readout, fps, a snapshot,
the flash before it fires (presets, a slider, Fire the mix shown), the keyboard, and a large disconnected state.

A real sim rig and its booth emulator on a pty; the LED levels are read at the emulator's end. Each test leaves
screenshots in its tmp dir; with ``MSFLASH_DOCS_SCREENSHOTS=DIR`` set, also ``DIR/live-<width>.png`` (how
``docs/live-1024.png``, ``docs/live-1920.png`` and ``docs/live-1024-disconnected.png`` were made; the camera panel's
and a camera error's, ``docs/live-1024-camera*.png``, by ``test_live_page_camera.py``).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import tifffile

from tests.acquisition.support.browser import RUN, chromium, data, js, needs_chromium, shot
from tests.acquisition.support.live import emulator_levels, live_server, wait_until

pytestmark = needs_chromium


@pytest.fixture(params=[(1024, 900), (1920, 1200), (3840, 2160)], ids=["1024px", "1920px", "4K"])
def browser(request: pytest.FixtureRequest) -> Iterator[object]:
    driver = chromium(*request.param)
    try:
        yield driver
    finally:
        driver.quit()  # type: ignore[attr-defined]


def test_the_page_zooms_reads_pixels_snapshots_previews_the_flash_and_shows_a_lost_server(
    tmp_path: Path, sim_run: Path, browser
) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    driver = browser
    width = js(driver, "return window.innerWidth")
    runs = tmp_path / "runs"
    shutil.copytree(sim_run, runs / RUN)
    with live_server(runs) as server:
        driver.get(f"http://127.0.0.1:{server.port}/")
        wait_until(lambda: int(data(driver, "frame-count", "frames") or 0) >= 5, "live frames")
        wait_until(lambda: float(data(driver, "fps", "fps") or 0) > 0, "an fps reading")
        assert int(data(driver, "dropped", "dropped")) >= 0

        # The layout: nothing cut off, no horizontal scrollbar, the controls beside or below the image.
        assert js(driver, "return document.documentElement.scrollWidth") <= width
        fire = driver.find_element("id", "fire")
        assert js(driver, "return arguments[0].getBoundingClientRect().right", fire) <= width
        # LED names everywhere, gain in both units.
        assert "led440" in driver.find_element("id", "leds").text
        assert "dB" in driver.find_element("id", "gain-value").text
        assert "×" in driver.find_element("id", "gain-value").text

        # Zoom: z toggles 4×, the wheel zooms about the cursor; the readout follows the cursor.
        image = driver.find_element("id", "live")
        ActionChains(driver).move_to_element_with_offset(image, 10, 5).perform()
        wait_until(lambda: "row" in driver.find_element("id", "readout").text, "the pixel readout")
        values = json.loads(data(driver, "readout", "values"))
        assert len(values) == 4 and all(0 <= v <= 4095 and float(v).is_integer() for v in values)
        assert [c for c in driver.find_element("id", "readout").text.split() if c in "RGB"] == ["R", "G", "G", "B"]
        driver.find_element("tag name", "body").send_keys("z")
        wait_until(lambda: data(driver, "viewport", "zoom") == "4", "4× zoom after z")
        rect = js(driver, "return arguments[0].getBoundingClientRect().width", image)
        viewport = js(driver, "return document.getElementById('viewport').clientWidth")
        assert rect == pytest.approx(4 * viewport, rel=0.02)
        ActionChains(driver).move_to_element_with_offset(image, 3, 3).perform()  # zoomed: a pixel near the corner
        wait_until(lambda: "row" in driver.find_element("id", "readout").text, "a readout while zoomed")
        shot(driver, tmp_path, "zoomed")
        driver.find_element("tag name", "body").send_keys("z")
        wait_until(lambda: data(driver, "viewport", "zoom") == "1", "1× after z again")

        # A snapshot by its key: a raw TIFF and a PNG in the runs folder.
        driver.find_element("tag name", "body").send_keys("s")
        tiff = wait_until(lambda: data(driver, "snapshot-result", "tiff"), "the snapshot's file")
        raw = tifffile.imread(runs / tiff)
        assert raw.shape == (106, 112) and raw.dtype == np.uint16
        assert (runs / tiff).with_suffix(".png").is_file()

        # The flash before it fires: the newest run's frames, presets, a slider, the mix fired.
        wait_until(lambda: data(driver, "flash-preview", "run") == RUN, "the last run's flash preview")
        wait_until(lambda: int(data(driver, "mix-frames", "frames") or 0) >= 1, "a synthesised image")
        driver.find_element("id", "mix-matching").click()
        wait_until(lambda: server.mix is not None and server.mix_levels == server.mix.solved["matching"], "matching")
        shown = int(data(driver, "mix-frames", "frames"))
        slider = driver.find_element("id", "mix-0")
        slider.click()
        slider.send_keys(Keys.HOME)
        for _ in range(3):
            slider.send_keys(Keys.PAGE_UP)  # 10 % of the range each
        wait_until(lambda: abs(server.mix_levels[0] - 0.3) < 1e-9, "led440 at 30 % in the mix")
        wait_until(lambda: int(data(driver, "mix-frames", "frames")) > shown, "the mix synthesised again")
        ActionChains(driver).move_to_element(driver.find_element("id", "mix-image")).perform()
        wait_until(lambda: data(driver, "readout", "view") == "mix", "a readout of the synthesised image")
        driver.find_element("id", "mix-fire").click()
        caption = driver.find_element("id", "mix-capture-caption")
        difference = wait_until(lambda: caption.get_attribute("data-difference"), "the mix captured")
        assert 0 < float(difference) < 0.08  # noise: about 1–4 % on the sim; ignoring the PWM was 20–50 %
        assert server.mix_capture is not None and server.mix_capture["levels"][0] == pytest.approx(0.3)
        assert (runs / RUN / server.mix_capture["tiff"]).is_file()
        assert server.stream.settings.levels == (0.0,) * 7  # the live levels as before the mix fired: all off
        assert emulator_levels(server) == (0.0,) * 7
        wait_until(lambda: js(driver, "return document.getElementById('mix-capture').naturalWidth") > 0, "its image")
        # The run's charts beside it: matplotlib's SVG, the estimate's band clipped to the axes.
        wait_until(lambda: driver.find_elements("css selector", "#charts svg g#band"), "the charts")
        assert js(driver, "return document.documentElement.scrollWidth") <= width
        js(driver, "window.scrollTo(0, 0)")
        shot(driver, tmp_path, f"live-{width}")

        # o: LEDs off.
        assert driver.find_element("id", "led-2")
        from msflash.acquisition.app.live.server import TOKEN_HEADER
        from tests.acquisition.app.test_live_http import request

        base = f"http://127.0.0.1:{server.port}"
        assert (
            request("POST", base + "/api/levels", {TOKEN_HEADER: server.token}, {"channel": 2, "level": 0.4})[0] == 200
        )
        wait_until(lambda: emulator_levels(server)[2] > 0.3, "led500 lit")
        driver.find_element("tag name", "body").send_keys("o")
        wait_until(lambda: emulator_levels(server) == (0.0,) * 7, "LEDs off after o")
    # The server is gone: the page greys the image and says so, large, with a reconnect button.
    wait_until(lambda: js(driver, "return document.body.dataset.connection") == "disconnected", "the lost server")
    box = driver.find_element("id", "disconnected")
    # The reason: the close frame's ("server stopping"), or, when the close was aborted under load, no answer.
    assert (
        box.is_displayed()
        and "Disconnected" in box.text
        and ("server stopping" in box.text or "does not answer" in box.text)
    )
    assert js(driver, "return getComputedStyle(arguments[0]).filter", image).startswith("grayscale")
    assert driver.find_element("id", "reconnect").is_displayed()
    driver.find_element("id", "reconnect").click()  # nobody answers: still disconnected, still saying why
    wait_until(lambda: js(driver, "return document.body.dataset.connection") == "disconnected", "still disconnected")
    js(driver, "window.scrollTo(0, 0)")
    shot(driver, tmp_path, f"live-{width}-disconnected")


def test_space_fires_a_sequence_and_its_frames_become_the_flash_preview(tmp_path: Path) -> None:
    driver = chromium(1024, 900)
    try:
        with live_server(tmp_path / "runs") as server:
            driver.get(f"http://127.0.0.1:{server.port}/")  # no run yet: the preview says what to do
            wait_until(lambda: int(data(driver, "frame-count", "frames") or 0) >= 1, "a live frame")
            assert driver.find_element("id", "mix-empty").is_displayed()
            driver.find_element("tag name", "body").send_keys(" ")
            job = driver.find_element("id", "job")
            wait_until(lambda: job.get_attribute("data-status") == "done", "the sequence", timeout_s=240)
            steps = [item.text.rstrip(" ✓") for item in driver.find_elements("css selector", "#job-steps li")]
            assert steps[1:8] == list(server.rig.led_spectra.names) and "led:1" not in " ".join(steps)
            run = job.get_attribute("data-run")
            wait_until(lambda: data(driver, "flash-preview", "run") == run, "the new run's flash preview")
            wait_until(lambda: int(data(driver, "mix-frames", "frames") or 0) >= 1, "its synthesised image")
            assert server.mix is not None and server.mix_levels == server.mix.solved["complementary"]
    finally:
        driver.quit()
